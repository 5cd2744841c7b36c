"""Build the Cython extensions.

Every ``*.pyx`` below ``springtrack/`` and ``firmware_sim/`` is compiled, so adding a
kernel or a decoder needs no edit here.  ``-ffp-contract=off`` keeps the float64
kernel bit-compatible with the pure-Python reference (no fused multiply-add).

With ``SPRINGTRACK_TEST_EXTENSIONS=1`` the test-only modules ``tests/support/*.pyx`` (kernel
internals exposed to the tests, never installed) are compiled too, with the same flags;
the tests do this themselves on first use (tests/support/probes.py).
"""
import glob
import os

import numpy as np
from Cython.Build import cythonize
from setuptools import Extension, setup

ROOT = os.path.dirname(os.path.abspath(__file__))     # headers by their repository path
COMPILE_ARGS = ["-O3", "-ffp-contract=off", "-fno-math-errno"]
if os.environ.get("SPRINGTRACK_NATIVE", "0") == "1":
    COMPILE_ARGS.append("-march=native")


def c_sources() -> list:
    """The hand-written C and headers below ``springtrack/`` (not the .c Cython writes
    beside a .pyx, nor the firmware's, which only the microcontroller build compiles): an
    extension may include any of them, directly or through another C file, and Cython
    tracks only the files a .pyx names, so a change to one rebuilds them all."""
    files = glob.glob("springtrack/**/*.[ch]", recursive=True)
    return sorted(f for f in files if not f.startswith("springtrack/mcu/")
                  and not os.path.exists(os.path.splitext(f)[0] + ".pyx"))


def extensions():
    exts = []
    depends = c_sources()
    roots = ["springtrack", "firmware_sim"]
    if os.environ.get("SPRINGTRACK_TEST_EXTENSIONS", "0") == "1":
        roots.append("tests")
    for pyx in sorted(p for root in roots for p in glob.glob(f"{root}/**/*.pyx", recursive=True)):
        module = os.path.splitext(pyx)[0].replace(os.sep, ".")
        only = os.environ.get("SPRINGTRACK_ONLY")      # developer convenience: build a subset
        if only and not any(module.startswith(o) for o in only.split(",")):
            continue
        exts.append(Extension(
            module, [pyx],
            depends=depends,
            include_dirs=[np.get_include(), os.path.dirname(pyx), ROOT],
            extra_compile_args=COMPILE_ARGS,
            define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
        ))
    return cythonize(exts, language_level=3, compiler_directives={
        "boundscheck": False, "wraparound": False, "cdivision": True,
        "initializedcheck": False,
    })


setup(ext_modules=extensions())
