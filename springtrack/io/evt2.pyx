"""Prophesee RAW EVT 2.0: streaming decoder and encoder (docs/formats.md#prophesee-raw-evt-20).

Word types and fields: evt2_types.h (CD_OFF / CD_ON events, EVT_TIME_HIGH, EXT_TRIGGER,
OTHERS / CONTINUED counted, anything else 'unknown_type').  The EVT_TIME_HIGH counter goes
through the time base of every decoder (timebase.pxd).
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.io.base import encoder_input

cnp.import_array()

MAX_COORD = 2048          # 11-bit x and y


cdef class Evt2Decoder(Decoder):
    """The EVT 2.0 state machine (evt2.pxd) as a streaming :class:`Decoder`."""

    def __init__(self, int width=0, int height=0):
        self._setup("evt2", EVT2_WORD_BYTES, 1, EVT2_WORD_BYTES, width, height, False)
        evt2_init(&self.st, width, height)

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t nw = n // EVT2_WORD_BYTES
        if nw > cap - nout[0]:
            nw = cap - nout[0]
        return evt2_decode_words(&self.st, &self.n, p, nw, out, nout) * EVT2_WORD_BYTES


def encode(events, prev_t=None) -> bytes:
    """EVT 2.0 words (no header) for time-sorted events; exact inverse of the decoder.

    Emits an EVT_TIME_HIGH word whenever t >> 6 changes.  Raises ValueError for negative or
    decreasing timestamps or coordinates above 2047.
    ``prev_t``: the time of the last event of a stream these words continue (its decoder's
    time base is then that event's time-high, not 0), e.g. a camera's stream encoded chunk
    by chunk; None: the stream starts here.
    """
    ev = encoder_input(events, "evt2", MAX_COORD, MAX_COORD, prev_t)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    t = ev["t"]
    th = t >> EVT2_TH_SHIFT
    # An EVT_TIME_HIGH word per change of t >> 6; gaps of half the 28-bit range or more get
    # bridging EVT_TIME_HIGH words so the decoder never mistakes them for a wrap.
    cdef int64_t start = 0 if prev_t is None else prev_t >> EVT2_TH_SHIFT
    dth = np.diff(th, prepend=start)
    cdef int64_t step = (1 << (EVT2_TH_BITS - 1)) - 1
    cdef Py_ssize_t total = n + 1 + int((dth > 0).sum()) + int(np.maximum(dth - 1, 0).__floordiv__(step).sum())
    words = np.empty(total, dtype="<u4")
    cdef uint32_t[::1] w = words
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t cur = start, h   # the decoder's time-high: 0 at the stream start
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
