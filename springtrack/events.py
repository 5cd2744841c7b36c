"""The event record shared by every stage: decoders, tracker, simulator, firmware.

An event array is a numpy structured array of :data:`EVENT_DTYPE`:

======  ======  =========================================
field   type    meaning
======  ======  =========================================
``t``   int64   timestamp, microseconds
``x``   uint16  column, 0 = left
``y``   uint16  row, 0 = top
``p``   uint8   polarity, 1 = ON (brighter), 0 = OFF
======  ======  =========================================

The dtype is aligned (16-byte records) so C code can read it as a plain struct
(see ``events.pxd``).
"""
from __future__ import annotations

import numpy as np

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")], align=True)
EVENT_FIELDS = ("t", "x", "y", "p")


def empty(n: int = 0) -> np.ndarray:
    """An uninitialised event array of length ``n``."""
    return np.empty(n, dtype=EVENT_DTYPE)


def make(t, x, y, p) -> np.ndarray:
    """Build an event array from four sequences (converted, not checked for range)."""
    t = np.asarray(t)
    ev = np.empty(len(t), dtype=EVENT_DTYPE)
    ev["t"] = t
    ev["x"] = x
    ev["y"] = y
    ev["p"] = p
    return ev


def as_events(arr) -> np.ndarray:
    """Return ``arr`` as a C-contiguous array of :data:`EVENT_DTYPE`.

    Accepts any structured array with fields ``t, x, y, p`` (e.g. the packed
    dtype other tools write, or ``x``/``y`` as int16).  Raises ``TypeError``
    naming the missing fields otherwise.
    """
    arr = np.asarray(arr)
    if arr.dtype == EVENT_DTYPE and arr.flags.c_contiguous:
        return arr
    names = arr.dtype.names or ()
    missing = [f for f in EVENT_FIELDS if f not in names]
    if missing:
        raise TypeError(
            f"event array needs fields t, x, y, p; missing {', '.join(missing)} "
            f"(got dtype {arr.dtype})")
    out = np.empty(arr.shape[0] if arr.ndim else 0, dtype=EVENT_DTYPE)
    for f in EVENT_FIELDS:
        out[f] = arr[f]
    return out
