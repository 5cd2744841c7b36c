"""The layering rule of docs/architecture.md: ``springtrack`` (the library) imports and
launches neither app; ``firmware_sim`` and ``hostctl`` never import each other."""
import ast
import re
from pathlib import Path

import pytest
from support import REPO


PACKAGES = ("springtrack", "firmware_sim", "hostctl")
# package -> the packages it must not import
FORBIDDEN = {"springtrack": {"firmware_sim", "hostctl"},
             "firmware_sim": {"hostctl"},
             "hostctl": {"firmware_sim"}}
CIMPORT = re.compile(r"^\s*(?:from\s+([\w.]+)\s+c?import|c?import\s+([\w.]+))", re.M)
# a module that can start processes must not name an app (its console script or module)
SPAWNERS = {"subprocess", "multiprocessing", "pty"}
APP_NAME = re.compile(r"firmware[-_]sim|hostctl")


def imported_tops(path: Path) -> set[str]:
    text = path.read_text()
    if path.suffix == ".py":
        tops = set()
        for node in ast.walk(ast.parse(text, str(path))):
            if isinstance(node, ast.Import):
                tops.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                tops.add(node.module.split(".")[0])
        return tops
    return {(m.group(1) or m.group(2)).split(".")[0] for m in CIMPORT.finditer(text)}


def sources(package: str):
    root = REPO / package
    return sorted(p for p in root.rglob("*") if p.suffix in (".py", ".pyx", ".pxd"))


@pytest.mark.parametrize("package", PACKAGES)
def test_no_upward_or_sideways_imports(package):
    bad = []
    for path in sources(package):
        for top in imported_tops(path) & FORBIDDEN[package]:
            bad.append(f"{path.relative_to(REPO)} imports {top}")
    assert not bad, "\n".join(bad)


def test_library_launches_no_app():
    bad = []
    for path in sources("springtrack"):
        if imported_tops(path) & SPAWNERS and APP_NAME.search(path.read_text()):
            bad.append(f"{path.relative_to(REPO)} starts processes and names an app")
    assert not bad, "\n".join(bad)


def test_checker_sees_a_forbidden_import(tmp_path):
    """The checker itself: a module importing an app is caught (both syntaxes)."""
    py = tmp_path / "m.py"
    py.write_text("import os\nfrom firmware_sim.loop import FirmwareLoop\n")
    pyx = tmp_path / "m.pyx"
    pyx.write_text("from hostctl.device cimport Device\n")
    assert "firmware_sim" in imported_tops(py)
    assert "hostctl" in imported_tops(pyx)
