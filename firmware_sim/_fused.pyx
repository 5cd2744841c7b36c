# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""Decode CCam ATIS USB words and track them in one nogil pass.

Per 4-byte word: ``springtrack.io.ccam.ccam_decode_word`` (word types in
springtrack/io/ccam_types.h), or 32 words at once while they are all plain change-detection
events (``ccam_decode_block``, springtrack/io/ccam_block.h, vectorised: time-high and
special words go word by word); the change-detection events go into a batch of at most
BATCH events (a C array in the object, 4 KiB, stays in L1), and each batch runs through
``springtrack._stepper.run_events``, the sampled event loop of ``springtrack track``, on
the tracker backend's :c:type:`Stepper` (springtrack/_stepper.pxd): the float64 kernel
(``springtrack._kernel.Kernel``) or the integer-only fixed-point kernel
(``springtrack._fixed.FixedKernel``).  No Python object, allocation or GIL per event; the
only output is a preallocated snapshot buffer that the caller drains.  When that buffer
fills mid-batch, the rest of the batch waits in the object for the next call.

Sampling is ``springtrack track``'s, in run_events (the rule of springtrack/csrc/sampling.h):
the first tracked event at t0 sets the first sample time to the smallest multiple of the
period >= t0; before an event at t with t >= next sample and t >= the kernel's last time,
one snapshot per sample time <= t is taken (state after all events with t < sample time),
an empty stretch sampled for its first springtrack.sampling.HOLD periods only.

Time: the decoder's own time base, unchanged (springtrack/io/timebase.pxd: wraps
unwrapped, a counter that goes back, e.g. a camera restarted after a reconnect, rebased so
that time never goes back), so the loop stamps every event exactly as decoding the same
bytes from a file does.  Gaps: after a dropped transfer or a reconnect (:meth:`Fused.gap`)
and at stream start, events are discarded (counted, ``gap_skipped``) until the next
time-high word, so no event gets a stale time base; the tracker then simply continues
(the kernel needs no reset).  Words split across transfers (odd lengths) are completed
from a 3-byte carry.
"""
from libc.stdint cimport uint8_t, uint16_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np

from springtrack._kernel cimport Kernel
from springtrack._fixed cimport FixedKernel
from springtrack._samples cimport SampleOut, sample_buffers, take_samples
from springtrack._stepper cimport Stepper, ST_UNSET, run_array, run_events
from springtrack.sampling import MAX_PERIOD
from springtrack.events cimport Event
from springtrack.io.base cimport (DecodeCounts, AN_UNKNOWN_TYPE, AN_OUT_OF_GEOMETRY,
                                  AN_TIME_BACKWARDS, IN_TIME_HIGH, IN_TIME_WRAPS, IN_EXPOSURE,
                                  IN_BEFORE_TIME_HIGH)
from springtrack.io.ccam cimport (CCamState, ccam_init, ccam_decode_word, ccam_decode_block,
                                  CCAM_BLOCK, CCAM_CD, CCAM_TIME_BASE)

cnp.import_array()

cdef enum:
    BATCH = 256                 # decoded events tracked per run_events call
    # feed() releases the GIL only for at least this many bytes (4096 words, some 0.2 ms of
    # work).  Releasing it hands the GIL to the USB reader thread, which keeps it for its
    # next read's Python set-up before it blocks; for a real-time transfer of a few hundred
    # words (microseconds of work) that wait, not the work, would be the loop's latency.
    # FirmwareLoop's full pieces (16 KiB) reach it, so under load the reader still runs
    # while a piece is tracked; real-time transfers, even coalesced, mostly stay below.
    NOGIL_MIN_BYTES = 16384

cdef Stepper stepper_of(kernel) except *:
    if isinstance(kernel, Kernel):
        return (<Kernel>kernel).stepper()
    if isinstance(kernel, FixedKernel):
        return (<FixedKernel>kernel).stepper()
    raise TypeError(f"the fused loop runs springtrack._kernel.Kernel or "
                    f"springtrack._fixed.FixedKernel, not {type(kernel).__name__}")


def packs_records(kernel) -> bool:
    """Whether the kernel's snapshots pack TELEMETRY records themselves (the fixed-point
    kernel, from its integer state): then the fused loop's sample rows carry them."""
    return stepper_of(kernel).wire_records


def track_events(kernel, events, long long period_us, long long next_t, Py_ssize_t cap):
    """``kernel.run(events, period_us, next_t, cap)`` whose sample rows carry the TELEMETRY
    records the kernel packs (``wire``, see :func:`packs_records`), like
    :meth:`Fused.feed`'s: for a decoder other than the fused CCam one."""
    return run_array(stepper_of(kernel), events, period_us, next_t, cap, True)


