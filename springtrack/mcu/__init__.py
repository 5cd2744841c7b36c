"""The fixed-point kernel on a microcontroller: a freestanding ELF for Cortex-M4, Cortex-M7
or RV32IMAC built from the same C source as ``--backend fixed`` (springtrack/csrc/), run
bit for bit in an instruction-set emulator.

* :mod:`.targets`   the supported cores (compiler target, emulator model, ISA notes);
* :mod:`.build`     cross-compiles ``entry.c`` + ``fixed/csrc/fixed_step.c`` with the clang of
                    the ``ziglang`` package, reports flash and static RAM;
* :mod:`.emulator`  loads that ELF into ``unicorn`` and calls its entry point, counting
                    instructions per basic block when asked;
* :mod:`.backend`   ``McuBackend``: the tracker backend interface over the emulator
                    (``Tracker(..., backend="mcu")``);
* :mod:`.profile`   instructions per event on a stream.

The toolchain and the emulator come from PyPI as the optional extra ``[mcu]``
(``pip install 'springtrack[mcu]'``); docs/mcu.md tells more.
"""
from __future__ import annotations

import importlib

EXTRA_HINT = "pip install 'springtrack[mcu]'"


class MissingExtra(RuntimeError):
    """A package of the ``[mcu]`` extra is not installed."""


def need(module: str):
    """Import ``module`` (ziglang, unicorn, capstone, elftools) or raise MissingExtra
    naming the extra that provides it."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise MissingExtra(f"the microcontroller build needs the Python package providing "
                           f"{module!r}, which is not installed ({e}); install the extra: "
                           f"{EXTRA_HINT}") from None
