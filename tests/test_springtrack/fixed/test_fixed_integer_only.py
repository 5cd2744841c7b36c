"""The fixed-point step is integer-only by construction.

springtrack/fixed/csrc/fixed_step.c (the per-event step, the springs and every arithmetic
helper they use) and fixed_telemetry.c (telemetry records from that state) must compile
with ``gcc -mgeneral-regs-only``, which on x86-64 rejects any floating-point or SIMD
operation, and contain no 128-bit integer (tests/test_springtrack/mcu/test_mcu.py cross-compiles them for
32-bit cores and inspects the linked symbols).  A control case shows the check does fail when a
float slips in.
"""
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from support import REPO

CSRC = REPO / "springtrack" / "fixed" / "csrc"
UNIT = CSRC / "fixed_step.c"
UNITS = [UNIT, CSRC / "fixed_telemetry.c"]
FLAGS = ["-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", "-mgeneral-regs-only", "-c"]

gcc = shutil.which("gcc")
needs_gcc = pytest.mark.skipif(gcc is None, reason="gcc is not installed")


def compile_c(src: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([gcc, *FLAGS, f"-I{CSRC}", str(src), "-o", str(out)],
                          capture_output=True, text=True)


@pytest.mark.slow
@needs_gcc
@pytest.mark.parametrize("unit", UNITS, ids=lambda u: u.name)
def test_fixed_units_compile_with_general_regs_only(tmp_path, unit):
    r = compile_c(unit, tmp_path / "unit.o")
    assert r.returncode == 0, f"{unit} does not compile integer-only:\n{r.stderr}"


@needs_gcc
def test_the_check_rejects_a_float(tmp_path):
    """Control: the same unit plus one line of double arithmetic must fail to compile."""
    src = tmp_path / "with_float.c"
    src.write_text(UNIT.read_text() + "\ndouble fx_leak(double v) { return v * 0.5; }\n")
    r = compile_c(src, tmp_path / "with_float.o")
    assert r.returncode != 0, "gcc -mgeneral-regs-only accepted floating-point code"
    assert "general" in r.stderr or "SSE" in r.stderr or "float" in r.stderr


def test_no_float_or_128_bit_type_in_the_fixed_unit():
    """A reader's check: no float/double/long double token, and no 128-bit integer (which
    32-bit cores do not have), in the C units or their headers."""
    for f in sorted(CSRC.glob("*.[ch]")):          # the units, their parts and headers
        code = re.sub(r"/\*.*?\*/", "", f.read_text(), flags=re.S)   # comments may say "float"
        assert not re.search(r"\b(float|double)\b", code), f"{f} mentions a floating-point type"
        assert "__int128" not in code, f"{f} uses a 128-bit integer"


def test_tables_header_is_generated_from_fixed_q():
    """fixed/csrc/fixed_tables.h (constant tables, flash on a microcontroller) is what
    springtrack.fixed.q generates: `python -m springtrack.fixed.q` rewrites it."""
    from springtrack.fixed import q as fixed_q
    assert (CSRC / "fixed_tables.h").read_text() == fixed_q.tables_header()
