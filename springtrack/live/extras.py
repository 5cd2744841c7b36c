"""Optional extras of the live work (dv, view): import a package of one, or say which
extra installs it.

    dv = need("dv_processing", "dv", "dv:// and dv:camera sources")

``MissingExtra`` is a ValueError so every command reports it as a bad argument (exit 2),
its message naming the ``pip install`` that fixes it.
"""
from __future__ import annotations

import importlib


class MissingExtra(ValueError):
    """A package of an optional extra is not installed."""


def need(module: str, extra: str, what: str):
    """``module`` imported, or MissingExtra naming ``springtrack[extra]``."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise MissingExtra(f"{what} need the Python package {module!r}, which is not "
                           f"installed ({e}): pip install 'springtrack[{extra}]'") from None
