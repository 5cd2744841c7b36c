# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# distutils: depends = springtrack/csrc/fixed_step.c springtrack/csrc/fixed_step.h springtrack/csrc/fixed_tables.h springtrack/csrc/fixed_telemetry.c springtrack/csrc/fixed_telemetry.h springtrack/csrc/sampling.h
"""Fixed-point tracker backend (``Tracker(..., backend="fixed")``).

The per-event step and the springs are the integer-only C unit
``springtrack/csrc/fixed_step.c`` (compiled into this module by ``#include`` so that it
inlines); this wrapper converts the model and parameters to their Q formats
(:mod:`springtrack.fixed_q`) once, runs the event loop without the GIL, and converts the
integer state to float64 only when a sample is taken.  Same interface as
``springtrack._kernel.Kernel``; docs/fixed_point.md has the formats and error bounds.
"""
from libc.stdlib cimport calloc, free
from libc.stdint cimport int64_t, uint64_t, int32_t, uint32_t, uint16_t, uint8_t

import numpy as np
cimport numpy as cnp

from springtrack.events cimport Event
from springtrack.events import EVENT_DTYPE
from springtrack import fixed_q as _q
from springtrack import limits as _limits
from springtrack import wire as _wire

from springtrack._samples cimport SampleOut, sample_buffers
from springtrack.track cimport TrackRow
from springtrack._stepper cimport Stepper, run_array

cnp.import_array()

cdef extern from "csrc/fixed_step.h" nogil:
    enum:
        FX_MAX_TRACKERS
        FX_MAX_CONNECTIONS
        FX_OK
    const int64_t FX_POS_LIM
    ctypedef struct fx_state:          # the fields this wrapper reads (fixed_step.h)
        int32_t n, nc, width, height
        int64_t act_thr
        int64_t mx[FX_MAX_TRACKERS]
        int64_t my[FX_MAX_TRACKERS]
        int64_t sxx[FX_MAX_TRACKERS]
        int64_t sxy[FX_MAX_TRACKERS]
        int64_t syy[FX_MAX_TRACKERS]
        int64_t act[FX_MAX_TRACKERS]
        uint64_t sensitive_mask
        int64_t energy[3][FX_MAX_CONNECTIONS]
        int64_t mean_energy
        int32_t frame_c, frame_s
        int64_t frame_gx, frame_gy
        int32_t energy_stale
        uint64_t* cells
        int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_spring_updates, n_reindex
        int64_t sat_position, sat_activity, sat_energy, sat_inverse
        int64_t n_resets
    ctypedef struct fx_event:
        int64_t t
        uint16_t x
        uint16_t y
        uint8_t p
    int fx_load_model(fx_state* s, const int32_t* w, int32_t nw, uint64_t* cells, int32_t cap)
    int fx_set_params(fx_state* s, const int32_t* w, int32_t nw)
    int fx_move(fx_state* s, const int32_t* w, int32_t nw)
    int32_t fx_cells_needed(int32_t width, int32_t height)
    int fx_step(fx_state* s, int64_t t, int32_t x, int32_t y)
    int64_t fx_steps(fx_state* s, const fx_event* ev, int64_t n, int64_t t_stop)
    void fx_springs(fx_state* s)
    void fx_energies(fx_state* s)
    void fx_reindex(fx_state* s, int i)
    int64_t fx_activity(const fx_state* s, int i, int64_t t)

cdef extern from "csrc/fixed_step.c":
    pass

cdef extern from "csrc/fixed_telemetry.h" nogil:
    enum:
        FX_TELE_RECORD
        FX_TELE_POS_SHIFT
        FX_TELE_SIGMA_SHIFT
        FX_TELE_RHO_SCALE
        FX_TELE_ACT_STEPS
    void fx_tele_records(const fx_state* s, int64_t t, uint8_t* out)

cdef extern from "csrc/fixed_telemetry.c":
    pass

# fx_event mirrors springtrack.events' Event (same members in the same order)
assert sizeof(fx_event) == sizeof(Event) == 16
assert _limits.MAX_TRACKERS == FX_MAX_TRACKERS and _limits.MAX_CONNECTIONS == FX_MAX_CONNECTIONS
assert FX_POS_LIM == _limits.POS_LIMIT_PX << 32, "fixed_step.h FX_POS_LIM disagrees with limits.py"
# the C telemetry packer writes springtrack.wire's layout: the scales must be the same
assert (_wire.TELE_TRACKER.itemsize == FX_TELE_RECORD
        and _wire.POS_SCALE == 2.0 ** (32 - FX_TELE_POS_SHIFT)
        and _wire.SIGMA_SCALE == 2.0 ** (20 - FX_TELE_SIGMA_SHIFT)
        and _wire.RHO_SCALE == FX_TELE_RHO_SCALE
        and _wire.ACT_SCALE == FX_TELE_ACT_STEPS), "fixed_telemetry.h disagrees with wire.py"

