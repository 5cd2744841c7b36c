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
# The values an event may hold, checked for every event source by as_events: times in whole
# µs within +-2^62 (the kernels' clocks start at T_MIN, before every event, and sampling
# arithmetic stays within int64), coordinates of a uint16, polarity 0 or 1.
T_MIN = -(1 << 62)
T_MAX = (1 << 62) - 1
RANGES = {"t": (T_MIN, T_MAX), "x": (0, 65535), "y": (0, 65535), "p": (0, 1)}


class EventError(ValueError):
    """An event holds a value outside :data:`RANGES` (or not a whole number): ``index`` is
    the first such event, ``detail`` says what is wrong with it."""

    def __init__(self, index: int, detail: str):
        super().__init__(f"event {index}: {detail}")
        self.index = index
        self.detail = detail


def empty(n: int = 0) -> np.ndarray:
    """An uninitialised event array of length ``n``."""
    return np.empty(n, dtype=EVENT_DTYPE)


# numpy asks the kernel for transparent huge pages on arrays of 4 MiB and more; the kernel
# gives them to whole, aligned 2 MiB spans only
HUGE_PAGE = 1 << 21
HUGE_ARRAY = 4 << 20


def empty_output(n: int) -> np.ndarray:
    """An uninitialised event array of length ``n`` for a decoder to fill: from 4 MiB on it
    starts on a 2 MiB boundary (a view into a buffer 2 MiB larger, never touched beyond the
    array), so that huge pages back all of it instead of its aligned middle only -- one
    page fault per 2 MiB instead of per 4 KiB, which makes much of a file read's time
    where faults are slow (virtual machines: about 2.5 µs each)."""
    nbytes = n * EVENT_DTYPE.itemsize
    if nbytes < HUGE_ARRAY:
        return np.empty(n, dtype=EVENT_DTYPE)
    raw = np.empty(nbytes + HUGE_PAGE, dtype=np.uint8)
    start = -raw.ctypes.data % HUGE_PAGE
    return raw[start:start + nbytes].view(EVENT_DTYPE)


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
    """Return ``arr`` as a C-contiguous array of :data:`EVENT_DTYPE`, its values checked.

    Accepts any structured array with fields ``t, x, y, p`` (e.g. the packed
    dtype other tools write, ``x``/``y`` as int16, times as float64 whole µs).  Raises
    ``TypeError`` naming the missing fields, and :class:`EventError` for the first event
    whose value is outside :data:`RANGES`, not finite or not a whole number: nothing is
    wrapped or truncated into the event record silently.
    """
    arr = np.asarray(arr)
    if arr.dtype == EVENT_DTYPE and arr.flags.c_contiguous:
        check(arr)
        return arr
    names = arr.dtype.names or ()
    missing = [f for f in EVENT_FIELDS if f not in names]
    if missing:
        raise TypeError(
            f"event array needs fields t, x, y, p; missing {', '.join(missing)} "
            f"(got dtype {arr.dtype})")
    check(arr)
    out = np.empty(arr.shape[0] if arr.ndim else 0, dtype=EVENT_DTYPE)
    for f in EVENT_FIELDS:
        out[f] = arr[f]
    return out


def check(arr) -> None:
    """Raise :class:`EventError` for the first event of the structured array ``arr``
    (fields t, x, y, p of any numeric types) whose value does not fit :data:`RANGES`.
    For an :data:`EVENT_DTYPE` array only what its types do not already bound is
    checked: t's range and p."""
    if arr.ndim == 0 or len(arr) == 0:
        return
    own = arr.dtype == EVENT_DTYPE
    for f in EVENT_FIELDS:
        if own and f in ("x", "y"):
            continue
        v = arr[f]
        lo, hi = RANGES[f]
        if v.dtype.kind == "b":
            continue
        if v.dtype.kind not in "iuf":
            raise TypeError(f"event field {f} must hold numbers, not {v.dtype}")
        if v.dtype.kind == "f":
            bad = ~np.isfinite(v)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise EventError(i, f"{f}={v[i].item()!r} is not a finite number")
            bad = v != np.floor(v)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise EventError(i, f"{f}={v[i].item()!r} is not a whole number"
                                    + (" of µs" if f == "t" else ""))
        if (v.dtype.kind == "u" or v.min() >= lo) and v.max() <= hi:
            continue
        bad = (v < lo) | (v > hi)
        i = int(np.flatnonzero(bad)[0])
        raise EventError(i, f"{f}={v[i].item()!r} out of range {lo}..{hi}")
