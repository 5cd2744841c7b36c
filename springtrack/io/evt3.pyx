"""Prophesee RAW EVT 3.0: streaming decoder and a simple encoder (docs/formats.md#evt-30).

Little-endian 16-bit words, type in bits 15..12:
0x0 EVT_ADDR_Y   y in 10..0 (bit 11: system type, ignored); sets the current row
0x2 EVT_ADDR_X   p in 11, x in 10..0: one CD event at (x, row, t)
0x3 VECT_BASE_X  p in 11, x in 10..0: base column and polarity of following vectors
0x4 VECT_12      bit i of 11..0 set -> event at base + i; base += 12
0x5 VECT_8       bit i of 7..0 set  -> event at base + i; base += 8
0x6 TIME_LOW     t bits 11..0
0x8 TIME_HIGH    t bits 23..12 (the 24-bit time wraps every 2**24 us, ~16.8 s)
0x7 CONTINUED_4, 0xA EXT_TRIGGER, 0xE OTHERS, 0xF CONTINUED_12 -> counted
0x1, 0x9, 0xB, 0xC, 0xD -> anomaly 'unknown_type'
Time high going back by more than half its range is a wrap (+2**24 us); a smaller step
back is the anomaly 'time_backwards' and is rebased so time stays monotonic.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.io.base import encoder_input
from springtrack.events import EVENT_DTYPE

cnp.import_array()

cdef extern from *:
    int __builtin_ctz(unsigned int) nogil


cdef class Evt3Decoder(Decoder):
    cdef int64_t th_last, epoch, tl
    cdef int64_t t_low_last   # timestamp set by the last TIME_LOW word
    cdef bint have_th
    cdef int y            # current row, -1 before the first EVT_ADDR_Y
    cdef int base_x       # vector base column, -1 before the first VECT_BASE_X
    cdef uint8_t vec_p

    def __init__(self, int width=0, int height=0):
        self._setup("evt3", 2, 12, 2, width, height, False)
        self.y = -1
        self.base_x = -1

    cdef void _reset_state(self) noexcept:
        pass   # time base and addresses legitimately persist; only the carry is dropped

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i = 0, nw = n >> 1, k = nout[0], stop = cap - 12
        cdef uint16_t v
        cdef uint32_t typ, x, m
        cdef int b
        cdef uint32_t W = self.width if self.width else 0x10000
        cdef uint32_t H = self.height if self.height else 0x10000
        # the time state in locals for the loop (written back after it): kept in the object,
        # every TIME_LOW word's load and store of t_low_last would chain through memory
        cdef int64_t epoch = self.epoch, th_last = self.th_last, tl = self.tl
        cdef int64_t t_low_last = self.t_low_last
        cdef int64_t raw, t = ((epoch + th_last) << 12) | tl
        cdef int y = self.y, base = self.base_x
        cdef uint8_t vp = self.vec_p
        cdef bint have_th = self.have_th
        cdef uint64_t before = 0       # events before the first TIME_HIGH
        while i < nw and k <= stop:
            memcpy(&v, p + 2 * i, 2)   # little-endian host assumed
            i += 1
            typ = v >> 12
            if typ == 0x2:             # EVT_ADDR_X: one event
                x = v & 0x7FF
                if y < 0:
                    self.anomalies[<int>AN_ORPHAN] += 1
                elif x >= W or <uint32_t>y >= H:
                    self.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                else:
                    put_event(&out[k], t, x, y, (v >> 11) & 1)
                    k += 1
                    before += not have_th
            elif typ == 0x0:           # EVT_ADDR_Y
                y = v & 0x7FF
            elif typ == 0x4 or typ == 0x5:   # VECT_12 / VECT_8
                m = v & (0xFFF if typ == 0x4 else 0xFF)
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
                base += 12 if typ == 0x4 else 8
                if base > 0xFFFF:
                    base = 0xFFFF
            elif typ == 0x3:           # VECT_BASE_X
                base = v & 0x7FF
                vp = (v >> 11) & 1
            elif typ == 0x6:           # TIME_LOW
                tl = v & 0xFFF
                raw = ((epoch + th_last) << 12) | tl
                if raw < t_low_last:        # real sensors jitter by a few us: kept, counted
                    self.info[<int>IN_TIME_LOW_BACK] += 1
                t_low_last = raw
                t = raw
            elif typ == 0x8:           # TIME_HIGH
                raw = v & 0xFFF
                self.info[<int>IN_TIME_HIGH] += 1
                if have_th and raw < th_last:
                    if th_last - raw > 2048:         # 12-bit counter wrapped
                        epoch += 4096
                        self.info[<int>IN_TIME_WRAPS] += 1
                    else:                           # jumped back: rebase
                        epoch += th_last - raw
                        self.anomalies[<int>AN_TIME_BACKWARDS] += 1
                th_last = raw
                have_th = True
                t = ((epoch + raw) << 12) | tl
            elif typ == 0xA:
                self.info[<int>IN_TRIGGERS] += 1
            elif typ == 0x7 or typ == 0xE or typ == 0xF:
                self.info[<int>IN_OTHERS] += 1
            else:
                self.anomalies[<int>AN_UNKNOWN_TYPE] += 1
        self.have_th = have_th
        self.epoch = epoch
        self.th_last = th_last
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

    Emits TIME_HIGH / TIME_LOW / EVT_ADDR_Y only when they change.  Timestamps must be
    >= 0 and non-decreasing; x, y <= 2047.  (No vectors: the decoder's vector path is
    tested with hand-built words and the real recording.)
    """
    ev = encoder_input(events, "evt3", 2048, 2048)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    t = ev["t"]
    # Gaps of half the 12-bit TIME_HIGH range or more get bridging TIME_HIGH words so the
    # decoder never mistakes them for a wrap.
    th_all = t >> 12
    dth = np.diff(th_all, prepend=0)
    cdef int64_t step = 2047
    words = np.empty(4 * n + int(np.maximum(dth - 1, 0).__floordiv__(step).sum()) + 1, dtype="<u2")
    cdef uint16_t[::1] w = words
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t th = 0, tl = -1, y = -1, h, l     # the decoder starts from time-high 0
    cdef bint first = True
    with nogil:
        for i in range(n):
            h = (e[i].t >> 12) & 0xFFF
            l = e[i].t & 0xFFF
            if (e[i].t >> 12) != th or first:
                first = False
                while (e[i].t >> 12) - th > step:
                    th += step
                    w[j] = <uint16_t>((0x8 << 12) | (th & 0xFFF))
                    j += 1
                w[j] = <uint16_t>((0x8 << 12) | h)
                j += 1
                th = e[i].t >> 12
                tl = -1
            if l != tl:
                w[j] = <uint16_t>((0x6 << 12) | l)
                j += 1
                tl = l
            if e[i].y != y:
                w[j] = <uint16_t>e[i].y
                j += 1
                y = e[i].y
            w[j] = <uint16_t>((0x2 << 12) | ((e[i].p != 0) << 11) | e[i].x)
            j += 1
    return words[:j].tobytes()