# float64 views of the Q formats (output only)
cdef double POS_UNIT = 1.0 / 4294967296.0     # Q.32 px
cdef double COV_UNIT = 1.0 / 1099511627776.0  # Q.40 px^2
cdef double Q32_UNIT = 1.0 / 4294967296.0     # Q.32 (activity)
cdef double Q40_UNIT = 1.0 / 1099511627776.0  # Q.40 (energies)


cdef inline void snapshot_row(const fx_state* s, int64_t t, SampleOut* o) noexcept nogil:
    cdef Py_ssize_t row = o.count, base = row * s.n
    cdef int i, k, q
    cdef int64_t a, tot
    cdef TrackRow* r = o.trackers + base
    o.t[row] = t
    for i in range(s.n):
        a = fx_activity(s, i, t)
        r[i].x = s.mx[i] * POS_UNIT
        r[i].y = s.my[i] * POS_UNIT
        r[i].sxx = s.sxx[i] * COV_UNIT
        r[i].sxy = s.sxy[i] * COV_UNIT
        r[i].syy = s.syy[i] * COV_UNIT
        r[i].activity = a * Q32_UNIT
        r[i].active = a > s.act_thr
        r[i].sensitive = (s.sensitive_mask >> i) & 1
        r[i].state = 1
    fx_energies(<fx_state*>s)     # the kinds the criterion does not use, computed when read
    for q in range(3):
        tot = 0
        for k in range(s.nc):
            tot += s.energy[q][k]
        o.energy[row * 3 + q] = (<double>tot) * Q40_UNIT / s.nc if s.nc > 0 else 0.0
    if o.wire != NULL:
        fx_tele_records(s, t, o.wire + base * FX_TELE_RECORD)
    o.count = row + 1


cdef int fixed_step(void* state, int64_t t, int x, int y) noexcept nogil:
    """One event on a FixedKernel's state (declared in _fixed.pxd for other modules)."""
    return fx_step(<fx_state*>state, t, x, y)


cdef Py_ssize_t fixed_steps(void* state, const Event* ev, Py_ssize_t n,
                            int64_t t_stop) noexcept nogil:
    # fx_event (csrc/fixed_step.h) has Event's layout
    return fx_steps(<fx_state*>state, <const fx_event*>ev, n, t_stop)


cdef void snapshot_opaque(const void* state, int64_t t, SampleOut* o) noexcept nogil:
    snapshot_row(<const fx_state*>state, t, o)


