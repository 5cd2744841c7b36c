# cython: language_level=3
"""Snapshot buffers shared by the tracker kernels and the firmware's fused loop."""
import numpy as np
cimport numpy as cnp
from springtrack.wire import TELE_TRACKER, quantise_trackers
from libc.stdint cimport int64_t, uint8_t

cnp.import_array()

TELE_RECORD = TELE_TRACKER.itemsize      # bytes per tracker record


cdef dict sample_buffers(Py_ssize_t cap, int n, SampleOut* o, bint records=False,
                         bint native=False):
    """Arrays for ``cap`` snapshot rows of ``n`` trackers (keys as the Track fields, plus
    ``t`` and ``energy``), bound to ``o`` with ``o.count = 0``.  With ``records`` the rows
    taken by :func:`take_samples` also carry ``wire``, their TELEMETRY records: packed by
    the kernel's snapshot itself when it can (``native``, the Stepper's wire_records),
    else quantised from the float rows."""
    b = dict(t=np.empty(cap, np.int64), x=np.empty((cap, n)), y=np.empty((cap, n)),
             sxx=np.empty((cap, n)), sxy=np.empty((cap, n)), syy=np.empty((cap, n)),
             activity=np.empty((cap, n)), active=np.empty((cap, n), np.uint8),
             sensitive=np.empty((cap, n), np.uint8), energy=np.empty((cap, 3)))
    o.cap = cap
    o.count = 0
    o.t = <int64_t*>cnp.PyArray_DATA(b["t"])
    o.x = <double*>cnp.PyArray_DATA(b["x"])
    o.y = <double*>cnp.PyArray_DATA(b["y"])
    o.sxx = <double*>cnp.PyArray_DATA(b["sxx"])
    o.sxy = <double*>cnp.PyArray_DATA(b["sxy"])
    o.syy = <double*>cnp.PyArray_DATA(b["syy"])
    o.act = <double*>cnp.PyArray_DATA(b["activity"])
    o.active = <uint8_t*>cnp.PyArray_DATA(b["active"])
    o.sensitive = <uint8_t*>cnp.PyArray_DATA(b["sensitive"])
    o.energy = <double*>cnp.PyArray_DATA(b["energy"])
    o.wire = NULL
    o.quantise = records and not native
    if records and native:
        b["wire"] = np.empty((cap, n * TELE_RECORD), np.uint8)
        o.wire = <uint8_t*>cnp.PyArray_DATA(b["wire"])
    return b


cdef dict take_samples(dict bufs, SampleOut* o, bint copy):
    """The ``o.count`` rows written so far (copies, or views of the buffers) and
    ``o.count = 0``; with records, ``wire`` holds each row's TELEMETRY records."""
    c = o.count
    out = {k: (v[:c].copy() if copy else v[:c]) for k, v in bufs.items()}
    if o.quantise:
        out["wire"] = quantise_trackers(out).view(np.uint8)      # (c, n * 8)
    o.count = 0
    return out
