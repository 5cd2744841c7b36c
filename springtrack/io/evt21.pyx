"""Prophesee RAW EVT 2.1: streaming decoder and encoder (layout in evt21.pxd,
docs/formats.md#evt-21).

The per-word decoding lives in ``evt21.pxd`` as inline nogil functions over a state struct
so a fused firmware loop can call it; this module wraps it as a :class:`Decoder` and adds
:func:`encode`, which groups events the way the sensor does (same time, row and polarity,
one 32-pixel column group) so that decoding gives back the same events in the same order.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
cimport numpy as cnp
import numpy as np

from springtrack.io.base import encoder_input

cnp.import_array()

WORD_BYTES = EVT21_WORD_BYTES
MAX_COORD = 1 << 11                   # x and y are 11-bit fields: sensors up to 2048 x 2048


cdef class Evt21Decoder(Decoder):
    """The EVT 2.1 state machine (evt21.pxd) as a streaming :class:`Decoder`
    (``legacy=True``: the IMX636's word order, 32-bit halves swapped)."""

    def __init__(self, int width=0, int height=0, bint legacy=False):
        self._setup("evt21", EVT21_WORD_BYTES, EVT21_MAX_PER_WORD, 4, width, height, False)
        evt21_init(&self.st, width, height, legacy)

    @property
    def legacy(self):
        return bool(self.st.legacy)

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        return (evt21_decode_words(&self.st, &self.n, p, n // EVT21_WORD_BYTES, out, cap, nout)
                * EVT21_WORD_BYTES)


def encode(events, bint legacy=False, prev_t=None) -> bytes:
    """EVT 2.1 words (no header) for time-sorted events; decoding gives them back exactly.

    A TIME_HIGH word whenever t >> 6 changes.  Across a gap of half the 28-bit range or
    more, bridging TIME_HIGH words at most that far apart, so the decoder never takes the
    gap for a wrap; across a wrap of the 28-bit counter, TIME_HIGH 2**28 - 1 then 0, the
    only wrap OpenEB's decoder recognises.  Consecutive events with the same t, y and p and
    increasing x inside one 32-column group [32 j, 32 j + 32) share a word (x base 32 j), as
    the sensor sends them.  ``legacy``: the IMX636 order.  Raises ValueError for negative or
    decreasing timestamps or coordinates above 2047.
    ``prev_t``: the time of the last event of a stream these words continue (its decoder's
    time base is then that event's time-high, not 0), e.g. a camera's stream encoded chunk
    by chunk; None: the stream starts here.
    """
    ev = encoder_input(events, "evt21", MAX_COORD, MAX_COORD, prev_t)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    th = ev["t"] >> EVT21_TH_SHIFT
    cdef int64_t start = 0 if prev_t is None else prev_t >> EVT21_TH_SHIFT
    dth = np.diff(th, prepend=start)
    cdef int64_t step = (1 << (EVT21_TH_BITS - 1)) - 1
    cdef Py_ssize_t total = (n + 1 + int((dth > 0).sum())
                             + int(np.maximum(dth - 1, 0).__floordiv__(step).sum())
                             + 2 * int(th[-1] >> EVT21_TH_BITS) + 2)
    words = np.empty(total, dtype="<u8")
    cdef uint64_t[::1] w = words
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t cur = start, h, t = -1, wrap   # the decoder's time-high: 0 at the start
    cdef uint32_t x, y = 0, group = 0, last_x = 0, pol = 0
    cdef bint first = True, open_word = False
    with nogil:
        for i in range(n):
            h = e[i].t >> EVT21_TH_SHIFT
            if h != cur or first:
                first = False
                open_word = False
                while h - cur > step or h >> EVT21_TH_BITS != cur >> EVT21_TH_BITS:
                    wrap = ((cur >> EVT21_TH_BITS) + 1) << EVT21_TH_BITS
                    if cur + step < wrap:
                        cur += step
                    else:                        # the counter's last value, then 0
                        w[j] = evt21_time_high_word(wrap - 1)
                        j += 1
                        cur = wrap
                    w[j] = evt21_time_high_word(cur)
                    j += 1
                if cur != h or j == 0:
                    w[j] = evt21_time_high_word(h)
                    j += 1
                    cur = h
            x = e[i].x
            if (open_word and e[i].t == t and e[i].y == y and (e[i].p != 0) == pol
                    and x >> EVT21_GROUP_BITS == group and x > last_x):
                w[j - 1] |= <uint64_t>1 << (x - (group << EVT21_GROUP_BITS))
            else:
                t = e[i].t
                y = e[i].y
                pol = e[i].p != 0
                group = x >> EVT21_GROUP_BITS
                w[j] = evt21_cd_word(pol, <uint32_t>t, group << EVT21_GROUP_BITS, y,
                                     <uint32_t>1 << (x - (group << EVT21_GROUP_BITS)))
                j += 1
                open_word = True
            last_x = x
    if legacy:
        with nogil:
            for i in range(j):
                w[i] = evt21_swap(w[i])
    return words[:j].tobytes()
