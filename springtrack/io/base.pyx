"""Streaming decoder base: buffer handling shared by every format module.

A format module subclasses :class:`Decoder` and implements one ``_run`` method: a nogil
loop over whole words that writes events into a preallocated output and stops early when
the output is nearly full.  This class does everything else once:

* words split across two ``decode()`` calls (USB bulk transfers, file chunks) are kept
  in a small carry buffer and completed by the next call;
* the output array is sized from the input length and grown if a format (EVT 3.0
  vectors) produces more events than the first guess;
* counters (words, events, anomalies by kind, informational counts) are exposed as
  :class:`springtrack.io.stats.DecodeStats`.
"""
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.events import EVENT_DTYPE, empty_output
from springtrack.io.stats import DecodeStats

cnp.import_array()

ANOMALY_NAMES = ("unknown_type", "out_of_geometry", "time_backwards", "orphan", "truncated")
INFO_NAMES = ("time_high_words", "time_wraps", "triggers", "other_words", "exposure_events",
              "overflow_bytes", "reset_bytes", "before_time_high", "time_low_backwards")
assert len(ANOMALY_NAMES) == N_ANOMALY and len(INFO_NAMES) == N_INFO, "names of base.pxd's enums"


cdef inline Event* _ptr(object arr):
    return <Event*>cnp.PyArray_DATA(<cnp.ndarray>arr)


