# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# distutils: depends = springtrack/fixed/csrc/fixed_step.c springtrack/fixed/csrc/fixed_step.h springtrack/fixed/csrc/fixed_tables.h springtrack/fixed/csrc/fixed_telemetry.c springtrack/fixed/csrc/fixed_telemetry.h springtrack/csrc/sampling.h springtrack/fixed/csrc/fixed_arith.c springtrack/fixed/csrc/fixed_motion.c springtrack/fixed/csrc/fixed_index.c springtrack/fixed/csrc/fixed_tracker.c springtrack/fixed/csrc/fixed_set.c springtrack/fixed/csrc/fixed_spring.c springtrack/fixed/csrc/fixed_frame.c springtrack/fixed/csrc/fixed_update.c springtrack/fixed/csrc/fixed_load.c springtrack/fixed/csrc/fixed_move.c
"""Fixed-point tracker backend (``Tracker(..., backend="fixed")``).

The per-event step and the springs are the integer-only C unit
``springtrack/fixed/csrc/fixed_step.c`` (compiled into this module by ``#include`` so that it
inlines); this wrapper converts the model and parameters to their Q formats
(:mod:`springtrack.fixed.q`) once, runs the event loop without the GIL, and converts the
integer state to float64 only when a sample is taken.  Same interface as
``springtrack.kernel.kernel.Kernel``; docs/fixed_point.md has the formats and error bounds.
"""
from libc.stdlib cimport calloc, free
from libc.stdint cimport int64_t, uint64_t, int32_t, uint32_t, uint16_t, uint8_t

import numpy as np
cimport numpy as cnp

from springtrack.events cimport Event
from springtrack.events import EVENT_DTYPE
from springtrack.fixed import q as _q
from springtrack import limits as _limits
from springtrack import wire as _wire

from springtrack.backends.samples cimport SampleOut, sample_buffers
from springtrack.track cimport TrackRow
from springtrack.backends.stepper cimport Stepper, run_array

cnp.import_array()

cdef extern from "csrc/fixed_step.h" nogil:
    enum:
        FX_MAX_TRACKERS
        FX_MAX_CONNECTIONS
        FX_MAX_INSTANCES
        FX_MAX_SET_TRACKERS
        FX_MAX_SET_CONNECTIONS
        FX_TRACKING
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
        int64_t tlast[FX_MAX_TRACKERS]
        int32_t vx[FX_MAX_TRACKERS]
        int32_t vy[FX_MAX_TRACKERS]
        int64_t hx[FX_MAX_TRACKERS]
        int64_t hy[FX_MAX_TRACKERS]
        int64_t tm[FX_MAX_TRACKERS]
        int64_t kpp[FX_MAX_TRACKERS]
        int64_t kpv[FX_MAX_TRACKERS]
        int64_t kvv[FX_MAX_TRACKERS]
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
    ctypedef struct fx_set:
        int32_t ni
        fx_state* inst[FX_MAX_INSTANCES]
        int32_t t0[FX_MAX_INSTANCES]
        int32_t state[FX_MAX_INSTANCES]
        int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_spring_updates
    int fx_set_init(fx_set* g, fx_state** inst, int32_t ni)
    int fx_set_step(fx_set* g, int64_t t, int32_t x, int32_t y, int32_t p)
    int64_t fx_set_steps(fx_set* g, const fx_event* ev, int64_t n, int64_t t_stop)
    void fx_set_springs(fx_set* g)
    void fx_set_state(fx_set* g, int q, int32_t state)
    int fx_load_model(fx_state* s, const int32_t* w, int32_t nw, uint64_t* cells, int32_t cap)
    int fx_set_params(fx_state* s, const int32_t* w, int32_t nw)
    int fx_move(fx_state* s, const int32_t* w, int32_t nw)
    int fx_relocate(fx_state* s, const int32_t* w, int32_t nw)
    int32_t fx_cells_needed(int32_t width, int32_t height)
    int fx_step(fx_state* s, int64_t t, int32_t x, int32_t y, int32_t p)
    int64_t fx_steps(fx_state* s, const fx_event* ev, int64_t n, int64_t t_stop)
    void fx_springs(fx_state* s)
    void fx_energies(fx_state* s)
    void fx_reindex(fx_state* s, int i)
    int64_t fx_activity(const fx_state* s, int i, int64_t t)
    void fx_predicted(const fx_state* s, int i, int64_t t, int64_t* x, int64_t* y)

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
assert (_limits.MAX_INSTANCES == FX_MAX_INSTANCES
        and _limits.MAX_SET_TRACKERS == FX_MAX_SET_TRACKERS
        and _limits.MAX_SET_CONNECTIONS == FX_MAX_SET_CONNECTIONS), \
    "fixed_step.h FX_MAX_INSTANCES / FX_MAX_SET_* disagree with limits.py"
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
cdef double VEL_UNIT = _q.VEL_UNIT            # Q.32 px/us as px/s (eq. M7)


