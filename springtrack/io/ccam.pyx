"""CCam ATIS USB words: streaming decoder and encoder (layout in ccam_types.h, docs/formats.md).

The per-word decoding lives in ``ccam.pxd`` as an inline nogil function so the firmware
simulator can fuse it into its own loop; this module wraps it as a :class:`Decoder` and
adds :func:`encode` (the simulated camera's output).
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.io.base import encoder_input

cnp.import_array()

WIDTH = CCAM_WIDTH
HEIGHT = CCAM_HEIGHT
TIME_HIGH_US = 1 << CCAM_TH_SHIFT


cdef class CCamDecoder(Decoder):
    """Change-detection events are returned; exposure events are counted and, with
    ``keep_exposure=True``, collected for :meth:`take_exposure`."""
    cdef CCamState st

    def __init__(self, bint keep_exposure=False, int width=CCAM_WIDTH, int height=CCAM_HEIGHT):
        if (width, height) != (CCAM_WIDTH, CCAM_HEIGHT):
            raise ValueError(f"ccam decoder: the CCam ATIS is {CCAM_WIDTH}x{CCAM_HEIGHT}, "
                             f"got {width}x{height}")
        self._setup("ccam", 4, 1, 4, CCAM_WIDTH, CCAM_HEIGHT, keep_exposure)
        ccam_init(&self.st)

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef CCamState st = self.st          # local copy: stays in registers
        cdef Py_ssize_t i, j, nw = n >> 2, k = nout[0], ks = nside[0]
        cdef int kind
        cdef Event e
        if nw > cap - k:
            nw = cap - k
        i = 0
        while i < nw:
            # a block of plain change-detection words at once (ccam_block.h), else word
            # by word; the block never writes past out[cap): k <= k0 + i, nw <= cap - k0
            if i + CCAM_BLOCK <= nw and ccam_decode_block(&st, &self.n, p + 4 * i, &out[k]):
                k += CCAM_BLOCK
                i += CCAM_BLOCK
                continue
            for j in range(i, min(i + CCAM_BLOCK, nw)):
                kind = ccam_decode_word(&st, &self.n, p + 4 * j, &e.t, &e.x, &e.y, &e.p)
                if kind == CCAM_CD:
                    out[k] = e
                    k += 1
                elif kind == CCAM_EXPOSURE and side != NULL:
                    side[ks] = e
                    ks += 1
            i += CCAM_BLOCK
        self.st = st
        nout[0] = k
        nside[0] = ks
        return nw * 4


def encode(events, exposure=None) -> bytes:
    """CCam ATIS words for time-sorted events (exact inverse of the decoder).

    A time-high word starts the stream and precedes every event whose t // 2048 us
    differs from the previous one.  ``exposure``: optional bool array marking
    exposure-measurement events (EM_OFF / EM_ON words).  Raises ValueError for negative or
    decreasing t, gaps of 2**23 time-high periods or more, x >= 304 or y >= 240.
    """
    ev = encoder_input(events, "ccam", CCAM_WIDTH, CCAM_HEIGHT)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0
    if n == 0:
        return b""
    t = ev["t"]
    th = t >> CCAM_TH_SHIFT
    if th[0] >= (1 << CCAM_TH_BITS):
        raise ValueError("ccam encode: the first timestamp must be below 2**24 * 2048 us "
                         "(the decoder starts from time-high 0)")
    if n > 1 and np.any(np.diff(th) >= (1 << (CCAM_TH_BITS - 1))):
        raise ValueError("ccam encode: a time gap of 2**23 time-high periods or more "
                         "cannot be represented (the decoder would see a wrap)")
    if exposure is None:
        flags = np.zeros(n, dtype=np.uint8)
    else:
        flags = np.ascontiguousarray(exposure, dtype=bool).view(np.uint8)
        if flags.shape[0] != n:
            raise ValueError(f"ccam encode: exposure has {flags.shape[0]} flags for {n} events")
    new_th = np.ones(n, dtype=bool)
    new_th[1:] = th[1:] != th[:n - 1]
    words = np.empty(n + int(new_th.sum()), dtype="<u4")
    cdef uint32_t[::1] w = words
    cdef const uint8_t[::1] fl = flags
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t cur = -1, h
    cdef uint32_t typ
    with nogil:
        for i in range(n):
            h = e[i].t >> CCAM_TH_SHIFT
            if h != cur:
                w[j] = ccam_time_high_word(<uint32_t>h)
                j += 1
                cur = h
            typ = CCAM_EM_OFF if fl[i] else CCAM_CD_OFF
            if e[i].p:
                typ |= CCAM_POLARITY_FLAG
            w[j] = ccam_event_word(typ, <uint32_t>e[i].t, e[i].x, CCAM_HEIGHT - 1 - e[i].y)
            j += 1
    return words.tobytes()
