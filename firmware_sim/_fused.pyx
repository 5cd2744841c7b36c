# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""Decode a camera's words and track them in one nogil pass.

The word formats of the cameras people own, each through its decoder's own state machine
(``springtrack.io``'s ``.pxd``: state struct, init, nogil step counting into a
``DecodeCounts``), at the sensor's own geometry:

========  ==============================  ==================================  ============
format    camera                          state machine                       geometry
========  ==============================  ==================================  ============
ccam      CCam ATIS (the paper's)         ``ccam.pxd`` (word / 32-word block)  304 x 240
evt2      Prophesee Gen3 EVK               ``evt2.pxd``                        up to 2048^2
evt21     GENX320 / IMX636 (EVT 2.1)      ``evt21.pxd`` (both word orders)    up to 2048^2
evt3      Prophesee Gen4 / IMX636 EVK     ``evt3.pxd``                        up to 2048^2
========  ==============================  ==================================  ============

Decoded change-detection events go into a batch of at most BATCH events (a C array in the
object, 16 KiB, half of a 32 KiB L1 data cache), optionally filtered to a region of interest (the rest counted,
``outside_roi``), and each batch runs through ``springtrack.backends.stepper.run_events``, the
sampled event loop of ``springtrack track``, on the tracker backend's :c:type:`Stepper`
(springtrack/backends/stepper.pxd): the float64 kernel (``springtrack.kernel.kernel.Kernel``) or the
integer-only fixed-point kernel (``springtrack.fixed.kernel.FixedKernel``).  No Python object,
allocation or GIL per event; the only output is a preallocated snapshot buffer that the
caller drains.  When that buffer fills mid-batch, the rest of the batch waits in the object
for the next call.

Sampling is ``springtrack track``'s, in run_events (the rule of springtrack/csrc/sampling.h):
the first tracked event at t0 sets the first sample time to the smallest multiple of the
period >= t0; before an event at t with t >= next sample and t >= the kernel's last time,
one snapshot per sample time <= t is taken (state after all events with t < sample time),
an empty stretch sampled for its first springtrack.sampling.HOLD periods and at its end
only (the sample times skipped counted, ``samples_skipped``).

Time: the decoder's own time base, unchanged (springtrack/io/timebase.pxd: wraps
unwrapped, a counter that goes back, e.g. a camera restarted after a reconnect, rebased so
that time never goes back), so the loop stamps every event exactly as decoding the same
bytes from a file does.  Gaps: after a dropped transfer or a reconnect (:meth:`Fused.gap`)
and at stream start, events are discarded (counted, ``gap_skipped``) until the next
time-high word, so no event gets a stale time base (EVT 3.0 also forgets its row and vector
base: ``evt3_lost_data``); the tracker then simply continues (the kernel needs no reset).
Words split across transfers (odd lengths) are completed from a carry of up to 7 bytes.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack.kernel.kernel cimport Kernel
from springtrack.fixed.kernel cimport FixedKernel
from springtrack.backends.samples cimport SampleOut, sample_buffers, take_samples
from springtrack.backends.stepper cimport Stepper, ST_UNSET, run_events, st_first_sample
from springtrack.sampling import MAX_PERIOD
from springtrack.events cimport Event
from springtrack.io.base cimport (DecodeCounts, MAX_WORD, AN_UNKNOWN_TYPE, AN_OUT_OF_GEOMETRY,
                                  AN_TIME_BACKWARDS, AN_ORPHAN, IN_TIME_HIGH, IN_TIME_WRAPS,
                                  IN_EXPOSURE, IN_BEFORE_TIME_HIGH, IN_TRIGGERS, IN_OTHERS,
                                  IN_TIME_LOW_BACK)
from springtrack.io.ccam cimport (CCamState, ccam_init, ccam_decode_word, ccam_decode_block,
                                  CCAM_BLOCK, CCAM_CD, CCAM_TIME_BASE, CCAM_WORD_BYTES,
                                  CCAM_WIDTH, CCAM_HEIGHT)
from springtrack.io.evt2 cimport Evt2State, evt2_init, evt2_decode_words, EVT2_WORD_BYTES
from springtrack.io.evt21 cimport (Evt21State, evt21_init, evt21_decode_words,
                                   EVT21_WORD_BYTES, EVT21_MAX_PER_WORD)
from springtrack.io.evt3 cimport (Evt3State, evt3_init, evt3_lost_data, evt3_decode_words,
                                  EVT3_WORD_BYTES, EVT3_MAX_EVENTS_PER_WORD)

cnp.import_array()