cdef object _ints(const int64_t* a, int n):
    """a[0..n) as an int64 array (raw_state)."""
    return np.array([a[i] for i in range(n)], np.int64)


cdef inline void tracker_rows(const fx_state* s, int64_t t, TrackRow* r,
                              uint8_t state) noexcept nogil:
    """The state's trackers at event time t as float64 rows r[0..n)."""
    cdef int i
    cdef int64_t a, x, y
    for i in range(s.n):
        a = fx_activity(s, i, t)
        fx_predicted(s, i, t, &x, &y)             # eq. (M1): the means at t
        r[i].x = x * POS_UNIT
        r[i].y = y * POS_UNIT
        r[i].sxx = s.sxx[i] * COV_UNIT
        r[i].sxy = s.sxy[i] * COV_UNIT
        r[i].syy = s.syy[i] * COV_UNIT
        r[i].activity = a * Q32_UNIT
        r[i].vx = s.vx[i] * VEL_UNIT                # eq. (M7), px/s
        r[i].vy = s.vy[i] * VEL_UNIT
        r[i].active = a > s.act_thr
        r[i].sensitive = (s.sensitive_mask >> i) & 1
        r[i].state = state


cdef inline void energy_sums(const fx_state* s, int64_t* tot) noexcept nogil:
    """Adds each kind's energies of the last spring update (Q.40) to tot[0..3)."""
    cdef int k, q
    fx_energies(<fx_state*>s)     # the kinds the criterion does not use, computed when read
    for q in range(3):
        for k in range(s.nc):
            tot[q] += s.energy[q][k]


cdef inline void snapshot_row(const fx_state* s, int64_t t, SampleOut* o) noexcept nogil:
    cdef Py_ssize_t row = o.count, base = row * s.n
    cdef int q
    cdef int64_t tot[3]
    o.t[row] = t
    tracker_rows(s, t, o.trackers + base, 1)
    tot[0] = tot[1] = tot[2] = 0
    energy_sums(s, tot)
    for q in range(3):
        o.energy[row * 3 + q] = (<double>tot[q]) * Q40_UNIT / s.nc if s.nc > 0 else 0.0
    if o.wire != NULL:
        fx_tele_records(s, t, o.wire + base * FX_TELE_RECORD)
    o.count = row + 1


cdef int fixed_step(void* state, int64_t t, int x, int y) noexcept nogil:
    """One event on a FixedKernel's state (declared in fixed/kernel.pxd for other modules),
    of polarity ON, as the Stepper's step() (backends/stepper.pxd) has none."""
    return fx_step(<fx_state*>state, t, x, y, 1)


