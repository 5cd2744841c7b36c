# One tracker backend as seen by a C-level event loop (firmware_sim._fused): its state and
# the calls such a loop makes, so the loop runs the float64 kernel (_kernel.Kernel) and
# the fixed-point kernel (_fixed.FixedKernel) alike without knowing their state.
#
#     cdef Stepper sp = (<Kernel>k).stepper()       # or (<FixedKernel>k).stepper()
#     with nogil:
#         sp.step(sp.state, t, x, y)                # Algorithm 1 for one event
#         c = sp.steps(sp.state, ev, n, t_stop)     # ... for ev[0], ev[1], ... (see below)
#         sp.snapshot(sp.state, t, &out)            # one SampleOut row at time t
#
# steps() runs the events in order and stops before the first one with t >= t_stop that
# is not back in time (t >= the last event time), which it leaves unprocessed; it returns
# how many it processed.  It is step() in a loop, compiled inside the kernel so the step
# is inlined: no call through a pointer per event.
#
# run_events() below is the loop with sampling built on steps() and snapshot(); the
# sampling rule itself is springtrack/csrc/sampling.h (mirrored by springtrack/sampling.py):
# steps() stops before the event st_sample_due() names.
#
# The pointers stay valid while the kernel object is alive: hold a reference to it.
from libc.stdint cimport int64_t
from springtrack.events cimport Event
from springtrack.backends.samples cimport SampleOut

cdef extern from "springtrack/csrc/sampling.h" nogil:
    const int64_t ST_UNSET                   # next sample time before the first event
    const int ST_HOLD                        # sample periods an empty stretch is sampled for
    int64_t st_first_sample(int64_t t0, int64_t period)
    bint st_sample_due(int64_t t, int64_t next_t, int64_t last_t)
    int64_t st_next_sample(int64_t t, int64_t next_t, int64_t last_t, int64_t period)

ctypedef int (*step_fn)(void* state, int64_t t, int x, int y) noexcept nogil
ctypedef Py_ssize_t (*steps_fn)(void* state, const Event* ev, Py_ssize_t n,
                                int64_t t_stop) noexcept nogil
ctypedef void (*snapshot_fn)(const void* state, int64_t t, SampleOut* o) noexcept nogil

cdef struct Stepper:
    void* state
    step_fn step
    steps_fn steps
    snapshot_fn snapshot
    int n                         # trackers (columns of a SampleOut row)
    const int64_t* last_t         # time of the last event processed, µs
    const int64_t* n_back         # events skipped: earlier than last_t
    const int64_t* n_outside      # events skipped: outside the sensor
    bint wire_records             # snapshot() also packs SampleOut.wire from the state

# the event loop of Kernel.run, FixedKernel.run and the fused loop (springtrack/backends/stepper.pyx)
cdef Py_ssize_t run_events(const Stepper* sp, const Event* ev, Py_ssize_t n, int64_t sample_us,
                           int64_t* next_t, SampleOut* o) noexcept nogil
cdef tuple run_array(Stepper sp, events, int64_t sample_us, int64_t next_t, Py_ssize_t cap,
                     bint records=*, dict into=*)
