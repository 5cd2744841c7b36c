# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""Float64 tracker kernel: a translation of springtrack/reference.py, equal to it to 1e-9 px.

This module is the kernel as its users see it: the ``Kernel`` class (model and parameters
loaded into a KState, the Python API of springtrack.tracker's backends) and the calls a
C-level loop makes through ``Kernel.stepper()`` (springtrack/backends/stepper.pxd), with the
sample row (ksnapshot).  The algorithm lives in its parts, one job each:

  kernel/state.pxd       the state (KState), capacities and step codes
  kernel/step.pxd        the per-event step, eqs. (2)-(6): kstep, ksteps
  kernel/index.pxd       the spatial index the step scans candidates from
  kernel/activity.pxd    eq. (6)'s activity, stored rescaled, its exps logged and batched
  kernel/covariance.pxd  eq. (4)'s covariance clamped and inverted for eq. (2)
  kernel/springs.pyx     springs and energy criteria, eqs. (7)-(22), incl. the similarity
                    frame, per instance, and the state guard (a mean outside the position
                    box resets its instance to the model's state)

Several model instances (springtrack.instances, a ModelSet) as in the reference: their
trackers side by side, eq. (2)'s argmin over the union of the sensitive trackers (an event
feeds at most one tracker of one instance; ties: the lowest index), springs, eq. (13)'s
mean energy, eqs. (21)-(22), the centre of mass and the similarity frame per instance
with its own parameters, each on its own spring clock (the events it takes and those no
tracker takes near it); only a tracking instance is sensitive and runs its springs.

The step, the index, the covariance clamp and the activity log are cdef inline functions
in .pxd files, so the whole per-event path compiles into this module as one unit (ksteps
inlined in the Stepper's steps()); the springs, once per spring_period events of an
instance's spring clock, are a call into springtrack.kernel.springs.

The per-event loop touches no Python object, allocates nothing and runs without the GIL.
Equations cite Valeiras et al. 2015; comments marked [ref] point at the reference lines
they translate.  The per-event arithmetic (eqs. 2-5) keeps the reference's order of
floating-point operations, so its decisions match even on exact ties (the activity is
stored rescaled, see kernel/activity.pxd: equal up to rounding); the springs do not (see
kernel/springs.pyx), so the two differ by rounding, ~1e-13 px over a million events.

Speed comes from ideas that do not change any decision of the algorithm:
* argmin of the Mahalanobis distance d^2 (eq. 2 in the log domain, no exp per tracker);
* a coarse spatial index: a bitmask of trackers per 8x8 px cell (one word per 64
  trackers: one word up to 64, the one-word path of eq. 2 kept for them) whose gate box
  (|dx| <= sqrt(gate*sxx), |dy| <= sqrt(gate*syy), enlarged by a margin) covers the cell.
  Trackers outside an event's cell cannot have d^2 < gate, so scanning only the cell's
  candidates, in index order, finds exactly the full scan's winner;
* springs in structure-of-arrays passes over the connections (gather, branch-free
  arithmetic that GCC vectorises in csrc/springs.h, scatter), with per-connection
  coefficients (kind-masked stiffnesses, 1/mass of both ends) precomputed, and eq. (14)'s
  angles measured in a frame that follows the mean angle (one atan per connection, no
  octant logic, while no connection strays far: see kernel/springs.pyx ksprings);
* eq. (6)'s exps logged and computed in vectorised batches (kernel/activity.pxd), as nothing
  in the event loop reads the activity;
* libm's exp, atan2, sin and cos replaced by csrc/fastmath.h (about 1 ulp; vectorised
  atan2, sincos and exp batches).  Results then differ from the reference by rounding only
  (~1e-15 relative), far inside the 1e-9 px contract of tests/test_springtrack/kernel/test_equivalence.py.
"""
from libc.stdlib cimport calloc, free
from libc.string cimport memset
from libc.stdint cimport int64_t, uint64_t

import numpy as np
cimport numpy as cnp

from springtrack.events cimport Event
from springtrack import limits as _limits
from springtrack.instances import InstanceState as _IS, ModelSet as _ModelSet, per_instance
from springtrack.params import Params as _Params
from springtrack.gate import covariance_bias, RHO_MAX as _RHO_MAX
from springtrack.reference import VELOCITY_MAX as _VMAX, P_UNKNOWN as _PU

from springtrack.backends.samples cimport SampleOut
from springtrack.track cimport TrackRow
from springtrack.backends.stepper cimport Stepper, run_array
from springtrack.kernel.state cimport (KState, MAX_TRACKERS, MAX_CONNECTIONS, MAX_INSTANCES,
                                  MAX_SET_TRACKERS, MAX_SET_CONNECTIONS, MAX_WORDS,
                                  CELL_SHIFT, K_SEARCHING, K_TRACKING, K_LOST)
from springtrack.kernel.step cimport kstep, ksteps
from springtrack.kernel.covariance cimport clamp_and_invert, ST_RHO_MAX, ST_RHO_MAX2
from springtrack.kernel.index cimport reindex
from springtrack.kernel.motion cimport predict_dt, still, clampd, ST_VELOCITY_MAX, ST_P_UNKNOWN
from springtrack.kernel.activity cimport (activity_decay, flush_activity, kactivity,
                                         rescale_activity)
from springtrack.kernel.springs cimport (ksprings, set_period, init_springs, init_instance, compose_sensitive,
                                    rest_trackers)

cdef extern from "springtrack/csrc/springs.h" nogil:
    double st_sum(int n, const double* x)

cnp.import_array()

assert (_limits.MAX_TRACKERS, _limits.MAX_CONNECTIONS, _limits.MAX_INSTANCES,
        _limits.MAX_SET_TRACKERS, _limits.MAX_SET_CONNECTIONS) == (
    MAX_TRACKERS, MAX_CONNECTIONS, MAX_INSTANCES, MAX_SET_TRACKERS, MAX_SET_CONNECTIONS), \
    "kernel/state.pxd's capacities disagree with springtrack/limits.py"
assert MAX_WORDS * 64 == MAX_SET_TRACKERS
assert ST_VELOCITY_MAX == _VMAX and ST_P_UNKNOWN == _PU, "kernel/motion.pxd disagrees with reference.py"
assert (_IS.SEARCHING, _IS.TRACKING, _IS.LOST) == (K_SEARCHING, K_TRACKING, K_LOST)
assert ST_RHO_MAX == _RHO_MAX and ST_RHO_MAX2 == _RHO_MAX * _RHO_MAX * (1.0 - 1e-12), \
    "kernel/covariance.pxd disagrees with reference.py"


# ---- the sample row -------------------------------------------------------------------
cdef void ksnapshot(const KState* s, int64_t t, SampleOut* o) noexcept nogil:
    # the row's pointer in a local: stores through it could alias the SampleOut fields,
    # which the compiler would otherwise reload for every tracker
    cdef Py_ssize_t row = o.count
    cdef int i, q
    cdef double a
    cdef double decay = activity_decay(s, t)         # kactivity's factor, one exp for all
    cdef double lead
    cdef double thr = s.act_thr
    cdef TrackRow* r = o.trackers + row * s.n
    o.t[row] = t
    for i in range(s.n):
        a = s.act[i] * decay
        lead = predict_dt(s, i, t)                    # [ref] snapshot: eq. (M1) at t
        r[i].x = s.mx[i] + s.vx[i] * lead
        r[i].y = s.my[i] + s.vy[i] * lead
        r[i].sxx = s.sxx[i]
        r[i].sxy = s.sxy[i]
        r[i].syy = s.syy[i]
        r[i].activity = a
        r[i].vx = s.vx[i] * 1e6                       # px/s
        r[i].vy = s.vy[i] * 1e6
        r[i].active = a > thr
        r[i].sensitive = (s.sensitive[i >> 6] >> (i & 63)) & 1
        r[i].state = s.state[s.inst[i]]
    for q in range(3):                                # eq. (13) of each kind
        o.energy[row * 3 + q] = st_sum(s.nc, s.energy[q]) / s.nc if s.nc > 0 else 0.0
    o.count = row + 1


# ---- the Stepper's calls (springtrack/backends/stepper.pxd): kstep, ksteps and ksnapshot on an
# opaque state; ksteps is inlined in steps_opaque, the loop a C caller runs per batch
cdef int step_opaque(void* s, int64_t t, int x, int y) noexcept nogil:
    # the Stepper's one-event call carries no polarity: ON (the batch call, steps, reads it)
    return kstep(<KState*>s, t, x, y, 1)


cdef Py_ssize_t steps_opaque(void* s, const Event* ev, Py_ssize_t n, int64_t t_stop) noexcept nogil:
    return ksteps(<KState*>s, ev, n, t_stop)


cdef void snapshot_opaque(const void* s, int64_t t, SampleOut* o) noexcept nogil:
    ksnapshot(<const KState*>s, t, o)


# ---- Python wrapper -----------------------------------------------------------------
cdef load_rest(KState* s, int g, arr):
    """Instance g's rest geometry from its model (``ShapeModel.arrays()``): the means and
    covariances the state starts from and the guard resets it to, the offsets to the rest
    centre of mass, the connections' rest lengths, angles and offsets."""
    cdef int i, k, t0 = s.g_t0[g], c0 = s.g_c0[g]
    for i in range(s.g_t1[g] - t0):
        s.rest_x[t0 + i] = arr["x"][i]
        s.rest_y[t0 + i] = arr["y"][i]
        s.rest_sxx[t0 + i] = arr["sxx"][i]
        s.rest_sxy[t0 + i] = arr["sxy"][i]
        s.rest_syy[t0 + i] = arr["syy"][i]
        s.gdx0[t0 + i] = arr["gdx0"][i]
        s.gdy0[t0 + i] = arr["gdy0"][i]
    for k in range(s.g_c1[g] - c0):
        s.l0[c0 + k] = arr["l0"][k]
        s.th0[c0 + k] = arr["th0"][k]
        s.dx0[c0 + k] = arr["dx0"][k]
        s.dy0[c0 + k] = arr["dy0"][k]


cdef class Kernel:
    """Owns one KState. ``Kernel(model, params)``: a ShapeModel and its Params, or a
    ``springtrack.instances.ModelSet`` (params None: each instance's own); see
    springtrack.tracker.Tracker for the API and springtrack.reference.ReferenceTracker for
    the instances' calls (states, set_state, place, move)."""

    movable = True                     # move(): an instance moved rigidly, state kept

    def __cinit__(self):
        self.st.cells = NULL

    cdef Stepper stepper(self):
        cdef Stepper sp
        sp.state = &self.st
        sp.step = step_opaque
        sp.steps = steps_opaque
        sp.snapshot = snapshot_opaque
        sp.n = self.st.n
        sp.last_t = &self.st.last_t
        sp.n_back = &self.st.n_back
        sp.n_outside = &self.st.n_outside
        sp.wire_records = False
        return sp

    def __init__(self, model, params):
        cdef KState* s = &self.st
        cdef int g, i, k
        if isinstance(model, _ModelSet):
            mset = model if params is None else model.with_params(params)
        else:
            mset = _ModelSet([model], params if params is not None else _Params())
        arr = mset.arrays()
        n, nc, ni = mset.n, mset.nc, len(mset)
        if (ni > MAX_INSTANCES or n > MAX_SET_TRACKERS or nc > MAX_SET_CONNECTIONS
                or any(inst.n > MAX_TRACKERS or inst.nc > MAX_CONNECTIONS for inst in mset)):
            raise ValueError(f"model exceeds kernel capacity ({MAX_TRACKERS} trackers, "
                             f"{MAX_CONNECTIONS} connections a model; {MAX_INSTANCES} "
                             f"instances, {MAX_SET_TRACKERS} trackers, {MAX_SET_CONNECTIONS} "
                             f"connections in all)")
        if s.cells != NULL:
            free(s.cells)
            s.cells = NULL
        memset(s, 0, sizeof(KState))
        self.model = mset
        s.n = n
        s.nc = nc
        s.ni = ni
        s.nw = (n + 63) >> 6
        s.width = mset.width
        s.height = mset.height
        s.gw = ((s.width - 1) >> CELL_SHIFT) + 1
        s.gh = ((s.height - 1) >> CELL_SHIFT) + 1
        s.cells = <uint64_t*>calloc(s.gw * s.gh * s.nw, sizeof(uint64_t))
        if s.cells == NULL:
            raise MemoryError()
        s.pos_lo_x, s.pos_hi_x, s.pos_lo_y, s.pos_hi_y = _limits.position_box(s.width, s.height)
        for g in range(ni):
            s.g_t0[g], s.g_t1[g] = arr["inst_t0"][g], arr["inst_t1"][g]
            s.g_c0[g], s.g_c1[g] = arr["inst_c0"][g], arr["inst_c1"][g]
            s.state[g] = K_TRACKING
            for i in range(s.g_t0[g], s.g_t1[g]):
                s.inst[i] = g
            load_rest(s, g, mset[g].model.arrays())
        for i in range(n):
            s.mx[i] = s.rest_x[i]
            s.my[i] = s.rest_y[i]
            s.sxx[i] = s.rest_sxx[i]
            s.sxy[i] = s.rest_sxy[i]
            s.syy[i] = s.rest_syy[i]
            s.mass[i] = arr["mass"][i]
            s.act[i] = 0.0
            still(s, i)
        s.act_n = 0
        for k in range(nc):
            s.ca[k] = arr["ca"][k]
            s.cb[k] = arr["cb"][k]
            s.kinds[k] = arr["kinds"][k]
            s.stiff[k] = arr["stiffness"][k]
        init_springs(s)
        s.last_t = -(1 << 62)
        self.set_params(mset.params_list)
        for i in range(n):
            clamp_and_invert(s, i)
            s.box_x0[i] = 0
            s.box_x1[i] = -1
            s.box_y0[i] = 0
            s.box_y1[i] = -1
            reindex(s, i)
        s.n_reindex = 0

    def _instance(self, g):
        if not 0 <= g < self.st.ni:
            raise IndexError(f"instance {g} out of range [0, {self.st.ni})")
        return g

    def _rest(self, int g, model):
        """Instance g's model replaced by ``model`` (the same trackers and connections):
        the set's, and the rest geometry; returns its arrays."""
        self.model = self.model.replaced(g, model)
        arr = model.arrays()
        load_rest(&self.st, g, arr)
        return arr

    # ---- the instances (springtrack.reference.ReferenceTracker's calls) ----------------
    def states(self):
        """Each instance's state (springtrack.instances.InstanceState codes)."""
        return [int(self.st.state[g]) for g in range(self.st.ni)]

    def set_state(self, int g, int state):
        """Instance g's state; a tracking instance's trackers are sensitive, the others'
        are not (the next spring update decides eq. 21 again)."""
        cdef KState* s = &self.st
        self._instance(g)
        s.state[g] = state
        n = s.g_t1[g] - s.g_t0[g]
        s.isens[g] = (~(<uint64_t>0) if n >= 64 else ((<uint64_t>1) << n) - 1) \
            if state == K_TRACKING else 0
        compose_sensitive(s)

    def place(self, int g, model):
        """Instance g placed as ``model`` (the same trackers and connections): positions,
        covariances and the rest geometry from it, activities 0, the frame at rest;
        tracking (springtrack.reference.ReferenceTracker.place)."""
        cdef KState* s = &self.st
        cdef int64_t moves = s.n_frame_moves
        self._instance(g)
        self._rest(g, model)
        rest_trackers(s, g)
        init_instance(s, g)                # the rest terms' coefficients, the frame at rest
        s.n_frame_moves = moves
        self.set_state(g, K_TRACKING)

    def relocate(self, int g, idx, x, y, sxx, sxy, syy):
        """Instance g's trackers ``idx`` at means (x, y), covariances (sxx, sxy, syy),
        activities 0; the others, the rest geometry, the frame and the state kept
        (springtrack.reference.ReferenceTracker.relocate), the index updated."""
        cdef KState* s = &self.st
        cdef int i, k
        self._instance(g)
        flush_activity(s)                  # the increments logged so far, first
        for k in range(len(idx)):
            i = s.g_t0[g] + <int>idx[k]
            if not s.g_t0[g] <= i < s.g_t1[g]:
                raise IndexError(f"relocate: tracker {int(idx[k])} is not in instance {g}")
            s.mx[i], s.my[i] = float(x[k]), float(y[k])
            s.sxx[i], s.sxy[i], s.syy[i] = float(sxx[k]), float(sxy[k]), float(syy[k])
            s.act[i] = 0.0
            still(s, i)
            clamp_and_invert(s, i)
            reindex(s, i)

    def move(self, int g, sim, model):
        """Instance g moved rigidly by ``sim`` = (a, b, tx, ty), x -> A x + t with
        A = [[a, -b], [b, a]], keeping activities, sensitivities, state and deformation;
        the rest geometry from ``model`` (its model moved by the same sim).  As
        springtrack.reference.ReferenceTracker.move (the specification), with the spatial
        index rebuilt."""
        cdef KState* s = &self.st
        cdef double a = sim[0], b = sim[1], tx = sim[2], ty = sim[3]
        cdef double x, y, sxx, sxy, syy, pxx, pxy, pyx, pyy, gx, gy, fc, fs
        cdef int i
        cdef int64_t moves = s.n_frame_moves
        self._instance(g)
        inst = self.model[g]
        if len(model.trackers) != inst.n or len(model.connections) != inst.nc:
            raise ValueError(f"move: the model has {len(model.trackers)} trackers and "
                             f"{len(model.connections)} connections, instance {inst.label} "
                             f"{inst.n} and {inst.nc}")
        fc, fs, gx, gy = s.sim_c[g], s.sim_s[g], s.sim_gx[g], s.sim_gy[g]
        self._rest(g, model)
        init_instance(s, g)                # the rest terms' coefficients
        s.n_frame_moves = moves
        s.sim_c[g], s.sim_s[g] = fc, fs
        s.sim_gx[g] = a * gx - b * gy + tx
        s.sim_gy[g] = b * gx + a * gy + ty
        for i in range(s.g_t0[g], s.g_t1[g]):
            x, y = s.mx[i], s.my[i]
            s.mx[i] = a * x - b * y + tx                     # mu' = A mu + t
            s.my[i] = b * x + a * y + ty
            sxx, sxy, syy = s.sxx[i], s.sxy[i], s.syy[i]
            # Sigma' = A Sigma A^T
            pxx, pxy = a * sxx - b * sxy, a * sxy - b * syy
            pyx, pyy = b * sxx + a * sxy, b * sxy + a * syy
            s.sxx[i] = pxx * a - pxy * b
            s.sxy[i] = pxx * b + pxy * a
            s.syy[i] = pyx * b + pyy * a
            x, y = s.vx[i], s.vy[i]                          # v' = A v, h' = A h
            s.vx[i] = clampd(a * x - b * y, -ST_VELOCITY_MAX, ST_VELOCITY_MAX)
            s.vy[i] = clampd(b * x + a * y, -ST_VELOCITY_MAX, ST_VELOCITY_MAX)
            x, y = s.hx[i], s.hy[i]
            s.hx[i] = clampd(a * x - b * y, -s.h_max, s.h_max)
            s.hy[i] = clampd(b * x + a * y, -s.h_max, s.h_max)
            clamp_and_invert(s, i)
            reindex(s, i)

    def __dealloc__(self):
        if self.st.cells != NULL:
            free(self.st.cells)
            self.st.cells = NULL

    def set_params(self, params):
        """Apply validated springtrack.params.Params (between two events): one for every
        instance, or one per instance (the shared ones equal)."""
        cdef KState* s = &self.st
        cdef int g, i, k
        plist = per_instance(params, s.ni)
        self.model = self.model.with_params(plist)
        p = plist[0]                                 # SHARED_PARAMS: the same in all
        self.params = p
        s.gate = p.gate_d2
        if s.tau != p.activity_tau_us and s.n_valid > 0:
            rescale_activity(s, s.last_t)          # [ref] a new tau decays from now on
        s.tau = p.activity_tau_us
        s.inv_tau = 1.0 / s.tau
        s.act_span = <int64_t>(32.0 * s.tau)
        s.act_thr = p.activity_threshold
        s.smin2 = p.sigma_min_px * p.sigma_min_px
        s.smax2 = p.sigma_max_px * p.sigma_max_px
        set_period(s, p.spring_period)             # [ref] each instance's clock kept
        # [ref] the motion model (eqs. M1-M8): 0 turns each part off
        s.horizon = p.prediction_horizon_us
        tau = p.motion_tau_us
        s.tau_m = tau
        s.q_m = 1.0 / (tau * tau * tau) if tau > 0.0 else 0.0
        s.vv_max = 1.0 / (tau * tau) if tau > 0.0 else 0.0
        s.c_h = p.polarity_gain
        s.h_max = p.sigma_max_px
        for g in range(s.ni):
            q = plist[g]
            gain = q.alpha_covariance / covariance_bias(q.alpha_position, q.gate_d2)
            for i in range(s.g_t0[g], s.g_t1[g]):
                s.gain[i][0] = q.alpha_position                 # eq. (3)
                s.gain[i][1] = 1.0 - q.alpha_covariance         # eq. (4)
                s.gain[i][2] = gain
                s.inv_a1[i] = 1.0 / max(q.alpha_position, 1e-6)        # eq. (M3)
            s.energy_scale[g] = q.energy_scale
            s.energy_gain[g] = q.energy_gain
            s.ekind[g] = q.energy_kind_index
            s.pull_sim[g] = 1 if q.pull_similarity else 0
            s.car_sim[g] = 1 if q.cartesian_similarity else 0
            s.need_torsion[g] = 1 if s.ekind[g] == 1 else 0
            for k in range(s.g_c0[g], s.g_c1[g]):
                if s.kinds[k] & 2:
                    s.need_torsion[g] = 1
            if s.g_c1[g] == s.g_c0[g]:
                s.need_torsion[g] = 0
        if s.cells != NULL:
            for i in range(s.n):
                clamp_and_invert(s, i)
                reindex(s, i)

    def run(self, events, long long sample_us, long long next_t, Py_ssize_t cap, into=None):
        """Process ``events`` (EVENT_DTYPE, C-contiguous). Returns (consumed, next_t, samples)
        where samples is a dict of arrays with at most ``cap`` rows (None if sample_us <= 0),
        written in ``into`` if given (backends/stepper.pyx run_array)."""
        return run_array(self.stepper(), events, sample_us, next_t, cap, False, into)

    def step(self, long long t, int x, int y, int p=1):
        """One event of polarity p (1 ON, 0 OFF)."""
        return kstep(&self.st, t, x, y, p)

    def springs(self):
        ksprings(&self.st)

    def snapshot(self, long long t):
        """Dict of per-tracker arrays at event time t."""
        cdef KState* s = &self.st
        n = s.n
        act = np.array([kactivity(s, i, t) for i in range(n)])
        lead = [predict_dt(s, i, t) for i in range(n)]
        return dict(x=np.array([s.mx[i] + s.vx[i] * lead[i] for i in range(n)]),
                    y=np.array([s.my[i] + s.vy[i] * lead[i] for i in range(n)]),
                    sxx=np.array([s.sxx[i] for i in range(n)]),
                    sxy=np.array([s.sxy[i] for i in range(n)]),
                    syy=np.array([s.syy[i] for i in range(n)]),
                    activity=act, vx=np.array([s.vx[i] * 1e6 for i in range(n)]),
                    vy=np.array([s.vy[i] * 1e6 for i in range(n)]), active=act > s.act_thr,
                    sensitive=np.array([bool((s.sensitive[i >> 6] >> (i & 63)) & 1)
                                        for i in range(n)]),
                    state=np.array([s.state[s.inst[i]] for i in range(n)], np.uint8))

    def energies(self):
        """(3, nc) array of the energies of every instance's connections, in order, each at
        its instance's last spring update: euclidean, torsional, cartesian."""
        cdef KState* s = &self.st
        out = np.empty((3, s.nc))
        cdef double[:, ::1] o = out
        cdef int q, k
        for q in range(3):
            for k in range(s.nc):
                o[q, k] = s.energy[q][k]
        return out

    @property
    def mean_energy(self):
        """eq. (13) of the first instance (:meth:`mean_energies`: every instance's)."""
        return self.st.mean_energy[0]

    def mean_energies(self):
        return [self.st.mean_energy[g] for g in range(self.st.ni)]

    def frame(self, int g=0):
        """Instance g's similarity frame of the last spring update (st_fit_frame): (c, sn,
        gx, gy) with s R = [[c, -sn], [sn, c]] and (gx, gy) the image of the rest centre of
        mass; (1, 0, G0) until a spring update fits one."""
        self._instance(g)
        return (self.st.sim_c[g], self.st.sim_s[g], self.st.sim_gx[g], self.st.sim_gy[g])

    @property
    def last_t(self):
        return self.st.last_t

    def counters(self):
        cdef KState* s = &self.st
        return dict(events_valid=s.n_valid, events_assigned=s.n_assigned,
                    skipped_back_in_time=s.n_back, skipped_outside_sensor=s.n_outside,
                    spring_updates=s.n_spring_updates, index_updates=s.n_reindex,
                    state_resets=s.n_resets)

    def frame_stats(self):
        """Diagnostics of eq. (14)'s fast path (ksprings): spring updates that fell back to
        the full atan2 (a connection more than 3 pi/8 from its frame direction), and
        frame moves (the mean angle drifted by more than FRAME_SLACK)."""
        return dict(frame_misses=self.st.n_frame_misses, frame_moves=self.st.n_frame_moves)
