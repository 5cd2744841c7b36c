"""Prophesee RAW EVT 2.0: streaming decoder and encoder (docs/formats.md#evt-20).

Little-endian 32-bit words, type in bits 31..28:
0x0 CD_OFF / 0x1 CD_ON  -> t low 6 bits in 27..22, x in 21..11, y in 10..0
0x8 EVT_TIME_HIGH       -> t >> 6 in 27..0 (28 bits; wraps every 2**34 us)
0xA EXT_TRIGGER, 0xE OTHERS, 0xF CONTINUED -> counted, not decoded
anything else           -> anomaly 'unknown_type', word skipped
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.io.base import encoder_input
from springtrack.events import EVENT_DTYPE

cdef extern from "springtrack/io/evt2_block.h" nogil:
    enum:
        EVT2_BLOCK
    int evt2_decode_plain(const uint8_t* p, int n, int64_t th, uint32_t width,
                          uint32_t height, void* out)

cnp.import_array()

cdef enum:
    TH_BITS = 28


cdef class Evt2Decoder(Decoder):
    cdef int64_t th_last      # last raw 28-bit time-high value
    cdef int64_t epoch        # added to raw time-high (wraps, backward-jump rebases)
    cdef bint have_th

    def __init__(self, int width=0, int height=0):
        self._setup("evt2", 4, 1, 4, width, height, False)

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i = 0, nw = n >> 2, k = nout[0]
        cdef Py_ssize_t room = cap - k
        cdef uint32_t v, typ, x, y
        cdef uint32_t W = self.width if self.width else 0x10000
        cdef uint32_t H = self.height if self.height else 0x10000
        cdef int64_t th = (self.epoch + self.th_last) << 6, raw
        cdef bint have_th = self.have_th
        cdef uint64_t before = 0       # events before the first TIME_HIGH
        if nw > room:
            nw = room
        while i < nw:
            # a block of plain CD words at once (evt2_block.h), else word by word up to the
            # next block boundary; the block never writes past out[cap): k <= k0 + i
            if i & (EVT2_BLOCK - 1) == 0:
                if (i + EVT2_BLOCK <= nw and have_th
                        and evt2_decode_plain(p + 4 * i, EVT2_BLOCK, th, W, H, &out[k])):
                    k += EVT2_BLOCK
                    i += EVT2_BLOCK
                    continue
            memcpy(&v, p + 4 * i, 4)   # little-endian host assumed (x86, ARM)
            i += 1
            typ = v >> 28
            if typ <= 1:               # CD_OFF / CD_ON
                x = (v >> 11) & 0x7FF
                y = v & 0x7FF
                if x >= W or y >= H:
                    self.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                    continue
                put_event(&out[k], th | ((v >> 22) & 0x3F), x, y, typ)
                k += 1
                before += not have_th
            elif typ == 0x8:           # EVT_TIME_HIGH
                raw = v & 0x0FFFFFFF
                self.info[<int>IN_TIME_HIGH] += 1
                if have_th and raw < self.th_last:
                    if self.th_last - raw > (1 << (TH_BITS - 1)):   # counter wrapped
                        self.epoch += 1 << TH_BITS
                        self.info[<int>IN_TIME_WRAPS] += 1
                    else:                                          # jumped back: rebase
                        self.epoch += self.th_last - raw
                        self.anomalies[<int>AN_TIME_BACKWARDS] += 1
                self.th_last = raw
                have_th = True
                th = (self.epoch + raw) << 6
            elif typ == 0xA:
                self.info[<int>IN_TRIGGERS] += 1
            elif typ == 0xE or typ == 0xF:
                self.info[<int>IN_OTHERS] += 1
            else:
                self.anomalies[<int>AN_UNKNOWN_TYPE] += 1
        self.have_th = have_th
        self.info[<int>IN_BEFORE_TIME_HIGH] += before
        self.words += i
        nout[0] = k
        return i * 4


def encode(events) -> bytes:
    """EVT 2.0 words (no header) for time-sorted events; exact inverse of the decoder.

    Emits a TIME_HIGH word whenever t >> 6 changes.  Raises ValueError for negative or
    decreasing timestamps or coordinates above 2047.
    """
    ev = encoder_input(events, "evt2", 2048, 2048)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    t = ev["t"]
    th = t >> 6
    # A TIME_HIGH word per change of t >> 6; gaps of half the 28-bit range or more get
    # bridging TIME_HIGH words so the decoder never mistakes them for a wrap.
    dth = np.diff(th, prepend=0)
    cdef int64_t step = (1 << (TH_BITS - 1)) - 1
    cdef Py_ssize_t total = n + 1 + int((dth > 0).sum()) + int(np.maximum(dth - 1, 0).__floordiv__(step).sum())
    words = np.empty(total, dtype="<u4")
    cdef uint32_t[::1] w = words
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t cur = 0, h       # the decoder starts from time-high 0
    cdef bint first = True
    with nogil:
        for i in range(n):
            h = e[i].t >> 6
            if h != cur or first:
                first = False
                while h - cur > step:
                    cur += step
                    w[j] = (<uint32_t>0x8 << 28) | <uint32_t>(cur & 0x0FFFFFFF)
                    j += 1
                w[j] = (<uint32_t>0x8 << 28) | <uint32_t>(h & 0x0FFFFFFF)
                j += 1
                cur = h
            w[j] = ((<uint32_t>(e[i].p != 0)) << 28) | (<uint32_t>(e[i].t & 0x3F) << 22) \
                | (<uint32_t>e[i].x << 11) | <uint32_t>e[i].y
            j += 1
    return words[:j].tobytes()