cdef class Fused:
    """``Fused(kernel, period_us, cap)``: decoder + tracker state for one stream;
    ``kernel`` is a ``springtrack._kernel.Kernel`` or ``springtrack._fixed.FixedKernel``.

    ``feed(buf, n)`` processes the first ``n`` bytes of a buffer (bytes, bytearray,
    array('B'), numpy uint8) and returns the snapshots taken as a dict of arrays (rows
    ``t``; ``trackers`` (rows, trackers) springtrack.track.TRACK_DTYPE; ``energy``
    (rows, 3); for a kernel that packs them (:attr:`native_records`, the fixed-point kernel
    from its integer state) ``wire`` (rows, trackers * 8), the TELEMETRY tracker records).
    """
    cdef object kernel                      # owns the state sp points into
    cdef Stepper sp
    cdef CCamState cs                       # the CCam decoder's state machine
    cdef DecodeCounts dn                    # and its counters
    cdef uint64_t decoded                   # change-detection events decoded
    cdef uint8_t carry[4]
    cdef int ncarry
    cdef bint await_th
    cdef int64_t period, next_t             # next_t: ST_UNSET before the first event
    # decoded events not yet tracked: batch[bpos:bn] (left over when the buffer filled)
    cdef Event batch[BATCH]
    cdef Py_ssize_t bpos, bn
    cdef bint mark
    cdef readonly int64_t first_t          # first event time after set_kernel(mark=True)
    cdef readonly uint64_t tracked, gap_skipped, gaps, bytes_in
    cdef SampleOut o
    cdef object bufs

    def __init__(self, kernel, long long period_us=1000, Py_ssize_t cap=1024):
        if cap < 1:
            raise ValueError(f"snapshot capacity must be >= 1, got {cap}")
        if period_us >= MAX_PERIOD:
            raise ValueError(f"sampling period {period_us} us is not below {MAX_PERIOD} us")
        ccam_init(&self.cs)
        self.ncarry = 0
        self.await_th = True
        self.period = period_us if period_us > 0 else 0
        self.next_t = ST_UNSET
        self.bpos = 0
        self.bn = 0
        self.first_t = -1
        self.o.cap = cap
        self._bind(kernel, False)

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
        self.gaps += 1

    # ---- the nogil core ------------------------------------------------------------------
    cdef inline bint _track(self) noexcept nogil:
        """Track batch[bpos:bn] with the sampling rule; True if the snapshot buffer filled
        before the batch was done (the rest stays for the next call)."""
        cdef Py_ssize_t k = self.bpos, c
        if self.mark:
            self.mark = False
            self.first_t = self.batch[k].t
        c = run_events(&self.sp, &self.batch[k], self.bn - k, self.period, &self.next_t,
                       &self.o)
        self.tracked += c
        self.bpos = k + c
        return self.bpos < self.bn

    cdef inline void _word(self, const uint8_t* w) noexcept nogil:
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

    cdef Py_ssize_t _decode(self, const uint8_t* p, Py_ssize_t pos, Py_ssize_t n) noexcept nogil:
        """Decode bytes [pos, n) into the (empty) batch until it holds BATCH events; return
        the position reached.  A word split across buffers is completed from the carry."""
        cdef Py_ssize_t k, end
        self.bpos = 0
        self.bn = 0
        if self.ncarry:
            k = 4 - self.ncarry
            if k > n - pos:
                k = n - pos
            memcpy(&self.carry[self.ncarry], p + pos, k)
            self.ncarry += k
            pos += k
            if self.ncarry < 4:
                return pos
            self.ncarry = 0
            self._word(self.carry)
        while pos + 4 <= n and self.bn < BATCH:
            # a block of plain change-detection words at once (ccam_block.h), else a block's
            # worth word by word
            if (pos + 4 * CCAM_BLOCK <= n and self.bn + CCAM_BLOCK <= BATCH
                    and not self.await_th
                    and ccam_decode_block(&self.cs, &self.dn, p + pos, &self.batch[self.bn])):
                self.decoded += CCAM_BLOCK
                self.bn += CCAM_BLOCK
                pos += 4 * CCAM_BLOCK
                continue
            end = pos + 4 * CCAM_BLOCK
            while pos + 4 <= n and pos < end and self.bn < BATCH:
                self._word(p + pos)
                pos += 4
        if pos < n and pos + 4 > n:     # a word split across transfers: keep its head
            memcpy(self.carry, p + pos, n - pos)
            self.ncarry = <int>(n - pos)
            pos = n
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
        return dict(words=n.words, time_high_words=n.info[<int>IN_TIME_HIGH],
                    events_decoded=self.decoded, exposure_events=n.info[<int>IN_EXPOSURE],
                    events_tracked=self.tracked, time_wraps=n.info[<int>IN_TIME_WRAPS],
                    gaps=self.gaps, bytes=self.bytes_in, pending_bytes=self.ncarry,
                    anomalies=dict(unknown_type=n.anomalies[<int>AN_UNKNOWN_TYPE],
                                   out_of_geometry=n.anomalies[<int>AN_OUT_OF_GEOMETRY],
                                   time_backwards=n.anomalies[<int>AN_TIME_BACKWARDS],
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
