"""Prophesee RAW EVT 2.0: streaming decoder and encoder (docs/formats.md#prophesee-raw-evt-20).

Word types and fields: evt2_types.h (CD_OFF / CD_ON events, EVT_TIME_HIGH, EXT_TRIGGER,
OTHERS / CONTINUED counted, anything else 'unknown_type').  The EVT_TIME_HIGH counter goes
through the time base of every decoder (timebase.pxd).
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.io.base import encoder_input
from springtrack.io.timebase cimport (TimeBase, timebase_init, timebase_known,
                                      timebase_count, timebase_update)

cdef extern from "springtrack/io/evt2_types.h" nogil:
    enum Evt2EventTypes:
        EVT2_CD_OFF
        EVT2_CD_ON
        EVT2_EVT_TIME_HIGH
        EVT2_EXT_TRIGGER
        EVT2_OTHERS
        EVT2_CONTINUED
    enum:
        EVT2_TH_BITS
        EVT2_TH_SHIFT
    uint32_t evt2_type(uint32_t v)
    uint32_t evt2_x(uint32_t v)
    uint32_t evt2_y(uint32_t v)
    uint32_t evt2_t_low(uint32_t v)
    uint32_t evt2_time_high(uint32_t v)
    uint32_t evt2_time_high_word(uint32_t count)
    uint32_t evt2_cd_word(uint32_t pol, uint32_t t_low, uint32_t x, uint32_t y)

cdef extern from "springtrack/io/evt2_block.h" nogil:
    enum:
        EVT2_BLOCK
    int evt2_decode_plain(const uint8_t* p, int n, int64_t th, uint32_t width,
                          uint32_t height, void* out)

cnp.import_array()

MAX_COORD = 2048          # 11-bit x and y


cdef class Evt2Decoder(Decoder):
    cdef TimeBase tb          # the EVT_TIME_HIGH counter

    def __init__(self, int width=0, int height=0):
        self._setup("evt2", 4, 1, 4, width, height, False)
        timebase_init(&self.tb)

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i = 0, nw = n >> 2, k = nout[0]
        cdef Py_ssize_t room = cap - k
        cdef uint32_t v, typ, x, y
        cdef uint32_t W = self.width if self.width else ANY_COORD
        cdef uint32_t H = self.height if self.height else ANY_COORD
        cdef TimeBase tb = self.tb
        cdef int64_t th = timebase_count(&tb) << EVT2_TH_SHIFT
        cdef bint have_th = timebase_known(&tb)
        cdef uint64_t before = 0       # events before the first EVT_TIME_HIGH
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
            typ = evt2_type(v)
            if typ == EVT2_CD_OFF or typ == EVT2_CD_ON:
                x = evt2_x(v)
                y = evt2_y(v)
                if x >= W or y >= H:
                    self.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                    continue
                put_event(&out[k], th | evt2_t_low(v), x, y, typ)
                k += 1
                before += not have_th
            elif typ == EVT2_EVT_TIME_HIGH:
                self.info[<int>IN_TIME_HIGH] += 1
                th = timebase_update(&tb, evt2_time_high(v), EVT2_TH_BITS) << EVT2_TH_SHIFT
                have_th = True
            elif typ == EVT2_EXT_TRIGGER:
                self.info[<int>IN_TRIGGERS] += 1
            elif typ == EVT2_OTHERS or typ == EVT2_CONTINUED:
                self.info[<int>IN_OTHERS] += 1
            else:
                self.anomalies[<int>AN_UNKNOWN_TYPE] += 1
        self.tb = tb
        self._count_time(&tb)
        self.info[<int>IN_BEFORE_TIME_HIGH] += before
        self.words += i
        nout[0] = k
        return i * 4


def encode(events) -> bytes:
    """EVT 2.0 words (no header) for time-sorted events; exact inverse of the decoder.

    Emits an EVT_TIME_HIGH word whenever t >> 6 changes.  Raises ValueError for negative or
    decreasing timestamps or coordinates above 2047.
    """
    ev = encoder_input(events, "evt2", MAX_COORD, MAX_COORD)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    t = ev["t"]
    th = t >> EVT2_TH_SHIFT
    # An EVT_TIME_HIGH word per change of t >> 6; gaps of half the 28-bit range or more get
    # bridging EVT_TIME_HIGH words so the decoder never mistakes them for a wrap.
    dth = np.diff(th, prepend=0)
    cdef int64_t step = (1 << (EVT2_TH_BITS - 1)) - 1
    cdef Py_ssize_t total = n + 1 + int((dth > 0).sum()) + int(np.maximum(dth - 1, 0).__floordiv__(step).sum())
    words = np.empty(total, dtype="<u4")
    cdef uint32_t[::1] w = words
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t cur = 0, h       # the decoder starts from time-high 0
    cdef bint first = True
    with nogil:
        for i in range(n):
            h = e[i].t >> EVT2_TH_SHIFT
            if h != cur or first:
                first = False
                while h - cur > step:
                    cur += step
                    w[j] = evt2_time_high_word(<uint32_t>cur)
                    j += 1
                w[j] = evt2_time_high_word(<uint32_t>h)
                j += 1
                cur = h
            w[j] = evt2_cd_word(e[i].p != 0, <uint32_t>e[i].t, e[i].x, e[i].y)
            j += 1
    return words[:j].tobytes()