cdef class FixedKernel:
    """Owns one fx_state. ``FixedKernel(model, params)``; see springtrack.tracker.Tracker."""

    def __cinit__(self):
        self.state = calloc(1, sizeof(fx_state))
        if self.state == NULL:
            raise MemoryError()

    cdef Stepper stepper(self):
        cdef fx_state* s = <fx_state*>self.state
        cdef Stepper sp
        sp.state = self.state
        sp.step = fixed_step
        sp.steps = fixed_steps
        sp.snapshot = snapshot_opaque
        sp.n = s.n
        sp.last_t = &s.last_t
        sp.n_back = &s.n_back
        sp.n_outside = &s.n_outside
        sp.wire_records = True
        return sp

    def __init__(self, model, params):
        cdef fx_state* s = <fx_state*>self.state
        n = len(model.trackers)
        nc = len(model.connections)
        if n > FX_MAX_TRACKERS or nc > FX_MAX_CONNECTIONS:
            raise ValueError(f"model exceeds kernel capacity ({FX_MAX_TRACKERS} trackers, "
                             f"{FX_MAX_CONNECTIONS} connections)")
        cdef int32_t[::1] words = _q.model_words(model.arrays(), model.width, model.height)
        cdef int32_t cap = fx_cells_needed(model.width, model.height)
        if s.cells != NULL:
            free(s.cells)
            s.cells = NULL
        cdef uint64_t* cells = <uint64_t*>calloc(cap, sizeof(uint64_t))
        if cells == NULL:
            raise MemoryError()
        rc = fx_load_model(s, &words[0], words.shape[0], cells, cap)
        if rc != FX_OK:
            free(cells)
            raise ValueError(f"fixed kernel: the model does not load (fx_load_model {rc})")
        self.model = model
        self.set_params(params)

    def __dealloc__(self):
        cdef fx_state* s = <fx_state*>self.state
        if s != NULL:
            if s.cells != NULL:
                free(s.cells)
            free(s)
            self.state = NULL

    def set_params(self, params):
        """Apply validated springtrack.params.Params (between two events)."""
        cdef fx_state* s = <fx_state*>self.state
        cdef int32_t[::1] words = _q.params_words(params, s.nc)
        rc = fx_set_params(s, &words[0], words.shape[0])
        if rc != FX_OK:
            raise ValueError(f"fixed kernel: the parameters do not load (fx_set_params {rc})")
        self.params = params

    def move(self, sim, model):
        """The instance moved rigidly by ``sim`` = (a, b, tx, ty), x -> A x + t with
        A = [[a, -b], [b, a]], keeping activities, sensitivities and deformation; the rest
        geometry from ``model`` (the model moved by the same sim).  As
        springtrack.reference.ReferenceTracker.move, in integers (fx_move; the similarity
        in the Q formats of fixed_q.move_words), with the spatial index rebuilt."""
        cdef fx_state* s = <fx_state*>self.state
        cdef int32_t[::1] words = _q.move_words(sim, model, s.n, s.nc)
        rc = fx_move(s, &words[0], words.shape[0])
        if rc != FX_OK:
            raise ValueError(f"fixed kernel: the move does not load (fx_move {rc}): the "
                             f"model must be the instance's own, moved")
        self.model = model

    def run(self, events, long long sample_us, long long next_t, Py_ssize_t cap):
        """Process ``events`` (EVENT_DTYPE, C-contiguous). Returns (consumed, next_t, samples)
        where samples is a dict of arrays with at most ``cap`` rows (None if sample_us <= 0)."""
        return run_array(self.stepper(), events, sample_us, next_t, cap)

    def step(self, long long t, int x, int y):
        return fx_step(<fx_state*>self.state, t, x, y)

    def springs(self):
        fx_springs(<fx_state*>self.state)

    def telemetry_records(self, long long t):
        """The TELEMETRY tracker records (``springtrack.wire.TELE_TRACKER`` layout) at event
        time t, packed from the integer state (csrc/fixed_telemetry.c)."""
        cdef fx_state* s = <fx_state*>self.state
        out = bytearray(s.n * FX_TELE_RECORD)
        cdef uint8_t[::1] mv = out
        if s.n:
            fx_tele_records(s, t, &mv[0])
        return bytes(out)

    def snapshot(self, long long t):
        """Dict of per-tracker float64 arrays at event time t."""
        cdef fx_state* s = <fx_state*>self.state
        n = s.n
        act = np.array([fx_activity(s, i, t) * Q32_UNIT for i in range(n)])
        return dict(x=np.array([s.mx[i] * POS_UNIT for i in range(n)]),
                    y=np.array([s.my[i] * POS_UNIT for i in range(n)]),
                    sxx=np.array([s.sxx[i] * COV_UNIT for i in range(n)]),
                    sxy=np.array([s.sxy[i] * COV_UNIT for i in range(n)]),
                    syy=np.array([s.syy[i] * COV_UNIT for i in range(n)]),
                    activity=act,
                    active=np.array([fx_activity(s, i, t) > s.act_thr for i in range(n)]),
                    sensitive=np.array([bool((s.sensitive_mask >> i) & 1) for i in range(n)]),
                    state=np.ones(n, np.uint8))

    def raw_state(self):
        """The integer state itself (Q formats of docs/fixed_point.md): x, y Q.32 int64;
        sxx, sxy, syy Q.40 int64; activity Q.32 (at the tracker's last event)."""
        cdef fx_state* s = <fx_state*>self.state
        n = s.n
        return dict(x=np.array([s.mx[i] for i in range(n)], np.int64),
                    y=np.array([s.my[i] for i in range(n)], np.int64),
                    sxx=np.array([s.sxx[i] for i in range(n)], np.int64),
                    sxy=np.array([s.sxy[i] for i in range(n)], np.int64),
                    syy=np.array([s.syy[i] for i in range(n)], np.int64),
                    activity=np.array([s.act[i] for i in range(n)], np.int64))

    def energies(self):
        """(3, nc) array of the last spring update's energies: euclidean, torsional, cartesian."""
        cdef fx_state* s = <fx_state*>self.state
        fx_energies(s)
        return (np.array([[s.energy[q][k] * Q40_UNIT for k in range(s.nc)] for q in range(3)])
                .reshape(3, s.nc))

    @property
    def mean_energy(self):
        return (<fx_state*>self.state).mean_energy * Q40_UNIT

    def frame(self):
        """The similarity frame of the last spring update: (c, sn, gx, gy) as floats, s R =
        [[c, -sn], [sn, c]] (Q.28 in the state), (gx, gy) the image of the rest centre of
        mass (Q.32)."""
        cdef fx_state* s = <fx_state*>self.state
        return (s.frame_c / 268435456.0, s.frame_s / 268435456.0, s.frame_gx * POS_UNIT,
                s.frame_gy * POS_UNIT)

    @property
    def last_t(self):
        return (<fx_state*>self.state).last_t

    def counters(self):
        cdef fx_state* s = <fx_state*>self.state
        return dict(events_valid=s.n_valid, events_assigned=s.n_assigned,
                    skipped_back_in_time=s.n_back, skipped_outside_sensor=s.n_outside,
                    spring_updates=s.n_spring_updates, index_updates=s.n_reindex,
                    saturated_position=s.sat_position, saturated_activity=s.sat_activity,
                    saturated_energy=s.sat_energy, saturated_inverse=s.sat_inverse,
                    state_resets=s.n_resets)
