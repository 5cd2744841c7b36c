"""Prophesee DAT (CD events): streaming decoder and encoder (docs/formats.md#prophesee-dat).

After the ``% `` header and two bytes (event type, event size = 8) come 8-byte records:
uint32 LE timestamp (us), uint32 LE data with x in bits 13..0, y in 27..14, p in 31..28.
The timestamp is a 32-bit counter of 1 us and goes through the time base of every decoder
(timebase.pxd: wraps add 2**32 us, a step back is rebased).  p > 1 is counted as
'unknown_type' and the record dropped.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.events import as_events
from springtrack.io.timebase cimport TimeBase, timebase_init, timebase_update

cnp.import_array()

cdef enum:                 # the record layout
    DAT_RECORD_BYTES = 8   # uint32 timestamp, uint32 data
    DAT_T_BITS = 32        # the timestamp counter, 1 us
    DAT_COORD_BITS = 14    # x in data bits 13..0, y in 27..14
    DAT_COORD_MASK = (1 << DAT_COORD_BITS) - 1
    DAT_Y_SHIFT = DAT_COORD_BITS
    DAT_POL_SHIFT = 28     # p in data bits 31..28: 0 or 1, else 'unknown_type'
    DAT_POL_ON = 1


cdef class DatDecoder(Decoder):
    cdef TimeBase tb          # the timestamp counter

    def __init__(self, int width=0, int height=0):
        self._setup("dat", DAT_RECORD_BYTES, 1, DAT_RECORD_BYTES, width, height, False)
        timebase_init(&self.tb)

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i, nw = n // DAT_RECORD_BYTES, k = nout[0]
        cdef uint32_t ts, data, x, y, pol
        cdef uint32_t W = geometry_bound(self.width)
        cdef uint32_t H = geometry_bound(self.height)
        cdef TimeBase tb = self.tb
        cdef int64_t t
        if nw > cap - k:
            nw = cap - k
        for i in range(nw):
            memcpy(&ts, p + DAT_RECORD_BYTES * i, 4)
            memcpy(&data, p + DAT_RECORD_BYTES * i + 4, 4)
            t = timebase_update(&tb, ts, DAT_T_BITS)
            x = data & DAT_COORD_MASK
            y = (data >> DAT_Y_SHIFT) & DAT_COORD_MASK
            pol = data >> DAT_POL_SHIFT
            if pol > DAT_POL_ON:
                self.n.anomalies[<int>AN_UNKNOWN_TYPE] += 1
                continue
            if x >= W or y >= H:
                self.n.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                continue
            put_event(&out[k], t, x, y, pol)
            k += 1
        self.tb = tb
        count_time(&self.n, &tb)
        self.n.words += nw
        nout[0] = k
        return nw * DAT_RECORD_BYTES


def encode(events) -> bytes:
    """DAT records (no header) for events with 0 <= t < 2**32 and x, y < 16384."""
    ev = as_events(events)
    if len(ev) == 0:
        return b""
    t = ev["t"]
    if t.min() < 0 or t.max() >= (<int64_t>1) << DAT_T_BITS:
        raise ValueError("dat encode: timestamps must be in [0, 2**32) us")
    if ev["x"].max() >= 1 << DAT_COORD_BITS or ev["y"].max() >= 1 << DAT_COORD_BITS:
        raise ValueError("dat encode: x and y must be < 16384 (14 bits)")
    rec = np.empty((len(ev), 2), dtype="<u4")
    rec[:, 0] = t
    rec[:, 1] = (ev["x"].astype(np.uint32) | (ev["y"].astype(np.uint32) << DAT_Y_SHIFT)
                 | ((ev["p"] != 0).astype(np.uint32) << DAT_POL_SHIFT))
    return rec.tobytes()
