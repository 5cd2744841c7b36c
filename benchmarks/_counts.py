"""Where the time goes without hardware counters: instructions, simulated cache misses and
branch mispredictions per event, counted by callgrind around single calls.

    from _counts import perf_status, callgrind_status, counted, mark
    perf_status()                   # None if `perf stat` counts instructions, else why not
    with mark("float"):             # in a process run under counted(): counts this block
        tracker.process(events)
    counted([python, script, ...])  # {name: {"Ir": ..., "D1mr": ..., ...}} per mark

``mark`` is a no-op outside valgrind.  The marks are callgrind's client requests
(valgrind/callgrind.h) in a small library built on first use; the process runs with
instrumentation off except inside the marks, so its set-up costs no simulation.
valgrind has no AVX-512: code run under it must take its AVX2 paths.
"""
from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import shlex
import shutil
import subprocess
import sysconfig
import tempfile
from pathlib import Path

MARKS_C = r"""
#include <valgrind/callgrind.h>
void cg_begin(void) { CALLGRIND_START_INSTRUMENTATION; CALLGRIND_ZERO_STATS; }
void cg_end(const char *name) { CALLGRIND_DUMP_STATS_AT(name); CALLGRIND_STOP_INSTRUMENTATION; }
"""
HEADER = Path("/usr/include/valgrind/callgrind.h")
# callgrind's events with --cache-sim=yes --branch-sim=yes
EVENTS = ("Ir", "Dr", "Dw", "I1mr", "D1mr", "D1mw", "ILmr", "DLmr", "DLmw", "Bc", "Bcm",
          "Bi", "Bim")


def perf_status() -> str | None:
    """None where `perf stat` counts instructions and cycles here; else the reason."""
    if not shutil.which("perf"):
        return "perf is not installed"
    r = subprocess.run(["perf", "stat", "-x,", "-e", "instructions,cycles", "true"],
                       capture_output=True, text=True)
    if r.returncode != 0 or "<not supported>" in r.stderr or "<not counted>" in r.stderr:
        return ("`perf stat` reports the hardware events instructions and cycles as "
                "<not supported> (this virtual machine exposes no performance counters)")
    return None


def callgrind_status() -> str | None:
    """None where valgrind and its callgrind.h are installed; else what is missing."""
    if not shutil.which("valgrind"):
        return "valgrind is not installed"
    if not HEADER.is_file():
        return f"{HEADER} is missing (Debian: valgrind)"
    return None


_LIB = None


def _marks():
    global _LIB
    if _LIB is None:
        key = hashlib.sha256(MARKS_C.encode()).hexdigest()[:12]
        so = Path(tempfile.gettempdir()) / f"springtrack_cgmarks_{key}.so"
        if not so.exists():
            src = so.with_suffix(".c")
            src.write_text(MARKS_C)
            cc = shlex.split(sysconfig.get_config_var("CC") or "cc")
            tmp = so.with_suffix(".tmp.so")
            subprocess.run([*cc, "-O1", "-fPIC", "-shared", "-o", str(tmp), str(src)], check=True)
            tmp.rename(so)
        _LIB = ctypes.CDLL(str(so))
        _LIB.cg_end.argtypes = [ctypes.c_char_p]
    return _LIB


@contextlib.contextmanager
def mark(name: str):
    """Count the block as ``name`` when the process runs under :func:`counted`."""
    if os.environ.get("SPRINGTRACK_CALLGRIND") != "1":
        yield
        return
    lib = _marks()
    lib.cg_begin()
    try:
        yield
    finally:
        lib.cg_end(name.encode())


def counted(argv: list[str], timeout: float = 3600) -> dict[str, dict[str, int]]:
    """Run ``argv`` under callgrind (cache and branch simulation, instrumentation only inside
    its marks); {mark name: {event: count}}."""
    _marks()                                       # built before valgrind runs the child
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "cg.out"
        cmd = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--cache-sim=yes",
               "--branch-sim=yes", f"--callgrind-out-file={out}", *argv]
        subprocess.run(cmd, check=True, timeout=timeout, capture_output=True,
                       env={**os.environ, "SPRINGTRACK_CALLGRIND": "1"})
        found = {}
        for f in sorted(Path(d).glob("cg.out*")):
            name, events, totals = None, None, None
            for line in f.read_text(errors="replace").splitlines():
                if line.startswith("desc: Trigger: Client Request: "):
                    name = line.split("Client Request: ", 1)[1].strip()
                elif line.startswith("events: "):
                    events = line.split()[1:]
                elif line.startswith(("summary: ", "totals: ")):
                    totals = [int(v) for v in line.split()[1:]]
            if name and events and totals:
                found[name] = dict(zip(events, totals))
        return found
