# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The event loop with sampling shared by every tracker backend (see _stepper.pxd)."""
cimport numpy as cnp
from libc.stdint cimport int64_t, INT64_MAX

from springtrack.events cimport Event
from springtrack.events import EVENT_DTYPE
from springtrack.sampling import HOLD, MAX_PERIOD, UNSET
from springtrack._samples cimport SampleOut, sample_buffers, take_samples

cnp.import_array()

assert ST_UNSET == UNSET and ST_HOLD == HOLD, "csrc/sampling.h disagrees with springtrack/sampling.py"


cdef Py_ssize_t run_events(const Stepper* sp, const Event* ev, Py_ssize_t n, int64_t sample_us,
                           int64_t* next_t, SampleOut* o) noexcept nogil:
    """Process events until done or the sample buffer is full; returns events consumed.
    The sampling rule (csrc/sampling.h): ``next_t`` ST_UNSET becomes the first sample time
    after ev[0]; before an event at t for which st_sample_due(t, next_t, the last event
    time), one snapshot per sample time <= t (the state after all earlier events), those
    of an empty stretch past its ST_HOLD periods skipped (st_next_sample)."""
    cdef Py_ssize_t k = 0
    cdef int64_t t
    if sample_us <= 0:
        while k < n:
            k += sp.steps(sp.state, ev + k, n - k, INT64_MAX)
            if k < n:                  # stopped at t == INT64_MAX: not a sample time
                sp.step(sp.state, ev[k].t, ev[k].x, ev[k].y)
                k += 1
        return n
    if n > 0 and next_t[0] == ST_UNSET:
        next_t[0] = st_first_sample(ev[0].t, sample_us)
    while True:
        k += sp.steps(sp.state, ev + k, n - k, next_t[0])
        if k >= n:
            return n
        t = ev[k].t                    # st_sample_due(t, next_t[0], the last event time)
        while True:
            next_t[0] = st_next_sample(t, next_t[0], sp.last_t[0], sample_us)
            if t < next_t[0]:
                break
            if o.count >= o.cap:
                return k
            sp.snapshot(sp.state, next_t[0], o)
            next_t[0] += sample_us


cdef tuple run_array(Stepper sp, events, int64_t sample_us, int64_t next_t, Py_ssize_t cap,
                     bint records=False):
    """``Kernel.run`` / ``FixedKernel.run``: (consumed, next_t, samples) where samples is a
    dict of arrays with at most ``cap`` rows (None if sample_us <= 0; keys as
    _samples.sample_buffers; ``next_t`` springtrack.sampling.UNSET before the first event
    sets the first sample time); with ``records`` a kernel that packs TELEMETRY records
    (the Stepper's wire_records) adds them (``wire``)."""
    cdef cnp.ndarray ev = events
    cdef Py_ssize_t n = ev.shape[0], consumed
    cdef SampleOut o
    if ev.dtype != EVENT_DTYPE or not ev.flags.c_contiguous:
        raise TypeError("events must be a C-contiguous EVENT_DTYPE array")
    if sample_us >= MAX_PERIOD:
        raise ValueError(f"sampling period {sample_us} us is not below {MAX_PERIOD} us")
    if sample_us <= 0:
        cap = 0
    out = sample_buffers(cap, sp.n, &o, records and sp.wire_records)
    cdef const Event* p = <const Event*>cnp.PyArray_DATA(ev)
    with nogil:
        consumed = run_events(&sp, p, n, sample_us, &next_t, &o)
    if sample_us <= 0:
        return consumed, next_t, None
    return consumed, next_t, take_samples(out, &o, False)
