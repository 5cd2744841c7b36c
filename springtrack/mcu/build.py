"""Cross-compile the fixed-point kernel, its telemetry packer and its entry point
(entry.c) into a freestanding
ELF with the clang of the ``ziglang`` package, and measure its flash and static RAM.

    >>> res = build("cortex-m4", "out/")                      # doctest: +SKIP
    >>> res.elf, res.flash_bytes, res.ram_bytes               # doctest: +SKIP

No heap, no libc: ``-ffreestanding -fno-builtin -nostdlib``, so a floating-point, 128-bit
or 64-bit-division helper the code needed would fail the link (there is no runtime to
take it from); tests/test_springtrack/mcu/test_mcu.py also inspects the symbol table.  Capacity (trackers,
connections, sensor size) is fixed at build time: the kernel's state is one struct of
that size, its spatial index one static array.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from ..limits import MAX_INSTANCES, MAX_SET_TRACKERS
from . import need
from .targets import Target, target as get_target

HERE = Path(__file__).resolve().parent
CSRC = HERE.parent / "csrc"                  # the C shared by the kernels and loops
FIXED = HERE.parent / "fixed" / "csrc"       # the fixed-point kernel's C
SOURCES = [HERE / "entry.c", FIXED / "fixed_step.c", FIXED / "fixed_telemetry.c"]
HEADERS = [*sorted(FIXED.glob("*.[ch]")), CSRC / "sampling.h", HERE / "link.ld"]
CFLAGS = ["-std=c11", "-O2", "-ffreestanding", "-fno-builtin", "-nostdlib",
          "-ffunction-sections", "-fdata-sections", "-fno-unwind-tables",
          "-fno-asynchronous-unwind-tables", "-Wall", "-Wextra", "-Werror"]
STACK_BYTES = 8192
FLASH_SECTIONS = (".text", ".rodata", ".data")
RAM_SECTIONS = (".data", ".bss", ".stack")


@dataclass(frozen=True)
class Capacity:
    """What the ELF is built for: trackers and connections of the model (of the largest,
    with several instances), the sensor (which sizes the spatial index: one 64-bit mask
    per 8 x 8 px cell, one index per instance), and the model instances and their trackers
    in all."""
    trackers: int = 64
    connections: int = 128
    width: int = 1280
    height: int = 720
    events: int = 256          # event buffer (records of 16 bytes)
    rows: int = 4              # snapshot rows per call
    instances: int = 1
    set_trackers: int = 0      # trackers of all instances (0: one instance's)
    states: bool = False       # the set's code (instance states) even for one instance

    def check(self):
        if not 1 <= self.trackers <= 64 or not 0 <= self.connections <= 128:
            raise ValueError(f"capacity {self.trackers} trackers / {self.connections} connections "
                             f"is outside the kernel's 1..64 / 0..128")
        if not (1 <= self.width <= 8192 and 1 <= self.height <= 8192):
            raise ValueError(f"sensor {self.width}x{self.height} is outside 1..8192 px per side")
        if not 1 <= self.instances <= MAX_INSTANCES or not self.set_trackers <= MAX_SET_TRACKERS:
            raise ValueError(f"capacity {self.instances} instances / {self.set_trackers} trackers "
                             f"in all is outside the kernel's 1..{MAX_INSTANCES} / "
                             f"{MAX_SET_TRACKERS}")

    @property
    def cells(self) -> int:
        return (((self.width - 1) >> 3) + 1) * (((self.height - 1) >> 3) + 1)

    def defines(self) -> list[str]:
        d = [f"-DFX_MAX_TRACKERS={self.trackers}", f"-DFX_MAX_CONNECTIONS={max(self.connections, 1)}",
             f"-DMCU_CELLS={self.cells}", f"-DMCU_EVENTS={self.events}", f"-DMCU_ROWS={self.rows}"]
        if self.instances > 1 or self.states:
            d += [f"-DMCU_INSTANCES={self.instances}", f"-DFX_MAX_INSTANCES={self.instances}",
                  f"-DMCU_SET_TRACKERS={self.set_trackers or self.trackers * self.instances}",
                  "-DMCU_SET=1"]
        return d

    @classmethod
    def of_model(cls, model, **kw) -> "Capacity":
        """Exactly ``model``: a ShapeModel, or a springtrack.instances.ModelSet (the set's
        code, with the instances' states, even for one instance)."""
        if hasattr(model, "instances"):
            ms = model.models
            return cls(max(len(m.trackers) for m in ms), max(len(m.connections) for m in ms),
                       ms[0].width, ms[0].height, instances=len(ms), set_trackers=model.n,
                       states=True, **kw)
        return cls(len(model.trackers), len(model.connections), model.width, model.height, **kw)


@dataclass
class BuildResult:
    elf: Path
    target: Target
    capacity: Capacity
    flash_bytes: int
    ram_bytes: int
    sections: dict = field(default_factory=dict)     # name -> bytes
    objects: dict = field(default_factory=dict)      # RAM symbol -> bytes

    def report(self) -> str:
        c = self.capacity
        lines = [f"target {self.target.name} ({self.target.isa}), capacity {c.trackers} trackers, "
                 f"{c.connections} connections, sensor {c.width}x{c.height} ({c.cells} index cells)",
                 f"elf {self.elf}"]
        lines += [f"  {name:8s} {size:8,d} bytes" for name, size in self.sections.items()]
        lines += [f"  ram: {name} {size:,d} bytes" for name, size in self.objects.items()]
        lines.append(f"flash_bytes={self.flash_bytes} ram_bytes={self.ram_bytes}")
        return "\n".join(lines)


def zig_cc() -> list[str]:
    need("ziglang")
    return [sys.executable, "-m", "ziglang", "cc"]


def source_key(tgt: Target, cap: Capacity) -> str:
    h = hashlib.sha256()
    for p in SOURCES + HEADERS:
        h.update(p.read_bytes())
    h.update(repr((tgt, cap, CFLAGS, STACK_BYTES)).encode())
    return h.hexdigest()[:16]


def build(target_name: str, out_dir, capacity: Capacity | None = None) -> BuildResult:
    """Compile and link; returns the ELF's path and its flash / RAM use."""
    tgt = get_target(target_name)
    cap = capacity or Capacity()
    cap.check()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    script = out / "link.ld"
    script.write_text((HERE / "link.ld").read_text().replace("STACK_SIZE;", f"{STACK_BYTES};"))
    elf = out / f"springtrack-{tgt.name}.elf"
    cmd = [*zig_cc(), "-target", tgt.triple, f"-mcpu={tgt.cpu}", *tgt.flags, *CFLAGS,
           *cap.defines(), f"-I{FIXED}", f"-I{CSRC}", *map(str, SOURCES), "-Wl,-T," + str(script),
           "-Wl,--gc-sections", "-Wl,-e,mcu_main", "-o", str(elf)]
    r = subprocess.run(cmd, capture_output=True, text=True,
                       env={**os.environ, "ZIG_GLOBAL_CACHE_DIR": str(cache_root() / "zig")})
    if r.returncode != 0:
        raise RuntimeError(f"cross-compiling for {tgt.name} failed:\n{' '.join(cmd)}\n{r.stderr}")
    return measure(elf, tgt, cap)


def measure(elf: Path, tgt: Target, cap: Capacity, prefix: str = "mcu_") -> BuildResult:
    """Flash = code + constants + initialised data; RAM = data + zeroed data + stack; the
    RAM objects whose names start with ``prefix`` listed."""
    ELFFile = need("elftools.elf.elffile").ELFFile
    with open(elf, "rb") as f:
        e = ELFFile(f)
        sections = {s.name: s["sh_size"] for s in e.iter_sections()
                    if s["sh_flags"] & 2 and s["sh_size"]}
        symtab = e.get_section_by_name(".symtab")
        objects = {s.name: s["st_size"] for s in symtab.iter_symbols()
                   if s["st_info"]["type"] == "STT_OBJECT" and s.name.startswith(prefix)
                   and s["st_value"] >= 0x20000000 and s["st_size"]}
    objects["stack"] = sections.get(".stack", 0)
    flash = sum(v for k, v in sections.items() if k in FLASH_SECTIONS)
    ram = sum(v for k, v in sections.items() if k in RAM_SECTIONS)
    unknown = set(sections) - set(FLASH_SECTIONS) - set(RAM_SECTIONS)
    if unknown:
        raise RuntimeError(f"{elf}: unexpected allocated sections {sorted(unknown)}")
    return BuildResult(elf, tgt, cap, flash, ram, sections, objects)


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "springtrack" / "mcu"


def cached_build(target_name: str, capacity: Capacity) -> BuildResult:
    """build() into a per-source-hash cache directory, reused while sources are unchanged."""
    tgt = get_target(target_name)
    capacity.check()
    out = cache_root() / f"{tgt.name}-{source_key(tgt, capacity)}"
    elf = out / f"springtrack-{tgt.name}.elf"
    if elf.exists():
        return measure(elf, tgt, capacity)
    tmp = out.with_name(out.name + f".tmp{os.getpid()}")
    res = build(target_name, tmp, capacity)
    try:
        tmp.rename(out)
    except OSError:                      # another process built it meanwhile
        pass
    return measure(out / res.elf.name, tgt, capacity) if (out / res.elf.name).exists() else res