cdef class Decoder:
    """Base of the streaming decoders; make one with ``springtrack.io.decoder(fmt)``."""

    def _setup(self, str fmt, int word_size, int max_per_word, int bound_den,
               int width, int height, bint keep_exposure):
        if width < 0 or height < 0 or width > 65535 or height > 65535:
            raise ValueError(f"{fmt} decoder: geometry {width}x{height} out of range 0..65535")
        self.format = fmt
        self.word_size = word_size
        self.max_per_word = max_per_word
        self.bound_den = bound_den
        self.width = width
        self.height = height
        self.keep_exposure = keep_exposure
        self._exposure_parts = []

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        return n  # overridden by every format

    cdef int _pending_state(self) noexcept:
        return 0  # bytes held in format state (Event Stream: a partial event)

    cdef void _reset_state(self) noexcept:
        pass

    cdef object _feed(self, const uint8_t* p, Py_ssize_t n, object out, Py_ssize_t* nout,
                      object side, Py_ssize_t* nside):
        """Run the format loop over ``n`` bytes (whole words), growing ``out`` as needed."""
        cdef Py_ssize_t used, cap
        cdef Event* o
        cdef Event* s = NULL if side is None else _ptr(side)
        while n > 0:
            o = _ptr(out)
            cap = out.shape[0]
            with nogil:
                used = self._run(p, n, o, cap, nout, s, nside)
            p += used
            n -= used
            if n > 0:   # output nearly full: grow and go on
                bigger = np.empty(max(2 * cap, nout[0] + 64 * self.max_per_word), EVENT_DTYPE)
                bigger[:nout[0]] = out[:nout[0]]
                out = bigger
        return out

    cdef object _decode(self, buffer, object out, Py_ssize_t* nout_p):
        """Decode ``buffer`` appending to ``out`` from ``nout_p[0]``; return ``out`` (grown
        if a format produced more events than the room it had)."""
        data = np.frombuffer(buffer, dtype=np.uint8)
        cdef Py_ssize_t n = data.shape[0]
        if n == 0:
            return out
        cdef const uint8_t[::1] mv = data
        cdef const uint8_t* p = &mv[0]
        cdef Py_ssize_t ws = self.word_size, pos = 0, k, whole, nout = nout_p[0], nside = 0
        side = np.empty((n + self.ncarry) // ws + 2, EVENT_DTYPE) if self.keep_exposure else None
        if self.ncarry:   # complete the word split by the previous call
            k = min(ws - self.ncarry, n)
            memcpy(&self.carry[self.ncarry], p, k)
            self.ncarry += k
            pos = k
            if self.ncarry == ws:
                self.ncarry = 0
                out = self._feed(self.carry, ws, out, &nout, side, &nside)
        whole = (n - pos) // ws * ws
        if whole:
            out = self._feed(p + pos, whole, out, &nout, side, &nside)
            pos += whole
        if pos < n:       # keep the tail of a split word for the next call
            memcpy(&self.carry[self.ncarry], p + pos, n - pos)
            self.ncarry += n - pos
        self.events_out += nout - nout_p[0]
        nout_p[0] = nout
        if side is not None and nside:
            self._exposure_parts.append(side[:nside].copy())
        return out

    def decode(self, buffer):
        """Decode ``buffer`` (bytes-like); return the events completed so far.

        State (time base, partial word, last address) carries over to the next call, so
        feeding a stream in pieces cut anywhere gives the same events as one call.
        """
        cdef Py_ssize_t n = len(memoryview(buffer).cast("B")), nout = 0
        out = empty_output((n + self.ncarry) // self.bound_den + self.max_per_word + 1)
        out = self._decode(buffer, out, &nout)
        if nout * 2 < out.shape[0]:
            return out[:nout].copy()
        return out[:nout]

    def decode_into(self, buffer, out, Py_ssize_t start=0):
        """Decode ``buffer`` into the preallocated EVENT_DTYPE array ``out`` from index
        ``start``; return the number of events written (no allocation: for streaming
        loops that reuse one buffer).  ``out`` must have room for the worst case:
        (len(buffer) + 7) // word_size * max_per_word events (EVT 3.0: 12 per word)."""
        cdef Py_ssize_t n = len(memoryview(buffer).cast("B")), nout = start
        cdef Py_ssize_t need = (n + self.ncarry) // self.word_size * self.max_per_word
        if not (isinstance(out, np.ndarray) and out.dtype == EVENT_DTYPE
                and out.flags.c_contiguous and out.ndim == 1):
            raise TypeError("decode_into: out must be a 1-D C-contiguous EVENT_DTYPE array")
        if start < 0 or out.shape[0] - start < need:
            raise ValueError(f"decode_into: out has room for {out.shape[0] - start} events "
                             f"from index {start}; this buffer may produce {need}")
        res = self._decode(buffer, out, &nout)
        assert res is out
        return nout - start

    def decode_append(self, buffer, out, Py_ssize_t start):
        """Decode ``buffer`` into ``out`` from index ``start``, growing it (a new array)
        if needed; return ``(out, total events in out)``.  For readers that fill one
        array from many file reads."""
        if not (isinstance(out, np.ndarray) and out.dtype == EVENT_DTYPE
                and out.flags.c_contiguous and out.ndim == 1) or not 0 <= start <= out.shape[0]:
            raise ValueError("decode_append: out must be a 1-D C-contiguous EVENT_DTYPE "
                             "array and 0 <= start <= len(out)")
        cdef Py_ssize_t nout = start
        out = self._decode(buffer, out, &nout)
        return out, nout

    def finish(self):
        """End of stream: count a partial trailing word as 'truncated'; return its byte count."""
        pending = self.pending_bytes
        if pending:
            self.n.anomalies[<int>AN_TRUNCATED] += 1
        self.ncarry = 0
        self._reset_state()
        return pending

    def take_exposure(self):
        """Exposure-measurement events kept since the last call (needs keep_exposure=True)."""
        parts, self._exposure_parts = self._exposure_parts, []
        if not parts:
            return np.empty(0, EVENT_DTYPE)
        return np.concatenate(parts)

    @property
    def words(self):
        """Words consumed (bytes for Event Stream)."""
        return self.n.words

    @property
    def pending_bytes(self):
        return self.ncarry + self._pending_state()

    @property
    def stats(self):
        return DecodeStats(
            format=self.format, words=self.n.words, events=self.events_out,
            pending_bytes=self.pending_bytes,
            anomalies={ANOMALY_NAMES[i]: int(self.n.anomalies[i]) for i in range(<int>N_ANOMALY)},
            info={INFO_NAMES[i]: int(self.n.info[i]) for i in range(<int>N_INFO) if self.n.info[i]})


cdef extern from "springtrack/io/clones.h" nogil:
    int io_avx2()


def simd_path() -> str:
    """The block paths the word decoders take in this process: ``"avx2"`` (the hand-written
    AVX2 blocks of EVT 2.0 and EVT 3.0: io/clones.h) or ``"portable"`` (no AVX2 in this
    build or processor, or ``SPRINGTRACK_SIMD=0`` in the environment).  Events and
    counters are the same on either."""
    return "avx2" if io_avx2() else "portable"


def encoder_input(events, str fmt, int width, int height, prev_t=None):
    """Events for an encoder: EVENT_DTYPE, t >= 0 (>= ``prev_t``, the last event time of
    the stream the events continue) and non-decreasing, x < width, y < height; raises
    ValueError naming the format otherwise."""
    from springtrack.events import as_events
    ev = as_events(events)
    if len(ev) == 0:
        return ev
    t = ev["t"]
    if prev_t is not None and t[0] < prev_t:
        raise ValueError(f"{fmt} encode: the events start at {t[0]} us, before the stream's "
                         f"last event at {prev_t} us")
    if t[0] < 0 or (len(t) > 1 and np.any(np.diff(t) < 0)):
        raise ValueError(f"{fmt} encode: timestamps must be >= 0 and non-decreasing")
    if ev["x"].max() >= width or ev["y"].max() >= height:
        raise ValueError(f"{fmt} encode: x must be < {width} and y < {height}")
    return ev