cdef enum:
    # decoded events tracked per run_events call.  The EVT decoders' fast paths start a
    # block only with room for its worst case (EVT 3.0: 16 words, up to 192 events), so
    # the batch is large enough for them to fill most of it
    BATCH = 1024
    # feed() releases the GIL only for at least this many bytes (4096 words, some 0.2 ms of
    # work).  Releasing it hands the GIL to the USB reader thread, which keeps it for its
    # next read's Python set-up before it blocks; for a real-time transfer of a few hundred
    # words (microseconds of work) that wait, not the work, would be the loop's latency.
    # FirmwareLoop's full pieces (16 KiB) reach it, so under load the reader still runs
    # while a piece is tracked; real-time transfers, even coalesced, mostly stay below.
    NOGIL_MIN_BYTES = 16384
    MAX_EVT_SIZE = 2048         # EVT 2.0 / 2.1 / 3.0 coordinates are 11 bits

cdef enum WordFormat:           # the word formats the loop decodes
    WF_CCAM
    WF_EVT2
    WF_EVT21
    WF_EVT3

# format name -> (WordFormat, bytes per word, most events one word completes)
WORD_FORMATS = {
    "ccam": (WF_CCAM, CCAM_WORD_BYTES, 1),
    "evt2": (WF_EVT2, EVT2_WORD_BYTES, 1),
    "evt21": (WF_EVT21, EVT21_WORD_BYTES, EVT21_MAX_PER_WORD),
    "evt3": (WF_EVT3, EVT3_WORD_BYTES, EVT3_MAX_EVENTS_PER_WORD),
}


def native_geometry(str fmt, int width=0, int height=0):
    """The sensor geometry the fused loop decodes ``fmt`` at: (width, height), checked
    (CCam words are the 304 x 240 ATIS; EVT words carry 11-bit coordinates, so a sensor of
    up to 2048 x 2048).  ``width``/``height`` 0: the CCam's, required for the EVT formats."""
    if fmt not in WORD_FORMATS:
        raise ValueError(f"the fused loop decodes {', '.join(WORD_FORMATS)} words, not {fmt!r}")
    if fmt == "ccam":
        if (width, height) not in ((0, 0), (CCAM_WIDTH, CCAM_HEIGHT)):
            raise ValueError(f"CCam ATIS words are {CCAM_WIDTH}x{CCAM_HEIGHT}, "
                             f"not {width}x{height}")
        return CCAM_WIDTH, CCAM_HEIGHT
    if not (1 <= width <= MAX_EVT_SIZE and 1 <= height <= MAX_EVT_SIZE):
        raise ValueError(f"{fmt} sensor geometry {width}x{height}: EVT words address up to "
                         f"{MAX_EVT_SIZE}x{MAX_EVT_SIZE} pixels (give the sensor's size)")
    return width, height


cdef Stepper stepper_of(kernel) except *:
    if isinstance(kernel, Kernel):
        return (<Kernel>kernel).stepper()
    if isinstance(kernel, FixedKernel):
        return (<FixedKernel>kernel).stepper()
    raise TypeError(f"the fused loop runs springtrack.kernel.kernel.Kernel or "
                    f"springtrack.fixed.kernel.FixedKernel, not {type(kernel).__name__}")