cdef Py_ssize_t fixed_steps(void* state, const Event* ev, Py_ssize_t n,
                            int64_t t_stop) noexcept nogil:
    # fx_event (fixed/csrc/fixed_step.h) has Event's layout
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
        in the Q formats of fixed.q.move_words), with the spatial index rebuilt."""
        cdef fx_state* s = <fx_state*>self.state
        cdef int32_t[::1] words = _q.move_words(sim, model, s.n, s.nc)
        rc = fx_move(s, &words[0], words.shape[0])
        if rc != FX_OK:
            raise ValueError(f"fixed kernel: the move does not load (fx_move {rc}): the "
                             f"model must be the instance's own, moved")
        self.model = model

    def relocate(self, idx, x, y, sxx, sxy, syy):
        """Trackers ``idx`` at means (x, y) and covariances (sxx, sxy, syy), activities 0;
        the others, the rest geometry, the frame and the state kept
        (springtrack.reference.ReferenceTracker.relocate, in integers: fx_relocate)."""
        cdef fx_state* s = <fx_state*>self.state
        cdef int32_t[::1] words = _q.relocate_words(idx, x, y, sxx, sxy, syy)
        rc = fx_relocate(s, &words[0], words.shape[0])
        if rc != FX_OK:
            raise ValueError(f"fixed kernel: the relocation does not load (fx_relocate {rc})")

    def run(self, events, long long sample_us, long long next_t, Py_ssize_t cap, into=None):
        """Process ``events`` (EVENT_DTYPE, C-contiguous). Returns (consumed, next_t, samples)
        where samples is a dict of arrays with at most ``cap`` rows (None if sample_us <= 0),
        written in ``into`` if given (backends/stepper.pyx run_array)."""
        return run_array(self.stepper(), events, sample_us, next_t, cap, False, into)

    def step(self, long long t, int x, int y, int p=1):
        """One event of polarity p (1 ON, 0 OFF)."""
        return fx_step(<fx_state*>self.state, t, x, y, p)

    def springs(self):
        fx_springs(<fx_state*>self.state)

    def telemetry_records(self, long long t):
        """The TELEMETRY tracker records (``springtrack.wire.TELE_TRACKER`` layout) at event
        time t, packed from the integer state (fixed/csrc/fixed_telemetry.c)."""
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
        cdef int64_t px, py
        act = np.array([fx_activity(s, i, t) * Q32_UNIT for i in range(n)])
        xs, ys = np.empty(n), np.empty(n)
        for i in range(n):
            fx_predicted(s, i, t, &px, &py)        # eq. (M1): the means at t
            xs[i] = px * POS_UNIT
            ys[i] = py * POS_UNIT
        return dict(x=xs, y=ys,
                    sxx=np.array([s.sxx[i] * COV_UNIT for i in range(n)]),
                    sxy=np.array([s.sxy[i] * COV_UNIT for i in range(n)]),
                    syy=np.array([s.syy[i] * COV_UNIT for i in range(n)]),
                    activity=act, vx=np.array([s.vx[i] * VEL_UNIT for i in range(n)]),
                    vy=np.array([s.vy[i] * VEL_UNIT for i in range(n)]),
                    active=np.array([fx_activity(s, i, t) > s.act_thr for i in range(n)]),
                    sensitive=np.array([bool((s.sensitive_mask >> i) & 1) for i in range(n)]),
                    state=np.ones(n, np.uint8))

    def raw_state(self):
        """The integer state itself (Q formats of docs/fixed_point.md): x, y Q.32 int64;
        sxx, sxy, syy Q.40 int64; activity Q.32 (at the tracker's last event); the motion
        model's (eqs. M1-M8, fixed/csrc/fixed_motion.c): vx, vy Q.32 px/us, hx, hy Q.32 px,
        tk, tm us, kpp, kpv, kvv Q.32 (units of tau_m)."""
        cdef fx_state* s = <fx_state*>self.state
        n = s.n
        return dict(x=_ints(s.mx, n), y=_ints(s.my, n), sxx=_ints(s.sxx, n),
                    sxy=_ints(s.sxy, n), syy=_ints(s.syy, n), activity=_ints(s.act, n),
                    vx=np.array([s.vx[i] for i in range(n)], np.int64),
                    vy=np.array([s.vy[i] for i in range(n)], np.int64),
                    hx=_ints(s.hx, n), hy=_ints(s.hy, n), tk=_ints(s.tlast, n),
                    tm=_ints(s.tm, n), kpp=_ints(s.kpp, n), kpv=_ints(s.kpv, n),
                    kvv=_ints(s.kvv, n))

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


# ---- several model instances (springtrack.instances) ----------------------------------

cdef void set_snapshot(const void* state, int64_t t, SampleOut* o) noexcept nogil:
    """One row of every instance's trackers, side by side (an fx_set's states)."""
    cdef const fx_set* g = <const fx_set*>state
    cdef const fx_state* s
    cdef int q, nc = 0
    cdef int ntot = g.t0[g.ni - 1] + g.inst[g.ni - 1].n
    cdef Py_ssize_t row = o.count, base = row * ntot
    cdef int64_t tot[3]
    o.t[row] = t
    tot[0] = tot[1] = tot[2] = 0
    for q in range(g.ni):
        s = g.inst[q]
        tracker_rows(s, t, o.trackers + base + g.t0[q], <uint8_t>g.state[q])
        energy_sums(s, tot)
        nc += s.nc
        if o.wire != NULL:
            fx_tele_records(s, t, o.wire + (base + g.t0[q]) * FX_TELE_RECORD)
    for q in range(3):
        o.energy[row * 3 + q] = (<double>tot[q]) * Q40_UNIT / nc if nc > 0 else 0.0
    o.count = row + 1


cdef int set_step(void* state, int64_t t, int x, int y) noexcept nogil:
    return fx_set_step(<fx_set*>state, t, x, y, 1)


cdef Py_ssize_t set_steps(void* state, const Event* ev, Py_ssize_t n,
                          int64_t t_stop) noexcept nogil:
    return fx_set_steps(<fx_set*>state, <const fx_event*>ev, n, t_stop)


_SET_COUNTERS = ("index_updates", "saturated_position", "saturated_activity",
                 "saturated_energy", "saturated_inverse", "state_resets")


cdef class FixedSet:
    """Several model instances on the fixed kernel: one FixedKernel (fx_state) per
    instance, and one event assignment over all of them (fixed/csrc/fixed_step.c's fx_set).
    ``FixedSet(mset)``: a springtrack.instances.ModelSet, each instance with its own
    parameters.  The backend interface of springtrack.tracker (run, snapshot, energies,
    frame(g), counters, ...) and the instances' (states, set_state, place, move)."""

    cdef fx_set* g
    cdef list kernels
    cdef object mset
    cdef dict done                        # counters of the kernels place() replaced
    movable = True

    def __cinit__(self):
        self.g = <fx_set*>calloc(1, sizeof(fx_set))
        if self.g == NULL:
            raise MemoryError()

    def __dealloc__(self):
        if self.g != NULL:
            free(self.g)
            self.g = NULL

    def __init__(self, mset):
        cdef fx_state* inst[FX_MAX_INSTANCES]
        if len(mset) > FX_MAX_INSTANCES or mset.n > FX_MAX_SET_TRACKERS \
                or mset.nc > FX_MAX_SET_CONNECTIONS:
            raise ValueError(f"{len(mset)} instances of {mset.n} trackers and {mset.nc} "
                             f"connections exceed the fixed kernel's capacity "
                             f"({FX_MAX_INSTANCES}, {FX_MAX_SET_TRACKERS}, "
                             f"{FX_MAX_SET_CONNECTIONS})")
        self.mset = mset
        self.kernels = [FixedKernel(i.model, i.params) for i in mset]
        for q, k in enumerate(self.kernels):
            inst[q] = <fx_state*>(<FixedKernel>k).state
        rc = fx_set_init(self.g, inst, len(self.kernels))
        if rc != FX_OK:
            raise ValueError(f"fixed kernel: the instances do not load (fx_set_init {rc})")
        self.done = {}

    cdef Stepper stepper(self):
        cdef Stepper sp
        sp.state = self.g
        sp.step = set_step
        sp.steps = set_steps
        sp.snapshot = set_snapshot
        sp.n = self.mset.n
        sp.last_t = &self.g.last_t
        sp.n_back = &self.g.n_back
        sp.n_outside = &self.g.n_outside
        sp.wire_records = True
        return sp

    def run(self, events, long long sample_us, long long next_t, Py_ssize_t cap, into=None):
        """As FixedKernel.run, over every instance's trackers."""
        return run_array(self.stepper(), events, sample_us, next_t, cap, False, into)

    def step(self, long long t, int x, int y, int p=1):
        """One event of polarity p; the winner's index among all trackers, or a NO_/SKIPPED_
        code."""
        return fx_set_step(self.g, t, x, y, p)

    def springs(self):
        fx_set_springs(self.g)

    def set_params(self, params):
        """One Params for every instance, or one per instance (the shared ones equal)."""
        from springtrack.instances import per_instance
        plist = per_instance(params, len(self.kernels))
        self.mset = self.mset.with_params(plist)
        for k, p in zip(self.kernels, plist):
            k.set_params(p)

    # ---- the instances' states --------------------------------------------------------
    def states(self):
        return [int(self.g.state[q]) for q in range(self.g.ni)]

    def set_state(self, int g, state):
        fx_set_state(self.g, g, int(state))

    def place(self, int g, model):
        """Instance g placed as ``model`` (the same trackers and connections): a kernel of
        it, as loaded (activities 0, the frame at rest), on the set's clock; tracking."""
        cdef FixedKernel old = self.kernels[g]
        cdef FixedKernel k
        self.mset = self.mset.replaced(g, model)
        for key, v in old.counters().items():
            if key in _SET_COUNTERS:
                self.done[key] = self.done.get(key, 0) + v
        k = FixedKernel(model, self.mset[g].params)
        cdef fx_state* s = <fx_state*>k.state
        s.last_t = self.g.last_t
        s.n_valid = self.g.n_valid
        s.n_back = self.g.n_back
        s.n_outside = self.g.n_outside
        self.kernels[g] = k
        self.g.inst[g] = s
        fx_set_state(self.g, g, FX_TRACKING)

    def relocate(self, int g, idx, x, y, sxx, sxy, syy):
        """Instance g's trackers ``idx`` put elsewhere (FixedKernel.relocate)."""
        self.kernels[g].relocate(idx, x, y, sxx, sxy, syy)

    def move(self, int g, sim, model):
        """Instance g moved rigidly by ``sim`` (FixedKernel.move: fx_move on its state)."""
        self.kernels[g].move(sim, model)
        self.mset = self.mset.replaced(g, model)

    # ---- observation ------------------------------------------------------------------
    def snapshot(self, long long t):
        parts = [k.snapshot(t) for k in self.kernels]
        out = {f: np.concatenate([p[f] for p in parts]) for f in parts[0]}
        out["state"] = np.concatenate([np.full(len(p["x"]), self.g.state[q], np.uint8)
                                       for q, p in enumerate(parts)])
        return out

    def telemetry_records(self, long long t):
        return b"".join(k.telemetry_records(t) for k in self.kernels)

    def energies(self):
        """(3, nc) array of every instance's energies, in order (each at its last spring
        update)."""
        return np.concatenate([k.energies() for k in self.kernels], axis=1)

    @property
    def mean_energy(self):
        return self.kernels[0].mean_energy

    def mean_energies(self):
        return [k.mean_energy for k in self.kernels]

    def frame(self, int g=0):
        return self.kernels[g].frame()

    @property
    def last_t(self):
        return self.g.last_t

    def counters(self):
        c = dict(events_valid=self.g.n_valid, events_assigned=self.g.n_assigned,
                 skipped_back_in_time=self.g.n_back, skipped_outside_sensor=self.g.n_outside,
                 spring_updates=self.g.n_spring_updates)
        for key in _SET_COUNTERS:
            c[key] = self.done.get(key, 0) + sum(k.counters()[key] for k in self.kernels)
        return c
