"""Test-only Cython modules (``tests/support/*.pyx``) that expose kernel internals to the tests.

They are not part of the package (nothing installed calls them): setup.py compiles them,
with the package's own flags and headers, only when ``SPRINGTRACK_TEST_EXTENSIONS=1``.
:func:`load` does that on first use in a test session (a no-op when they are up to date),
so ``pytest tests/test_springtrack/test_x.py`` works on a fresh build.

    kp = probes.load("kernel_probe")     # tests/support/kernel_probe.pyx
"""
from __future__ import annotations

import importlib
import os
import subprocess
import sys

from . import REPO
_built = False


def build() -> None:
    """Compile tests/support/*.pyx in place (setup.py build_ext, only what changed)."""
    global _built
    if _built:
        return
    env = dict(os.environ, SPRINGTRACK_TEST_EXTENSIONS="1", SPRINGTRACK_ONLY="tests.")
    r = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=REPO,
                       env=env, capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"building the test extensions (tests/support/*.pyx) failed:\n"
                           f"{r.stdout[-3000:]}{r.stderr[-3000:]}")
    _built = True


def load(name: str):
    """The test-only module ``tests/support/<name>.pyx``, built first if needed."""
    build()
    return importlib.import_module(f"support.{name}")
