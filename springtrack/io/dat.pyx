"""Prophesee DAT (CD events): streaming decoder and encoder (docs/formats.md#dat).

After the ``% `` header and two bytes (event type, event size = 8) come 8-byte records:
uint32 LE timestamp (us), uint32 LE data with x in bits 13..0, y in 27..14, p in 31..28.
A timestamp below the previous one by more than 2**31 is a wrap of the 32-bit counter
(+2**32 us); a smaller step back is counted ('time_backwards') and kept as read.
p > 1 is counted as 'unknown_type' and the record dropped.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.events import as_events

cnp.import_array()


cdef class DatDecoder(Decoder):
    cdef int64_t epoch
    cdef int64_t last_raw

    def __init__(self, int width=0, int height=0):
        self._setup("dat", 8, 1, 8, width, height, False)
        self.last_raw = -1

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i, nw = n >> 3, k = nout[0]
        cdef uint32_t ts, data, x, y, pol
        cdef uint32_t W = self.width if self.width else 0x10000
        cdef uint32_t H = self.height if self.height else 0x10000
        if nw > cap - k:
            nw = cap - k
        for i in range(nw):
            memcpy(&ts, p + 8 * i, 4)
            memcpy(&data, p + 8 * i + 4, 4)
            if <int64_t>ts < self.last_raw:
                if self.last_raw - ts > (<int64_t>1 << 31):
                    self.epoch += <int64_t>1 << 32
                    self.info[<int>IN_TIME_WRAPS] += 1
                else:
                    self.anomalies[<int>AN_TIME_BACKWARDS] += 1
            self.last_raw = ts
            x = data & 0x3FFF
            y = (data >> 14) & 0x3FFF
            pol = data >> 28
            if pol > 1:
                self.anomalies[<int>AN_UNKNOWN_TYPE] += 1
                continue
            if x >= W or y >= H:
                self.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                continue
            put_event(&out[k], self.epoch + ts, x, y, pol)
            k += 1
        self.words += nw
        nout[0] = k
        return nw * 8


def encode(events) -> bytes:
    """DAT records (no header) for events with 0 <= t < 2**32 and x, y < 16384."""
    ev = as_events(events)
    if len(ev) == 0:
        return b""
    t = ev["t"]
    if t.min() < 0 or t.max() >= 1 << 32:
        raise ValueError("dat encode: timestamps must be in [0, 2**32) us")
    if ev["x"].max() >= 1 << 14 or ev["y"].max() >= 1 << 14:
        raise ValueError("dat encode: x and y must be < 16384 (14 bits)")
    rec = np.empty((len(ev), 2), dtype="<u4")
    rec[:, 0] = t
    rec[:, 1] = (ev["x"].astype(np.uint32) | (ev["y"].astype(np.uint32) << 14)
                 | ((ev["p"] != 0).astype(np.uint32) << 28))
    return rec.tobytes()
