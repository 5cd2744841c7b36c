"""The package's layout keeps its rules: no import circle among the library's modules (at
module level or inside functions), at most 20 modules at springtrack's top level, and no
hand-written source file over 1,000 lines (docs/architecture.md, "Layout")."""
from __future__ import annotations

import ast
import re
from pathlib import Path
from support import REPO

ROOT = REPO
PACKAGES = ("springtrack", "firmware_sim", "hostctl")
SOURCE_SUFFIXES = (".py", ".pyx", ".pxd", ".c", ".h")
MAX_LINES = 1000
MAX_TOP_MODULES = 20
# generated, not hand-written: each is rewritten by its generator and a test checks it is
# what the generator writes (tests/test_springtrack/fixed/test_fixed_integer_only.py)
GENERATED = {"springtrack/fixed/csrc/fixed_tables.h"}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def library_modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*")):
            if p.suffix in (".py", ".pyx") and "__pycache__" not in p.parts:
                mods[module_name(p)] = p
    return mods


_CIMPORT = re.compile(r"^\s*(?:from\s+([\w.]+)\s+cimport|cimport\s+([\w.]+))", re.M)


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The library modules ``name`` imports anywhere in its text (a relative import
    resolved; ``from pkg import mod`` counted as the module when it is one)."""
    text = path.read_text()
    is_pkg = path.stem == "__init__"
    package = name if is_pkg else name.rpartition(".")[0]
    found: set[str] = set()

    def add(mod: str, names=()):
        for n in names:
            if f"{mod}.{n}" in known:
                found.add(f"{mod}.{n}")
        while mod and mod not in known:
            mod = mod.rpartition(".")[0]
        if mod:
            found.add(mod)

    if path.suffix == ".pyx":           # Cython: its Python imports parse once cimports go
        for m in _CIMPORT.finditer(text):
            add(m.group(1) or m.group(2))
        text = "\n".join(line.strip() for line in text.splitlines()
                          if re.match(r"^\s*(from\s+[\w.]+\s+import|import)\s[^(]*$", line))
    tree = ast.parse(text)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                add(a.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            add(mod, [a.name for a in node.names])
    found.discard(name)
    # a module importing its own package's __init__ is not an edge back (Python runs the
    # package first); count only the package's own imports
    return {m for m in found if not name.startswith(m + ".")}


def import_graph() -> dict[str, set[str]]:
    mods = library_modules()
    known = set(mods)
    return {n: imports_of(n, p, known) for n, p in mods.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(n):
        colour[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if colour.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in colour:
                c = visit(m)
                if c:
                    return c
        stack.pop()
        colour[n] = 2
        return None

    for n in sorted(graph):
        if n not in colour:
            c = visit(n)
            if c:
                return c
    return None


def test_no_import_cycle_among_library_modules():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_a_planted_circle():
    """Control: a graph with a circle is caught, and the real graph has edges to search."""
    g = import_graph()
    assert sum(len(v) for v in g.values()) > 100
    assert "springtrack.gate" in g["springtrack.limits"]
    planted = {k: set(v) for k, v in g.items()}
    planted["springtrack.gate"].add("springtrack.limits")
    assert find_cycle(planted) is not None


def test_at_most_twenty_modules_at_springtracks_top_level():
    top = sorted({p.stem for p in (ROOT / "springtrack").iterdir()
                  if p.suffix in (".py", ".pyx")})
    assert len(top) <= MAX_TOP_MODULES, f"{len(top)} top-level modules: {top}"


def test_no_hand_written_source_over_1000_lines():
    over = []
    for top in ("springtrack", "firmware_sim", "hostctl", "tests", "benchmarks"):
        for p in (ROOT / top).rglob("*"):
            rel = p.relative_to(ROOT).as_posix()
            if p.suffix not in SOURCE_SUFFIXES or rel in GENERATED or not p.is_file():
                continue
            if p.suffix == ".c" and (p.with_suffix(".pyx").exists() or p.with_suffix(".py").exists()):
                continue                       # Cython's output of a .pyx
            n = len(p.read_text(errors="replace").splitlines())
            if n > MAX_LINES:
                over.append(f"{rel}: {n}")
    assert not over, "files over 1,000 lines: " + ", ".join(over)


def test_generated_files_say_so():
    for rel in GENERATED:
        assert "generated" in (ROOT / rel).read_text()[:300]


def test_no_test_module_imports_another():
    """Helpers and fixtures live in tests/support/; a test module imports no test module."""
    tests = {p.stem for p in (ROOT / "tests").rglob("test_*.py")}
    bad = []
    for p in (ROOT / "tests").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad += [f"{p.relative_to(ROOT)}: {n}" for n in names if n.split(".")[-1] in tests]
    assert not bad, bad


def test_tests_mirror_the_packages():
    """Test modules sit in the folder of the package they test: tests/test_springtrack/kernel/
    for springtrack/kernel/, tests/test_hostctl/ for hostctl/ (``test_`` before a package's
    name, so that a tests folder never shadows the package it tests on sys.path)."""
    folders = [d for d in (ROOT / "tests").rglob("*") if d.is_dir()
               and "__pycache__" not in d.parts and any(d.glob("test_*.py"))]
    assert len(folders) >= 10
    for d in folders:
        rel = d.relative_to(ROOT / "tests").parts
        assert rel[0].startswith("test_"), f"tests/{'/'.join(rel)}"
        package = ROOT.joinpath(rel[0][len("test_"):], *rel[1:])
        assert (package / "__init__.py").is_file(), f"tests/{'/'.join(rel)} mirrors no package"
