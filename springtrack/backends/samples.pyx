# cython: language_level=3
"""Snapshot buffers shared by the tracker kernels and the firmware's fused loop."""
import numpy as np
cimport numpy as cnp
from springtrack.track import TRACK_DTYPE, TRACK_FIELDS
from springtrack.track cimport TrackRow
from springtrack.wire import TELE_TRACKER
from libc.stdint cimport int64_t, uint8_t
from libc.math cimport isfinite
from libc.string cimport memcpy

cnp.import_array()

TELE_RECORD = TELE_TRACKER.itemsize      # bytes per tracker record


def _check_track_row():
    """TrackRow (track.pxd) is TRACK_DTYPE (track.py): same size, and each field, set
    alone in a numpy record, is read back under its own name at its own place."""
    assert sizeof(TrackRow) == TRACK_DTYPE.itemsize, "TrackRow and TRACK_DTYPE differ in size"
    cdef cnp.ndarray rec
    for f in TRACK_FIELDS:
        rec = np.zeros(1, TRACK_DTYPE)
        rec[f] = 1
        row = (<TrackRow*>cnp.PyArray_DATA(rec))[0]         # the struct as a dict
        assert tuple(row) == TRACK_FIELDS, f"TrackRow fields {tuple(row)} != TRACK_FIELDS"
        assert all(v == (g == f) for g, v in row.items()), f"TrackRow.{f} is not TRACK_DTYPE's"


_check_track_row()


cdef dict sample_buffers(Py_ssize_t cap, int n, SampleOut* o, bint wire=False):
    """Arrays for ``cap`` snapshot rows of ``n`` trackers: ``t`` (cap,), ``trackers``
    (cap, n) TRACK_DTYPE, ``energy`` (cap, 3), and with ``wire`` (for a kernel whose
    snapshot packs them, the Stepper's wire_records) ``wire`` (cap, n * 8), the TELEMETRY
    tracker records; bound to ``o`` with ``o.count = 0``."""
    b = dict(t=np.empty(cap, np.int64), trackers=np.empty((cap, n), TRACK_DTYPE),
             energy=np.empty((cap, 3)))
    o.cap = cap
    o.count = 0
    o.t = <int64_t*>cnp.PyArray_DATA(b["t"])
    o.trackers = <TrackRow*>cnp.PyArray_DATA(b["trackers"])
    o.energy = <double*>cnp.PyArray_DATA(b["energy"])
    o.wire = NULL
    if wire:
        b["wire"] = np.empty((cap, n * TELE_RECORD), np.uint8)
        o.wire = <uint8_t*>cnp.PyArray_DATA(b["wire"])
    return b


cdef cnp.ndarray _rows_copy(cnp.ndarray rows):
    """A copy of C-contiguous ``rows``, byte for byte: numpy copies an aligned record dtype
    (TRACK_DTYPE, with padding) field by field, several times slower."""
    cdef cnp.ndarray out = np.empty_like(rows)
    memcpy(cnp.PyArray_DATA(out), cnp.PyArray_DATA(rows), cnp.PyArray_NBYTES(rows))
    return out


cdef dict bind_buffers(dict bufs, int n, SampleOut* o):
    """``bufs`` (arrays as sample_buffers makes them: ``t`` (m,) int64, ``trackers``
    (m, n) TRACK_DTYPE, ``energy`` (m, 3) float64, each C-contiguous) bound to ``o`` for m
    rows, ``o.count = 0``; ValueError if they are not that."""
    cdef cnp.ndarray t = bufs["t"], tr = bufs["trackers"], en = bufs["energy"]
    m = t.shape[0] if t.ndim == 1 else -1
    if not (t.dtype == np.int64 and tr.dtype == TRACK_DTYPE and en.dtype == np.float64
            and tr.ndim == 2 and tr.shape[0] == m and tr.shape[1] == n and en.ndim == 2
            and en.shape[0] == m and en.shape[1] == 3 and t.flags.c_contiguous
            and tr.flags.c_contiguous and en.flags.c_contiguous):
        raise ValueError(f"sample buffers must be C-contiguous t (m,) int64, trackers "
                         f"(m, {n}) TRACK_DTYPE and energy (m, 3) float64")
    o.cap = m
    o.count = 0
    o.t = <int64_t*>cnp.PyArray_DATA(t)
    o.trackers = <TrackRow*>cnp.PyArray_DATA(tr)
    o.energy = <double*>cnp.PyArray_DATA(en)
    o.wire = NULL
    return {"t": t, "trackers": tr, "energy": en}


cdef dict take_samples(dict bufs, SampleOut* o, bint copy):
    """The ``o.count`` rows written so far (copies, or views of the buffers); ``o.count = 0``."""
    c = o.count
    out = {k: (_rows_copy(v[:c]) if copy else v[:c]) for k, v in bufs.items()}
    o.count = 0
    return out


def finite_rows(trackers):
    """(rows,) bool: every float field of every tracker of the row is finite.
    ``trackers``: (rows, n) springtrack.track.TRACK_DTYPE (the float fields: TrackRow's
    doubles)."""
    cdef cnp.ndarray a = np.ascontiguousarray(trackers)
    if a.dtype != TRACK_DTYPE or a.ndim != 2:
        raise TypeError(f"finite_rows takes (rows, trackers) {TRACK_DTYPE}, not "
                        f"{a.ndim}-d {a.dtype}")
    cdef Py_ssize_t rows = a.shape[0], n = a.shape[1], i, k
    cdef const TrackRow* r = <const TrackRow*>cnp.PyArray_DATA(a)
    ok = np.ones(rows, np.bool_)
    cdef uint8_t[::1] o = ok.view(np.uint8)
    cdef const TrackRow* q
    with nogil:
        for i in range(rows):
            for k in range(n):
                q = &r[i * n + k]
                if not (isfinite(q.x) and isfinite(q.y) and isfinite(q.sxx)
                        and isfinite(q.sxy) and isfinite(q.syy) and isfinite(q.activity)
                        and isfinite(q.vx) and isfinite(q.vy)):
                    o[i] = 0
                    break
    return ok
