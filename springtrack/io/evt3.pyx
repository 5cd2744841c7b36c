"""Prophesee RAW EVT 3.0: streaming decoder and a simple encoder (docs/formats.md#prophesee-raw-evt-30).

Word types and fields: evt3_types.h.  The decoder is a state machine over the current row
(EVT_ADDR_Y), vector base and polarity (VECT_BASE_X) and time (EVT_TIME_HIGH through the
time base of every decoder, timebase.pxd; EVT_TIME_LOW taken as read).
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

cdef extern from "springtrack/io/evt3_types.h" nogil:
    enum Evt3EventTypes:
        EVT3_EVT_ADDR_Y
        EVT3_EVT_ADDR_X
        EVT3_VECT_BASE_X
        EVT3_VECT_12
        EVT3_VECT_8
        EVT3_EVT_TIME_LOW
        EVT3_CONTINUED_4
        EVT3_EVT_TIME_HIGH
        EVT3_EXT_TRIGGER
        EVT3_OTHERS
        EVT3_CONTINUED_12
    enum:
        EVT3_TH_BITS
        EVT3_TH_SHIFT
        EVT3_VECT_12_BITS
        EVT3_VECT_8_BITS
        EVT3_MAX_EVENTS_PER_WORD
    uint32_t evt3_type(uint16_t v)
    uint32_t evt3_coord(uint16_t v)
    uint32_t evt3_pol(uint16_t v)
    uint32_t evt3_time(uint16_t v)
    uint32_t evt3_vect_mask(uint16_t v, uint32_t bits)
    uint16_t evt3_word(uint32_t type, uint32_t payload)
    uint16_t evt3_addr_x_word(uint32_t pol, uint32_t x)

cnp.import_array()

cdef extern from *:
    int __builtin_ctz(unsigned int) nogil

MAX_COORD = 2048          # 11-bit x and y


cdef class Evt3Decoder(Decoder):
    cdef TimeBase tb          # the EVT_TIME_HIGH counter
    cdef int64_t tl           # last EVT_TIME_LOW value
    cdef int64_t t_low_last   # timestamp set by the last EVT_TIME_LOW word
    cdef int y                # current row, -1 before the first EVT_ADDR_Y
    cdef int base_x           # vector base column, -1 before the first VECT_BASE_X
    cdef uint8_t vec_p

    def __init__(self, int width=0, int height=0):
        self._setup("evt3", 2, EVT3_MAX_EVENTS_PER_WORD, 2, width, height, False)
        timebase_init(&self.tb)
        self.y = -1
        self.base_x = -1

    cdef void _reset_state(self) noexcept:
        pass   # time base and addresses legitimately persist; only the carry is dropped

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i = 0, nw = n >> 1, k = nout[0], stop = cap - EVT3_MAX_EVENTS_PER_WORD
        cdef uint16_t v
        cdef uint32_t typ, x, m
        cdef int b
        cdef uint32_t W = self.width if self.width else ANY_COORD
        cdef uint32_t H = self.height if self.height else ANY_COORD
        # the fine time in locals for the loop (written back after it): kept in the object,
        # every EVT_TIME_LOW word's load and store of t_low_last would chain through memory;
        # the time base, touched only by EVT_TIME_HIGH words, stays in the object
        cdef int64_t hi = timebase_count(&self.tb) << EVT3_TH_SHIFT, tl = self.tl
        cdef int64_t t_low_last = self.t_low_last
        cdef int64_t t = hi | tl
        cdef int y = self.y, base = self.base_x
        cdef uint8_t vp = self.vec_p
        cdef bint have_th = timebase_known(&self.tb)
        cdef uint64_t before = 0       # events before the first EVT_TIME_HIGH
        while i < nw and k <= stop:
            memcpy(&v, p + 2 * i, 2)   # little-endian host assumed
            i += 1
            typ = evt3_type(v)
            if typ == EVT3_EVT_ADDR_X:             # one event
                x = evt3_coord(v)
                if y < 0:
                    self.anomalies[<int>AN_ORPHAN] += 1
                elif x >= W or <uint32_t>y >= H:
                    self.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                else:
                    put_event(&out[k], t, x, y, evt3_pol(v))
                    k += 1
                    before += not have_th
            elif typ == EVT3_EVT_ADDR_Y:
                y = evt3_coord(v)
            elif typ == EVT3_VECT_12 or typ == EVT3_VECT_8:
                m = evt3_vect_mask(v, EVT3_VECT_12_BITS if typ == EVT3_VECT_12
                                   else EVT3_VECT_8_BITS)
                if y < 0 or base < 0:
                    self.anomalies[<int>AN_ORPHAN] += 1
                    continue
                while m:
                    b = __builtin_ctz(m)
                    m &= m - 1
                    x = <uint32_t>(base + b)
                    if x >= W or <uint32_t>y >= H:
                        self.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                        continue
                    put_event(&out[k], t, x, y, vp)
                    k += 1
                    before += not have_th
                base += EVT3_VECT_12_BITS if typ == EVT3_VECT_12 else EVT3_VECT_8_BITS
                if base >= ANY_COORD:
                    base = ANY_COORD - 1
            elif typ == EVT3_VECT_BASE_X:
                base = evt3_coord(v)
                vp = evt3_pol(v)
            elif typ == EVT3_EVT_TIME_LOW:
                tl = evt3_time(v)
                t = hi | tl
                if t < t_low_last:          # real sensors jitter by a few us: kept, counted
                    self.info[<int>IN_TIME_LOW_BACK] += 1
                t_low_last = t
            elif typ == EVT3_EVT_TIME_HIGH:
                self.info[<int>IN_TIME_HIGH] += 1
                hi = timebase_update(&self.tb, evt3_time(v), EVT3_TH_BITS) << EVT3_TH_SHIFT
                have_th = True
                t = hi | tl
            elif typ == EVT3_EXT_TRIGGER:
                self.info[<int>IN_TRIGGERS] += 1
            elif typ == EVT3_CONTINUED_4 or typ == EVT3_OTHERS or typ == EVT3_CONTINUED_12:
                self.info[<int>IN_OTHERS] += 1
            else:
                self.anomalies[<int>AN_UNKNOWN_TYPE] += 1
        self._count_time(&self.tb)
        self.tl = tl
        self.t_low_last = t_low_last
        self.info[<int>IN_BEFORE_TIME_HIGH] += before
        self.y = y
        self.base_x = base
        self.vec_p = vp
        self.words += i
        nout[0] = k
        return i * 2


def encode(events) -> bytes:
    """EVT 3.0 words (no header) for time-sorted events, one EVT_ADDR_X per event.

    Emits EVT_TIME_HIGH / EVT_TIME_LOW / EVT_ADDR_Y only when they change.  Timestamps must
    be >= 0 and non-decreasing; x, y <= 2047.  (No vectors: the decoder's vector path is
    tested with hand-built words and the real recording.)
    """
    ev = encoder_input(events, "evt3", MAX_COORD, MAX_COORD)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    t = ev["t"]
    # Gaps of half the 12-bit EVT_TIME_HIGH range or more get bridging EVT_TIME_HIGH words
    # so the decoder never mistakes them for a wrap.
    th_all = t >> EVT3_TH_SHIFT
    dth = np.diff(th_all, prepend=0)
    cdef int64_t step = (1 << (EVT3_TH_BITS - 1)) - 1
    words = np.empty(4 * n + int(np.maximum(dth - 1, 0).__floordiv__(step).sum()) + 1, dtype="<u2")
    cdef uint16_t[::1] w = words
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t th = 0, tl = -1, y = -1, h, l     # the decoder starts from time-high 0
    cdef bint first = True
    with nogil:
        for i in range(n):
            h = e[i].t >> EVT3_TH_SHIFT
            l = e[i].t & ((1 << EVT3_TH_SHIFT) - 1)
            if h != th or first:
                first = False
                while h - th > step:
                    th += step
                    w[j] = evt3_word(EVT3_EVT_TIME_HIGH, <uint32_t>th)
                    j += 1
                w[j] = evt3_word(EVT3_EVT_TIME_HIGH, <uint32_t>h)
                j += 1
                th = h
                tl = -1
            if l != tl:
                w[j] = evt3_word(EVT3_EVT_TIME_LOW, <uint32_t>l)
                j += 1
                tl = l
            if e[i].y != y:
                w[j] = evt3_word(EVT3_EVT_ADDR_Y, e[i].y)
                j += 1
                y = e[i].y
            w[j] = evt3_addr_x_word(e[i].p, e[i].x)
            j += 1
    return words[:j].tobytes()
