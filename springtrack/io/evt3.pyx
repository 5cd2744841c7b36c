"""Prophesee RAW EVT 3.0: streaming decoder and a simple encoder (docs/formats.md#prophesee-raw-evt-30).

Word types and fields: evt3_types.h.  The decoder is a state machine over the current row
(EVT_ADDR_Y), vector base and polarity (VECT_BASE_X) and time (EVT_TIME_HIGH through the
time base of every decoder, timebase.pxd; EVT_TIME_LOW taken as read).
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.io.base import encoder_input

cnp.import_array()

MAX_COORD = 2048          # 11-bit x and y


cdef class Evt3Decoder(Decoder):
    """The EVT 3.0 state machine (evt3.pxd) as a streaming :class:`Decoder`."""

    def __init__(self, int width=0, int height=0):
        self._setup("evt3", EVT3_WORD_BYTES, EVT3_MAX_EVENTS_PER_WORD, EVT3_WORD_BYTES,
                    width, height, False)
        evt3_init(&self.st, width, height)

    cdef void _reset_state(self) noexcept:
        pass   # time base and addresses legitimately persist; only the carry is dropped

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        return (evt3_decode_words(&self.st, &self.n, p, n // EVT3_WORD_BYTES, out, nout, cap)
                * EVT3_WORD_BYTES)


def encode(events, prev_t=None) -> bytes:
    """EVT 3.0 words (no header) for time-sorted events, one EVT_ADDR_X per event.

    Emits EVT_TIME_HIGH / EVT_TIME_LOW / EVT_ADDR_Y only when they change.  Timestamps must
    be >= 0 and non-decreasing; x, y <= 2047.  (No vectors: the decoder's vector path is
    tested with hand-built words and the real recording.)
    ``prev_t``: the time of the last event of a stream these words continue (its decoder's
    time base is then that event's time-high, not 0), e.g. a camera's stream encoded chunk
    by chunk; None: the stream starts here.
    """
    ev = encoder_input(events, "evt3", MAX_COORD, MAX_COORD, prev_t)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    t = ev["t"]
    # Gaps of half the 12-bit EVT_TIME_HIGH range or more get bridging EVT_TIME_HIGH words
    # so the decoder never mistakes them for a wrap.
    th_all = t >> EVT3_TH_SHIFT
    cdef int64_t start = 0 if prev_t is None else prev_t >> EVT3_TH_SHIFT
    dth = np.diff(th_all, prepend=start)
    cdef int64_t step = (1 << (EVT3_TH_BITS - 1)) - 1
    words = np.empty(4 * n + int(np.maximum(dth - 1, 0).__floordiv__(step).sum()) + 1, dtype="<u2")
    cdef uint16_t[::1] w = words
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t th = start, tl = -1, y = -1, h, l  # the decoder's time-high: 0 at the start
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