cdef class Fused:
    """``Fused(kernel, period_us, cap, fmt="ccam", width=0, height=0, legacy=False,
    roi=None)``: decoder + tracker state for one stream; ``kernel`` is a
    ``springtrack.kernel.kernel.Kernel`` or ``springtrack.fixed.kernel.FixedKernel``; ``fmt`` a key of
    :data:`WORD_FORMATS` at the sensor's ``width`` x ``height`` (:func:`native_geometry`);
    ``legacy``: EVT 2.1 in the IMX636 word order; ``roi``: ``(x, y, w, h)`` px, only the
    events inside are tracked (the rest counted, ``outside_roi``).

    ``feed(buf, n)`` processes the first ``n`` bytes of a buffer (bytes, bytearray,
    array('B'), numpy uint8) and returns the snapshots taken (or, with a ``sink``, passes
    them to ``sink(part)`` part by part and returns None) as a dict of arrays (rows
    ``t``; ``trackers`` (rows, trackers) springtrack.track.TRACK_DTYPE; ``energy``
    (rows, 3); for a kernel that packs them (:attr:`native_records`, the fixed-point kernel
    from its integer state) ``wire`` (rows, trackers * 8), the TELEMETRY tracker records).
    """
    cdef object kernel                      # owns the state sp points into
    cdef Stepper sp
    cdef WordFormat wf
    cdef readonly str format
    cdef readonly int width, height, word_size
    cdef int max_per_word
    # the decoders' state machines (the one of `wf` runs) and their counters
    cdef CCamState cs
    cdef Evt2State e2
    cdef Evt21State e21
    cdef Evt3State e3
    cdef DecodeCounts dn
    cdef uint64_t decoded                   # change-detection events decoded
    cdef uint8_t carry[MAX_WORD]
    cdef int ncarry
    cdef bint await_th
    cdef bint has_roi
    cdef uint32_t rx0, ry0, rx1, ry1        # region of interest [rx0, rx1) x [ry0, ry1)
    cdef readonly uint64_t outside_roi
    cdef int64_t period, next_t             # next_t: ST_UNSET before the first event
    # decoded events not yet tracked: batch[bpos:bn] (left over when the buffer filled)
    cdef Event batch[BATCH]
    cdef Py_ssize_t bpos, bn
    cdef bint mark
    cdef readonly int64_t first_t          # first event time after set_kernel(mark=True)
    cdef readonly uint64_t tracked, gap_skipped, gaps, bytes_in
    cdef readonly uint64_t samples_skipped  # sample times of empty stretches not taken
    cdef SampleOut o
    cdef object bufs

    def __init__(self, kernel, long long period_us=1000, Py_ssize_t cap=1024,
                 str fmt="ccam", int width=0, int height=0, bint legacy=False, roi=None):
        if cap < 1:
            raise ValueError(f"snapshot capacity must be >= 1, got {cap}")
        if period_us >= MAX_PERIOD:
            raise ValueError(f"sampling period {period_us} us is not below {MAX_PERIOD} us")
        self.width, self.height = native_geometry(fmt, width, height)
        wf, self.word_size, self.max_per_word = WORD_FORMATS[fmt]
        self.wf = wf
        self.format = fmt
        if legacy and fmt != "evt21":
            raise ValueError(f"legacy word order applies to EVT 2.1, not {fmt}")
        ccam_init(&self.cs)
        evt2_init(&self.e2, self.width, self.height)
        evt21_init(&self.e21, self.width, self.height, legacy)
        evt3_init(&self.e3, self.width, self.height)
        self._set_roi(roi)
        self.ncarry = 0
        self.await_th = True
        self.period = period_us if period_us > 0 else 0
        self.next_t = ST_UNSET
        self.bpos = 0
        self.bn = 0
        self.first_t = -1
        self.o.cap = cap
        self._bind(kernel, False)

    cdef _set_roi(self, roi):
        self.has_roi = roi is not None
        if roi is None:
            return
        x, y, w, h = (int(v) for v in roi)
        if w < 1 or h < 1 or x < 0 or y < 0 or x + w > self.width or y + h > self.height:
            raise ValueError(f"ROI x={x} y={y} w={w} h={h} must lie inside the "
                             f"{self.width}x{self.height} sensor")
        self.rx0, self.ry0, self.rx1, self.ry1 = x, y, x + w, y + h

    @property
    def roi(self):
        """(x, y, w, h) of the region of interest, or None (the whole sensor)."""
        if not self.has_roi:
            return None
        return (self.rx0, self.ry0, self.rx1 - self.rx0, self.ry1 - self.ry0)

    cdef _bind(self, kernel, bint mark):
        self.sp = stepper_of(kernel)
        self.kernel = kernel
        self.bufs = sample_buffers(self.o.cap, self.sp.n, &self.o, self.sp.wire_records)
        self.mark = mark
        if mark:
            self.first_t = -1

    def set_kernel(self, kernel):
        """Swap the tracked model (between two events; call only between feeds).  The
        decoder state and the sampling clock carry over; :attr:`first_t` becomes the time
        of the first event the new kernel processes."""
        if self.o.count:
            raise RuntimeError("drain the snapshots before swapping the kernel")
        self._bind(kernel, True)

    def mark_next(self):
        """Record the time of the next tracked event in :attr:`first_t` (the event time
        at which a parameter change applied between two feeds took effect)."""
        self.mark = True
        self.first_t = -1

    @property
    def kernel_obj(self):
        return self.kernel

    @property
    def native_records(self):
        """The sample rows carry the kernel's own TELEMETRY records (``wire``)."""
        return self.sp.wire_records

    def gap(self):
        """Data was lost before the next buffer: wait for a fresh time base."""
        self.ncarry = 0            # a split word's tail is gone with the dropped transfer
        self.await_th = True
        if self.wf == WF_EVT3:
            evt3_lost_data(&self.e3)
        self.gaps += 1

    # ---- the nogil core ------------------------------------------------------------------
    cdef inline bint _track(self) noexcept nogil:
        """Track batch[bpos:bn] with the sampling rule; True if the snapshot buffer filled
        before the batch was done (the rest stays for the next call)."""
        cdef Py_ssize_t k = self.bpos, c, taken = self.o.count
        cdef int64_t start = self.next_t
        if self.mark:
            self.mark = False
            self.first_t = self.batch[k].t
        if start == ST_UNSET and self.period > 0 and k < self.bn:
            start = st_first_sample(self.batch[k].t, self.period)
        c = run_events(&self.sp, &self.batch[k], self.bn - k, self.period, &self.next_t,
                       &self.o)
        if self.period > 0 and self.next_t != ST_UNSET:    # the sample times passed over
            self.samples_skipped += (self.next_t - start) // self.period - (self.o.count - taken)
        self.tracked += c
        self.bpos = k + c
        return self.bpos < self.bn

    cdef inline void _ccam_word(self, const uint8_t* w) noexcept nogil:
        cdef int64_t t
        cdef uint16_t x, y
        cdef uint8_t p
        cdef int kind = ccam_decode_word(&self.cs, &self.dn, w, &t, &x, &y, &p)
        if kind != CCAM_CD:
            if kind == CCAM_TIME_BASE:
                self.await_th = False
            return
        self.decoded += 1
        if self.await_th:
            self.gap_skipped += 1
            return
        self.batch[self.bn].t = t
        self.batch[self.bn].x = x
        self.batch[self.bn].y = y
        self.batch[self.bn].p = p
        self.bn += 1

    cdef Py_ssize_t _ccam_words(self, const uint8_t* p, Py_ssize_t nw) noexcept nogil:
        """Decode up to nw CCam words into the batch; return the words consumed."""
        cdef Py_ssize_t i = 0, end
        while i < nw and self.bn < BATCH:
            # a block of plain change-detection words at once (ccam_block.h), else a block's
            # worth word by word
            if (i + CCAM_BLOCK <= nw and self.bn + CCAM_BLOCK <= BATCH and not self.await_th
                    and ccam_decode_block(&self.cs, &self.dn, p + CCAM_WORD_BYTES * i,
                                          &self.batch[self.bn])):
                self.decoded += CCAM_BLOCK
                self.bn += CCAM_BLOCK
                i += CCAM_BLOCK
                continue
            end = i + CCAM_BLOCK
            while i < nw and i < end and self.bn < BATCH:
                self._ccam_word(p + CCAM_WORD_BYTES * i)
                i += 1
        return i

    cdef Py_ssize_t _evt_words(self, const uint8_t* p, Py_ssize_t nw) noexcept nogil:
        """Decode up to nw EVT words into the batch with the format's state machine; return
        the words consumed (0: no room left for a word's worst case).  While waiting for a
        time base, one word at a time, its events discarded and counted, until a time-high
        word."""
        cdef Py_ssize_t k0 = self.bn, used
        cdef uint64_t th0 = self.dn.info[<int>IN_TIME_HIGH]
        if self.await_th:
            nw = 1
        if self.wf == WF_EVT2:
            if nw > BATCH - self.bn:
                nw = BATCH - self.bn
            used = evt2_decode_words(&self.e2, &self.dn, p, nw, self.batch, &self.bn)
        elif self.wf == WF_EVT21:
            used = evt21_decode_words(&self.e21, &self.dn, p, nw, self.batch, BATCH, &self.bn)
        else:
            used = evt3_decode_words(&self.e3, &self.dn, p, nw, self.batch, &self.bn, BATCH)
        self.decoded += self.bn - k0
        if self.await_th:
            if self.dn.info[<int>IN_TIME_HIGH] != th0:
                self.await_th = False
            else:
                self.gap_skipped += self.bn - k0
                self.bn = k0
        return used

    cdef inline Py_ssize_t _words(self, const uint8_t* p, Py_ssize_t nw) noexcept nogil:
        if self.wf == WF_CCAM:
            return self._ccam_words(p, nw)
        return self._evt_words(p, nw)

    cdef void _keep_roi(self) noexcept nogil:
        """Keep the batch's events inside the region of interest, count the others."""
        cdef Py_ssize_t i, k = 0
        cdef uint32_t x, y
        for i in range(self.bn):
            x = self.batch[i].x
            y = self.batch[i].y
            if self.rx0 <= x < self.rx1 and self.ry0 <= y < self.ry1:
                self.batch[k] = self.batch[i]
                k += 1
        self.outside_roi += self.bn - k
        self.bn = k

    cdef Py_ssize_t _decode(self, const uint8_t* p, Py_ssize_t pos, Py_ssize_t n) noexcept nogil:
        """Decode bytes [pos, n) into the (empty) batch until it is full; return the
        position reached.  A word split across buffers is completed from the carry."""
        cdef Py_ssize_t k, used, ws = self.word_size
        self.bpos = 0
        self.bn = 0
        if self.ncarry:
            k = ws - self.ncarry
            if k > n - pos:
                k = n - pos
            memcpy(&self.carry[self.ncarry], p + pos, k)
            self.ncarry += k
            pos += k
            if self.ncarry < ws:
                return pos
            self.ncarry = 0
            self._words(self.carry, 1)      # the batch is empty: room for any word
        while pos + ws <= n and BATCH - self.bn >= self.max_per_word:
            used = self._words(p + pos, (n - pos) // ws)
            if used == 0:
                break
            pos += used * ws
        if pos < n and pos + ws > n:     # a word split across transfers: keep its head
            memcpy(self.carry, p + pos, n - pos)
            self.ncarry = <int>(n - pos)
            pos = n
        if self.has_roi:
            self._keep_roi()
        return pos

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t pos, Py_ssize_t n) noexcept nogil:
        """Process bytes [pos, n); return the position reached (< n, or events left in the
        batch, if the snapshot buffer filled)."""
        while True:
            if self.bpos < self.bn and self._track():
                return pos
            if pos >= n:
                return pos
            pos = self._decode(p, pos, n)

    def feed(self, buf, Py_ssize_t n=-1, sink=None):
        """Process the first ``n`` bytes of ``buf`` (all if n < 0); return the snapshots
        taken, or with ``sink`` pass them to ``sink(rows)`` as each ``cap`` rows fill
        (memory bounded by ``cap`` rows however many samples the bytes produce) and
        return None."""
        cdef const uint8_t[::1] mv = memoryview(buf).cast("B")
        cdef Py_ssize_t total = mv.shape[0] if n < 0 else n, pos = 0
        if total > mv.shape[0]:
            raise ValueError(f"feed: n={n} exceeds the buffer's {mv.shape[0]} bytes")
        cdef const uint8_t* p = &mv[0] if mv.shape[0] else NULL
        parts = []
        self.bytes_in += total
        while True:
            if total - pos >= NOGIL_MIN_BYTES:
                with nogil:
                    pos = self._run(p, pos, total)
            else:                               # short work: keep the GIL (see above)
                pos = self._run(p, pos, total)
            if self.o.count:
                if sink is not None:
                    sink(self._take())
                else:
                    parts.append(self._take())
            if pos >= total and self.bpos >= self.bn:
                break
        if not parts:
            return None
        if len(parts) == 1:
            return parts[0]
        return {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}

    cdef object _take(self):
        return take_samples(self.bufs, &self.o, True)

    def counters(self) -> dict:
        cdef DecodeCounts* n = &self.dn
        return dict(format=self.format, words=n.words, time_high_words=n.info[<int>IN_TIME_HIGH],
                    events_decoded=self.decoded, exposure_events=n.info[<int>IN_EXPOSURE],
                    events_tracked=self.tracked, time_wraps=n.info[<int>IN_TIME_WRAPS],
                    gaps=self.gaps, bytes=self.bytes_in, pending_bytes=self.ncarry,
                    triggers=n.info[<int>IN_TRIGGERS], other_words=n.info[<int>IN_OTHERS],
                    time_low_backwards=n.info[<int>IN_TIME_LOW_BACK],
                    outside_roi=self.outside_roi, samples_skipped=self.samples_skipped,
                    anomalies=dict(unknown_type=n.anomalies[<int>AN_UNKNOWN_TYPE],
                                   out_of_geometry=n.anomalies[<int>AN_OUT_OF_GEOMETRY],
                                   time_backwards=n.anomalies[<int>AN_TIME_BACKWARDS],
                                   orphan=n.anomalies[<int>AN_ORPHAN],
                                   before_time_high=n.info[<int>IN_BEFORE_TIME_HIGH],
                                   skipped_after_gap=self.gap_skipped,
                                   tracker_back_in_time=self.sp.n_back[0],
                                   tracker_outside_sensor=self.sp.n_outside[0]))

    @property
    def last_t(self):
        return self.sp.last_t[0]

    @property
    def next_sample_t(self):
        return None if self.next_t == ST_UNSET else self.next_t
