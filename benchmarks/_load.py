"""A known machine load for real-time benchmarks: ``busy(n)`` runs ``n`` processes that
spin on the CPU at ordinary priority for the length of a ``with`` block, so "loaded" means
the same thing on every run (every core of a 2-core machine taken, whatever else runs)."""
from __future__ import annotations

import contextlib
import subprocess
import sys

SPIN = "while True: pass"


@contextlib.contextmanager
def busy(n: int):
    procs = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()
