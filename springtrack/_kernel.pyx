# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""Float64 tracker kernel: a translation of springtrack/reference.py, equal to it to 1e-9 px.

The per-event loop touches no Python object, allocates nothing and runs without the GIL.
Equations cite Valeiras et al. 2015; comments marked [ref] point at the reference lines
they translate.  The per-event arithmetic (eqs. 2-5) keeps the reference's order of
floating-point operations, so its decisions match even on exact ties (the activity is
stored rescaled, see kactivity: equal up to rounding); the springs do not (see below),
so the two differ by rounding, ~1e-13 px
over a million events.

Speed comes from ideas that do not change any decision of the algorithm:
* argmin of the Mahalanobis distance d^2 (eq. 2 in the log domain, no exp per tracker);
* a coarse spatial index: a bitmask of trackers per 8x8 px cell whose gate box
  (|dx| <= sqrt(gate*sxx), |dy| <= sqrt(gate*syy), enlarged by a margin) covers the cell.
  Trackers outside an event's cell cannot have d^2 < gate, so scanning only the cell's
  candidates, in index order, finds exactly the full scan's winner;
* springs in structure-of-arrays passes over the connections (gather, branch-free
  arithmetic that GCC vectorises in csrc/springs.h, scatter), with per-connection
  coefficients (kind-masked stiffnesses, 1/mass of both ends) precomputed, and eq. (14)'s
  angles measured in a frame that follows the mean angle (one atan per connection, no
  octant logic, while no connection strays far: see ksprings);
* eq. (6)'s exps logged and computed in vectorised batches (log_activity), as nothing in
  the event loop reads the activity;
* libm's exp, atan2, sin and cos replaced by csrc/fastmath.h (about 1 ulp; vectorised
  atan2, sincos and exp batches).  Results then differ from the reference by rounding only
  (~1e-15 relative), far inside the 1e-9 px contract of tests/test_equivalence.py.
"""
from libc.math cimport exp, sqrt, cos, sin, floor, fabs, M_PI
from libc.stdlib cimport calloc, free
from libc.string cimport memset
from libc.stdint cimport int64_t, uint64_t, uint8_t

import numpy as np
cimport numpy as cnp

from springtrack.events cimport Event
from springtrack.events import EVENT_DTYPE
from springtrack import limits as _limits
from springtrack.reference import covariance_bias, RHO_MAX as _RHO_MAX
from springtrack import reference as _ref

from springtrack._samples cimport SampleOut, sample_buffers
from springtrack.track cimport TrackRow
from springtrack._stepper cimport Stepper, run_array, st_sample_due

cnp.import_array()

assert _limits.MAX_TRACKERS == MAX_TRACKERS and _limits.MAX_CONNECTIONS == MAX_CONNECTIONS
assert (_ref.FRAME_SCALE_MIN, _ref.FRAME_SCALE_MAX, _ref.FRAME_MIN_SPREAD) == (
    ST_FRAME_SCALE_MIN, ST_FRAME_SCALE_MAX, ST_FRAME_MIN_SPREAD), "springs.h disagrees with reference.py"

cdef double RHO_MAX = _RHO_MAX
cdef double RHO_MAX2 = _RHO_MAX * _RHO_MAX * (1.0 - 1e-12)   # slightly low: never miss a clamp
cdef double TWO_PI = 2.0 * M_PI
# A gate box is (re)indexed enlarged by INDEX_GROW of itself plus INDEX_MARGIN px, so that a
# mean jittering by a fraction of sigma (alpha_position = 0.2 moves it ~0.3 sigma) does not
# re-index every few events.  Any enlargement keeps the scan exact; these only trade
# re-indexing against candidates (docs/benchmarks.md, "Where the time goes").
# After each update a cheap sufficient test (st_box_left) re-indexes a tracker once its
# sigmas have grown by INDEX_SIGMA_SLACK or its mean has moved by what that growth leaves
# of the enlargement: four comparisons instead of the exact gate box, for re-indexing a
# little earlier than needed.
cdef double INDEX_MARGIN = 3.0
cdef double INDEX_GROW = 0.25
cdef double INDEX_SIGMA_SLACK = 0.05
# The frame of eq. (14)'s fast path (st_torsion_angles_framed) follows the mean angle once
# it is this far (rad) from it: connections within 3 pi/8 - pi/16 of the mean angle then
# stay on the fast path.
cdef double FRAME_SLACK = M_PI / 16




cdef extern from *:
    """
    static inline int st_ctz64(unsigned long long v) { return __builtin_ctzll(v); }
    """
    int st_ctz64(unsigned long long v) nogil

cdef extern from "csrc/fastmath.h" nogil:
    void st_exp_batch(const double* x, double* out, int n)
    void st_atan2_batch(const double* y, const double* x, double* out, int n)
    void st_sincos_batch(const double* e, double* sn, double* cm1, int n)

cdef extern from "csrc/springs.h" nogil:
    double st_sum(int n, const double* x)
    void st_over_ends(int nc, const double* e, double thr, const uint64_t* ends,
                      uint64_t* pulled, uint64_t* calm)
    void st_pull(int n, uint64_t pulled, double gx, double gy, double c, double sn, double gain,
                 const double* gdx0, const double* gdy0, double* mx, double* my)
    double ST_FRAME_SCALE_MIN, ST_FRAME_SCALE_MAX, ST_FRAME_MIN_SPREAD
    void st_fit_frame(int n, uint64_t fit, const double* mass, const double* gdx0,
                      const double* gdy0, const double* mx, const double* my, double rx,
                      double ry, double* c, double* sn, double* gx, double* gy)
    void st_turn_offsets(int n, double c, double sn, const double* dx0, const double* dy0,
                         double* odx, double* ody)
    void st_torsion_angles(int n, const double* rx, const double* ry, const double* rdx,
                           const double* rdy, const double* dth_zero, double* th)
    int64_t st_torsion_angles_framed(int n, const double* rx, const double* ry,
                                     const double* qdx, const double* qdy, double phi,
                                     double* th)
    void st_torsion_rotation(int n, const double* th, double mean, const double* half_a,
                             const double* a_tor, double* e_tor, double* eps, double* sn,
                             double* cm1)
    void st_spring_terms_batch(int n, const double* rx, const double* ry, const double* sn,
                               const double* cm1, const double* l0, const double* half_a,
                               const double* dx0, const double* dy0, const double* c0,
                               const double* s0, const double* a_euc, const double* a_car,
                               const double* wa, const double* wb,
                               double* e_euc, double* e_car, double* uax, double* uay,
                               double* ubx, double* uby)
    int64_t st_box_left(double mx, double my, double sxx, double syy, double bcx, double bcy,
                        double dev_x, double dev_y, double sxx_lim, double syy_lim)
    void st_boxes_left(int n, const double* mx, const double* my, const double* sxx,
                       const double* syy, const double* bcx, const double* bcy,
                       const double* dev_x, const double* dev_y, const double* sxx_lim,
                       const double* syy_lim, int64_t* out)


# ---- spatial index ------------------------------------------------------------------
cdef inline void index_set(KState* s, int i, int x0, int x1, int y0, int y1, bint on) noexcept nogil:
    cdef int cx, cy
    cdef uint64_t bit = (<uint64_t>1) << i
    for cy in range(y0, y1 + 1):
        for cx in range(x0, x1 + 1):
            if on:
                s.cells[cy * s.gw + cx] |= bit
            else:
                s.cells[cy * s.gw + cx] &= ~bit


cdef inline int clampi(int v, int lo, int hi) noexcept nogil:
    if v < lo:
        return lo
    if v > hi:
        return hi
    return v


cdef inline int cell_of(const KState* s, double v, int gmax) noexcept nogil:
    # floor division of a pixel coordinate by the cell size, clamped to the grid
    cdef double c = floor(v / (1 << CELL_SHIFT))
    if not c >= 0.0:                   # below the grid, or not a number
        return 0
    if c > gmax:
        return gmax
    return <int>c


cdef void reindex(KState* s, int i) noexcept nogil:
    """(Re)insert tracker i with its current gate box enlarged by INDEX_GROW and INDEX_MARGIN,
    and set the slack of st_box_left: the gate box may grow by INDEX_SIGMA_SLACK (sigma,
    i.e. the variances by its square) and the mean move by what is then left of the
    enlargement; shrunk by 1e-9 relative so rounding can never make the test miss."""
    cdef double gx = sqrt(s.gate * s.sxx[i]), gy = sqrt(s.gate * s.syy[i])
    cdef double hx = gx * (1.0 + INDEX_GROW) + INDEX_MARGIN
    cdef double hy = gy * (1.0 + INDEX_GROW) + INDEX_MARGIN
    cdef double grow2 = (1.0 + INDEX_SIGMA_SLACK) * (1.0 + INDEX_SIGMA_SLACK) * (1.0 - 1e-9)
    s.bx_lo[i] = s.mx[i] - hx
    s.bx_hi[i] = s.mx[i] + hx
    s.by_lo[i] = s.my[i] - hy
    s.by_hi[i] = s.my[i] + hy
    s.bcx[i] = s.mx[i]
    s.bcy[i] = s.my[i]
    s.dev_x[i] = (gx * (INDEX_GROW - INDEX_SIGMA_SLACK) + INDEX_MARGIN) * (1.0 - 1e-9)
    s.dev_y[i] = (gy * (INDEX_GROW - INDEX_SIGMA_SLACK) + INDEX_MARGIN) * (1.0 - 1e-9)
    s.sxx_lim[i] = s.sxx[i] * grow2
    s.syy_lim[i] = s.syy[i] * grow2
    index_set(s, i, s.box_x0[i], s.box_x1[i], s.box_y0[i], s.box_y1[i], False)
    s.box_x0[i] = cell_of(s, s.bx_lo[i], s.gw - 1)
    s.box_x1[i] = cell_of(s, s.bx_hi[i], s.gw - 1)
    s.box_y0[i] = cell_of(s, s.by_lo[i], s.gh - 1)
    s.box_y1[i] = cell_of(s, s.by_hi[i], s.gh - 1)
    index_set(s, i, s.box_x0[i], s.box_x1[i], s.box_y0[i], s.box_y1[i], True)
    s.n_reindex += 1


cdef inline void check_index(KState* s, int i) noexcept nogil:
    """Re-index tracker i if its exact gate box may have left the box it is indexed with."""
    if st_box_left(s.mx[i], s.my[i], s.sxx[i], s.syy[i], s.bcx[i], s.bcy[i], s.dev_x[i],
                   s.dev_y[i], s.sxx_lim[i], s.syy_lim[i]):
        reindex(s, i)


# ---- per tracker ----------------------------------------------------------------------
cdef inline void clamp_and_invert(KState* s, int i) noexcept nogil:
    # [ref] _clamp_and_invert
    cdef double sxx = s.sxx[i], syy = s.syy[i], sxy = s.sxy[i], lim, inv_det
    if sxx < s.smin2:
        sxx = s.smin2
    if sxx > s.smax2:
        sxx = s.smax2
    if syy < s.smin2:
        syy = s.smin2
    if syy > s.smax2:
        syy = s.smax2
    if sxy * sxy > RHO_MAX2 * (sxx * syy):       # |rho| may exceed RHO_MAX: the exact test
        lim = RHO_MAX * sqrt(sxx * syy)
        if sxy < -lim:
            sxy = -lim
        if sxy > lim:
            sxy = lim
    s.sxx[i] = sxx
    s.sxy[i] = sxy
    s.syy[i] = syy
    inv_det = 1.0 / (sxx * syy - sxy * sxy)                         # [ref] one division
    s.ia[i] = syy * inv_det
    s.ib2[i] = 2.0 * (-sxy * inv_det)
    s.ic[i] = sxx * inv_det


cdef inline void update_tracker(KState* s, int i, int64_t t, double fx, double fy, double d2) noexcept nogil:
    # [ref] _update
    # eq. (6) with eq. (2)'s unnormalised kernel value p = exp(-d2/2) as the increment,
    # kept rescaled (see kactivity): act += p * exp((t - act_t0) / tau), one exp (logged)
    if t - s.act_t0 > s.act_span:
        rescale_activity(s, t)
    log_activity(s, i, -0.5 * d2 + <double>(t - s.act_t0) * s.inv_tau)
    cdef double dx = fx - s.mx[i]                                    # eq. (5), pre-update mean
    cdef double dy = fy - s.my[i]
    s.mx[i] = s.mx[i] + s.a1 * dx                                    # eq. (3)
    s.my[i] = s.my[i] + s.a1 * dy
    s.sxx[i] = s.keep * s.sxx[i] + s.cov_gain * (dx * dx)           # eq. (4)
    s.sxy[i] = s.keep * s.sxy[i] + s.cov_gain * (dx * dy)
    s.syy[i] = s.keep * s.syy[i] + s.cov_gain * (dy * dy)
    clamp_and_invert(s, i)
    check_index(s, i)


cdef Py_ssize_t ksteps(KState* s, const Event* ev, Py_ssize_t n, int64_t t_stop) noexcept nogil:
    """kstep() over ev[0..n), stopping before the first event with t >= t_stop that is not
    back in time (the sampling rule, csrc/sampling.h, with t_stop the next sample time);
    returns the events processed (the Stepper's steps(), _stepper.pxd).
    The counters and the last time live in locals for the batch and are written back at
    its end (nothing the step calls reads them)."""
    cdef Py_ssize_t k
    cdef int64_t t, last_t = s.last_t, n_back = 0, n_outside = 0, n_valid = 0
    cdef int since = s.since_spring, period = s.period
    cdef unsigned int x, y, width = s.width, height = s.height
    for k in range(n):
        t = ev[k].t
        if st_sample_due(t, t_stop, last_t):
            break
        if t < last_t:
            n_back += 1
            continue
        last_t = t
        x = ev[k].x
        y = ev[k].y
        if x >= width or y >= height:
            n_outside += 1
            continue
        n_valid += 1
        assign_event(s, t, x, y)
        since += 1
        if since >= period:
            since = 0
            ksprings(s)
    else:
        k = n
    flush_activity(s)
    s.last_t = last_t
    s.since_spring = since
    s.n_back += n_back
    s.n_outside += n_outside
    s.n_valid += n_valid
    return k


cdef int kstep(KState* s, int64_t t, int x, int y) noexcept nogil:
    """One event (Algorithm 1). Returns the winning tracker, K_NO_TRACKER or a skip code.
    ksteps() is the same step over a batch, with the counters kept in locals."""
    if t < s.last_t:
        s.n_back += 1
        return K_BACK_IN_TIME
    s.last_t = t
    if x >= s.width or y >= s.height or x < 0 or y < 0:
        s.n_outside += 1
        return K_OUT_OF_SENSOR
    s.n_valid += 1
    cdef int best = assign_event(s, t, x, y)
    flush_activity(s)
    s.since_spring += 1
    if s.since_spring >= s.period:
        s.since_spring = 0
        ksprings(s)
    return best


cdef inline int assign_event(KState* s, int64_t t, int x, int y) noexcept nogil:
    """eqs. (2)-(6) for a valid event: the most probable sensitive tracker takes it."""
    cdef double fx = x, fy = y, dx, dy, d2
    cdef double best_d2 = s.gate
    cdef int best = K_NO_TRACKER, i
    # eq. (2): candidates are the sensitive trackers indexed in this event's cell, in
    # increasing index order, so ties resolve exactly as in the reference's full scan.
    cdef uint64_t m = s.cells[(y >> CELL_SHIFT) * s.gw + (x >> CELL_SHIFT)] & s.sensitive_mask
    while m:
        i = st_ctz64(m)
        m &= m - 1
        dx = fx - s.mx[i]
        dy = fy - s.my[i]
        d2 = s.ia[i] * dx * dx + s.ic[i] * dy * dy + s.ib2[i] * dx * dy
        if d2 < best_d2:
            best_d2 = d2
            best = i
    if best >= 0:
        update_tracker(s, best, t, fx, fy, best_d2)
        s.n_assigned += 1
    return best


# ---- springs and energy criteria ----------------------------------------------------
cdef inline double wrap_angle(double a) noexcept nogil:
    # [ref] wrap_angle: [-3 pi, 3 pi) -> [-pi, pi)
    if a >= M_PI:
        return a - TWO_PI
    if a < -M_PI:
        return a + TWO_PI
    return a


cdef void ksprings(KState* s) noexcept nogil:
    # [ref] springs, in structure-of-arrays passes (csrc/springs.h, vectorised):
    #   1. gather r = end b - end a;  2. eq. (14) angles, in the frame of a recent mean
    #   angle (fast) or from the rest directions;  3. eq. (15) mean angle;  4. eqs.
    #   (15)-(17) deviation, torsional energy and rotation (0. before them all, in the
    #   similarity frame: the Cartesian rest offsets turned and scaled);  5. eqs. (10)-(12), (16),
    #   (18)-(20) branch-free (a_euc/a_tor/a_car are 0 for kinds a connection lacks),
    #   displacements divided by each end's mass;  6. scatter onto the ends' means
    #   (scalar);  7. energy criteria (OR-reduced bit masks);  8. the state guard;  9.
    #   re-index the trackers whose gate boxes left their indexed boxes.
    # Rounding-level differences from the reference, none larger than ~1e-15 relative: the
    # three kinds' displacements are summed per connection and added straight to the means
    # (the reference adds them one by one to per-tracker sums, then those to the means);
    # the mean angle and the mean energy are summed in four interleaved partial sums
    # (st_sum: a chain of n/4 additions instead of n; both gate the rest of the update).
    cdef int n = s.n, nc = s.nc, k, i, j
    cdef int64_t left[MAX_TRACKERS]
    cdef double rx[MAX_CONNECTIONS]
    cdef double ry[MAX_CONNECTIONS]
    cdef double th[MAX_CONNECTIONS]
    cdef double eps[MAX_CONNECTIONS]
    cdef double sn[MAX_CONNECTIONS]
    cdef double cm1[MAX_CONNECTIONS]
    cdef double uax[MAX_CONNECTIONS]
    cdef double uay[MAX_CONNECTIONS]
    cdef double ubx[MAX_CONNECTIONS]
    cdef double uby[MAX_CONNECTIONS]
    cdef double odx[MAX_CONNECTIONS]
    cdef double ody[MAX_CONNECTIONS]
    cdef const double* dx0 = s.dx0
    cdef const double* dy0 = s.dy0
    cdef double mean_dth = 0.0
    s.n_spring_updates += 1
    if s.car_sim:                      # 0. eq. (18): s R d0 in the last update's frame
        st_turn_offsets(nc, s.sim_c, s.sim_s, s.dx0, s.dy0, odx, ody)
        dx0 = odx
        dy0 = ody
    for k in range(nc):                                              # 1. gather
        i = s.ca[k]
        j = s.cb[k]
        rx[k] = s.mx[j] - s.mx[i]
        ry[k] = s.my[j] - s.my[i]
    if s.need_torsion:
        if st_torsion_angles_framed(nc, rx, ry, s.qdx, s.qdy, s.frame_phi, th):  # 2. eq. (14)
            s.n_frame_misses += 1
            st_torsion_angles(nc, rx, ry, s.rdx, s.rdy, s.dth_zero, th)
        mean_dth = st_sum(nc, th) / nc                               # 3. eq. (15)
        if fabs(mean_dth - s.frame_phi) > FRAME_SLACK:
            set_frame(s, mean_dth)
        st_torsion_rotation(nc, th, mean_dth, s.half_a, s.a_tor, s.energy[1], eps, sn,  # 4.
                            cm1)
    else:
        for k in range(nc):
            s.energy[1][k] = 0.0
            sn[k] = 0.0
            cm1[k] = 0.0
    st_spring_terms_batch(nc, rx, ry, sn, cm1, s.l0, s.half_a, dx0, dy0, s.c0, s.s0,  # 5.
                          s.a_euc, s.a_car, s.wa, s.wb, s.energy[0], s.energy[2],
                          uax, uay, ubx, uby)
    for k in range(nc):                                              # 6. scatter
        i = s.ca[k]
        j = s.cb[k]
        s.mx[i] += uax[k]
        s.my[i] += uay[k]
        s.mx[j] -= ubx[k]
        s.my[j] -= uby[k]
    energy_criteria(s)                                               # 7.
    if guard_state(s):                                               # 8.
        return
    st_boxes_left(n, s.mx, s.my, s.sxx, s.syy, s.bcx, s.bcy, s.dev_x, s.dev_y, s.sxx_lim,  # 9.
                  s.syy_lim, left)
    for i in range(n):
        if left[i]:
            reindex(s, i)


cdef bint guard_state(KState* s) noexcept nogil:
    """[ref] _guard: a mean outside the position box, or not a number, is a state no model
    within springtrack.limits reaches: counted, and the state reset to the model (True)."""
    cdef int i
    cdef bint out = False
    for i in range(s.n):
        out |= not (s.mx[i] >= s.pos_lo_x and s.mx[i] < s.pos_hi_x
                    and s.my[i] >= s.pos_lo_y and s.my[i] < s.pos_hi_y)
    if out:
        s.n_resets += 1
        reset_state(s)
    return out


cdef void reset_state(KState* s) noexcept nogil:
    """[ref] _reset_state, then every covariance clamped and inverted and every tracker
    re-indexed: the tracker state of the model, counters and time kept."""
    cdef int i, k, q
    for i in range(s.n):
        s.mx[i] = s.rest_x[i]
        s.my[i] = s.rest_y[i]
        s.sxx[i] = s.rest_sxx[i]
        s.sxy[i] = s.rest_sxy[i]
        s.syy[i] = s.rest_syy[i]
        s.act[i] = 0.0
    s.act_n = 0                        # increments logged for the state left behind
    for q in range(3):
        for k in range(s.nc):
            s.energy[q][k] = 0.0
    s.mean_energy = 0.0
    s.sensitive_mask = ~(<uint64_t>0) if s.n == 64 else ((<uint64_t>1) << s.n) - 1
    s.sim_c = 1.0                      # [ref] the identity frame about G0 until a fit
    s.sim_s = 0.0
    if s.n:
        s.sim_gx = s.mx[0] - s.gdx0[0]
        s.sim_gy = s.my[0] - s.gdy0[0]
    set_frame(s, 0.0)
    for i in range(s.n):
        clamp_and_invert(s, i)
        reindex(s, i)


cdef void set_frame(KState* s, double phi) noexcept nogil:
    """Turn the rest directions by phi for st_torsion_angles_framed (a cache: any phi gives
    the same angles, up to rounding; one near the mean angle lets the fast path apply)."""
    cdef double c = cos(phi), sn = sin(phi)
    cdef int k
    s.frame_phi = phi
    for k in range(s.nc):
        s.qdx[k] = c * s.rdx[k] - sn * s.rdy[k]
        s.qdy[k] = sn * s.rdx[k] + c * s.rdy[k]
    s.n_frame_moves += 1


cdef void energy_criteria(KState* s) noexcept nogil:
    # [ref] _energy_criteria
    cdef int n = s.n, nc = s.nc, i
    cdef const double* e = s.energy[s.ekind]
    cdef double thr, msum = s.mass_sum, gx = 0.0, gy = 0.0
    cdef uint64_t pulled, calm
    if nc == 0:
        return
    s.mean_energy = st_sum(nc, e) / nc                               # eq. (13)
    thr = s.energy_scale * s.mean_energy
    st_over_ends(nc, e, thr, s.ends, &pulled, &calm)
    if s.pull_sim or s.car_sim:          # [ref] fit_frame over the trackers left alone
        st_fit_frame(n, ~pulled, s.mass, s.gdx0, s.gdy0, s.mx, s.my, s.sim_gx, s.sim_gy,
                     &s.sim_c, &s.sim_s, &s.sim_gx, &s.sim_gy)
    if s.pull_sim:                       # eq. (22) toward G + s R dG0, the fitted frame
        st_pull(n, pulled, s.sim_gx, s.sim_gy, s.sim_c, s.sim_s, s.energy_gain, s.gdx0,
                s.gdy0, s.mx, s.my)
    else:
        for i in range(n):                                           # eq. (22): G
            gx += s.mass[i] * s.mx[i]
            gy += s.mass[i] * s.my[i]
        gx = gx / msum
        gy = gy / msum
        st_pull(n, pulled, gx, gy, 1.0, 0.0, s.energy_gain, s.gdx0, s.gdy0, s.mx, s.my)
    s.sensitive_mask = calm | s.isolated     # eq. (21): insensitive if all its connections are over


cdef double kactivity(const KState* s, int i, int64_t t) noexcept nogil:
    """eq. (6) at time t: A_i(t) = sum over i's events k of p_k exp(-(t - t_k) / tau).
    Stored as act[i] = A_i(act_t0) = sum of p_k exp((t_k - act_t0) / tau), the same sum
    seen from a common time act_t0, so an event adds one term (one exp) instead of
    decaying the sum since the tracker's last event first (the reference's form; equal
    up to rounding, ~1e-15 relative)."""
    return s.act[i] * activity_decay(s, t)


cdef inline double activity_decay(const KState* s, int64_t t) noexcept nogil:
    """exp(-(t - act_t0) / tau): the factor from the stored activities to those at t, the
    same for every tracker."""
    return exp(-(<double>(t - s.act_t0)) * s.inv_tau)


cdef inline void log_activity(KState* s, int i, double arg) noexcept nogil:
    """act[i] += exp(arg), deferred: the increments wait in a log whose exps flush_activity
    computes as one vectorised batch (st_exp_batch: the same values as st_exp, about a
    third of its instructions each) and adds in the order logged, so every act[i] is the
    same sum as if added at once.  Nothing in the event loop reads act (eq. 6 only feeds
    the output), so the log is flushed before act_t0 moves (rescale_activity), when full,
    and whenever a batch of events ends (ksteps, kstep): outside them it is empty."""
    cdef int n = s.act_n
    s.act_i[n] = i
    s.act_arg[n] = arg
    s.act_n = n + 1
    if n + 1 == ACT_LOG:
        flush_activity(s)


cdef void flush_activity(KState* s) noexcept nogil:
    cdef double v[ACT_LOG]
    cdef int k, n = s.act_n
    if n == 0:
        return
    st_exp_batch(s.act_arg, v, n)
    for k in range(n):
        s.act[s.act_i[k]] += v[k]
    s.act_n = 0


cdef void rescale_activity(KState* s, int64_t t) noexcept nogil:
    """Move act_t0 to t (every act_span = 32 tau of event time), so the terms added,
    p exp((t - act_t0) / tau) <= e^32, stay far from overflow and rounding loss."""
    cdef int i
    cdef double f = activity_decay(s, t)
    flush_activity(s)                  # the logged exponents are relative to the old act_t0
    for i in range(s.n):
        s.act[i] *= f
    s.act_t0 = t


# ---- sampling -------------------------------------------------------------------------
cdef void ksnapshot(const KState* s, int64_t t, SampleOut* o) noexcept nogil:
    # the row's pointer in a local: stores through it could alias the SampleOut fields,
    # which the compiler would otherwise reload for every tracker
    cdef Py_ssize_t row = o.count
    cdef int i, q
    cdef double a
    cdef double decay = activity_decay(s, t)         # kactivity's factor, one exp for all
    cdef double thr = s.act_thr
    cdef uint64_t sensitive = s.sensitive_mask
    cdef TrackRow* r = o.trackers + row * s.n
    o.t[row] = t
    for i in range(s.n):
        a = s.act[i] * decay
        r[i].x = s.mx[i]
        r[i].y = s.my[i]
        r[i].sxx = s.sxx[i]
        r[i].sxy = s.sxy[i]
        r[i].syy = s.syy[i]
        r[i].activity = a
        r[i].active = a > thr
        r[i].sensitive = (sensitive >> i) & 1
    for q in range(3):                                # eq. (13) of each kind
        o.energy[row * 3 + q] = st_sum(s.nc, s.energy[q]) / s.nc if s.nc > 0 else 0.0
    o.count = row + 1


# the Stepper calls (springtrack/_stepper.pxd): kstep and ksnapshot on an opaque state
cdef int step_opaque(void* s, int64_t t, int x, int y) noexcept nogil:
    return kstep(<KState*>s, t, x, y)


cdef Py_ssize_t steps_opaque(void* s, const Event* ev, Py_ssize_t n, int64_t t_stop) noexcept nogil:
    return ksteps(<KState*>s, ev, n, t_stop)


cdef void snapshot_opaque(const void* s, int64_t t, SampleOut* o) noexcept nogil:
    ksnapshot(<const KState*>s, t, o)


# ---- Python wrapper -----------------------------------------------------------------
cdef class Kernel:
    """Owns one KState. ``Kernel(model, params)``; see springtrack.tracker.Tracker for the API."""

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
        arr = model.arrays()
        n = len(model.trackers)
        nc = len(model.connections)
        if n > MAX_TRACKERS or nc > MAX_CONNECTIONS:
            raise ValueError(f"model exceeds kernel capacity ({MAX_TRACKERS} trackers, "
                             f"{MAX_CONNECTIONS} connections)")
        if s.cells != NULL:
            free(s.cells)
            s.cells = NULL
        memset(s, 0, sizeof(KState))
        self.model = model
        s.n = n
        s.nc = nc
        s.width = model.width
        s.height = model.height
        s.gw = ((model.width - 1) >> CELL_SHIFT) + 1
        s.gh = ((model.height - 1) >> CELL_SHIFT) + 1
        s.cells = <uint64_t*>calloc(s.gw * s.gh, sizeof(uint64_t))
        if s.cells == NULL:
            raise MemoryError()
        s.pos_lo_x, s.pos_hi_x, s.pos_lo_y, s.pos_hi_y = _limits.position_box(s.width, s.height)
        for i in range(n):
            s.mx[i] = s.rest_x[i] = arr["x"][i]
            s.my[i] = s.rest_y[i] = arr["y"][i]
            s.sxx[i] = s.rest_sxx[i] = arr["sxx"][i]
            s.sxy[i] = s.rest_sxy[i] = arr["sxy"][i]
            s.syy[i] = s.rest_syy[i] = arr["syy"][i]
            s.mass[i] = arr["mass"][i]
            s.gdx0[i] = arr["gdx0"][i]
            s.gdy0[i] = arr["gdy0"][i]
            s.act[i] = 0.0
        s.act_n = 0
        for k in range(nc):
            s.ca[k] = arr["ca"][k]
            s.cb[k] = arr["cb"][k]
            s.kinds[k] = arr["kinds"][k]
            s.stiff[k] = arr["stiffness"][k]
            s.l0[k] = arr["l0"][k]
            s.th0[k] = arr["th0"][k]
            s.dx0[k] = arr["dx0"][k]
            s.dy0[k] = arr["dy0"][k]
            s.ends[k] = ((<uint64_t>1) << s.ca[k]) | ((<uint64_t>1) << s.cb[k])
            s.wa[k] = 1.0 / s.mass[s.ca[k]]
            s.wb[k] = 1.0 / s.mass[s.cb[k]]
            s.half_a[k] = 0.5 * s.stiff[k]
            s.a_euc[k] = s.stiff[k] if s.kinds[k] & 1 else 0.0
            s.a_tor[k] = s.stiff[k] if s.kinds[k] & 2 else 0.0
            s.a_car[k] = s.stiff[k] if s.kinds[k] & 4 else 0.0
            s.c0[k] = cos(s.th0[k])
            s.s0[k] = sin(s.th0[k])
            if s.dx0[k] != 0.0 or s.dy0[k] != 0.0:
                s.rdx[k] = s.dx0[k]
                s.rdy[k] = s.dy0[k]
            else:                          # coincident rest ends: th0 = atan2(0, 0) = 0
                s.rdx[k] = s.c0[k]
                s.rdy[k] = s.s0[k]
            s.dth_zero[k] = wrap_angle(0.0 - s.th0[k])
        set_frame(s, 0.0)
        s.n_frame_moves = 0
        s.sensitive_mask = 0
        s.mass_sum = 0.0
        for i in range(n):
            s.sensitive_mask |= (<uint64_t>1) << i
            s.mass_sum += s.mass[i]           # [ref] msum, summed in the same order
        s.isolated = s.sensitive_mask         # less every tracker a connection links
        s.sim_c = 1.0
        s.sim_s = 0.0
        if n:                                 # [ref] G0, the frame before the first fit
            s.sim_gx = s.mx[0] - s.gdx0[0]
            s.sim_gy = s.my[0] - s.gdy0[0]
        for k in range(nc):
            s.isolated &= ~s.ends[k]
        s.last_t = -(1 << 62)
        self.set_params(params)
        for i in range(n):
            clamp_and_invert(s, i)
            s.box_x0[i] = 0
            s.box_x1[i] = -1
            s.box_y0[i] = 0
            s.box_y1[i] = -1
            reindex(s, i)
        s.n_reindex = 0

    def __dealloc__(self):
        if self.st.cells != NULL:
            free(self.st.cells)
            self.st.cells = NULL

    def set_params(self, params):
        """Apply validated springtrack.params.Params (between two events)."""
        cdef KState* s = &self.st
        self.params = params
        s.a1 = params.alpha_position
        s.a2 = params.alpha_covariance
        s.keep = 1.0 - params.alpha_covariance
        s.gate = params.gate_d2
        if s.tau != params.activity_tau_us and s.n_valid > 0:
            rescale_activity(s, s.last_t)          # [ref] a new tau decays from now on
        s.tau = params.activity_tau_us
        s.inv_tau = 1.0 / s.tau
        s.act_span = <int64_t>(32.0 * s.tau)
        s.act_thr = params.activity_threshold
        s.energy_scale = params.energy_scale
        s.energy_gain = params.energy_gain
        s.cov_gain = params.alpha_covariance / covariance_bias(params.alpha_position, params.gate_d2)
        s.smin2 = params.sigma_min_px * params.sigma_min_px
        s.smax2 = params.sigma_max_px * params.sigma_max_px
        s.period = params.spring_period
        s.ekind = params.energy_kind_index
        s.pull_sim = 1 if params.pull_similarity else 0
        s.car_sim = 1 if params.cartesian_similarity else 0
        s.need_torsion = 1 if s.ekind == 1 else 0
        for k in range(s.nc):
            if s.kinds[k] & 2:
                s.need_torsion = 1
        if s.nc == 0:
            s.need_torsion = 0
        if s.cells != NULL:
            for i in range(s.n):
                clamp_and_invert(s, i)
                reindex(s, i)

    def run(self, events, long long sample_us, long long next_t, Py_ssize_t cap):
        """Process ``events`` (EVENT_DTYPE, C-contiguous). Returns (consumed, next_t, samples)
        where samples is a dict of arrays with at most ``cap`` rows (None if sample_us <= 0)."""
        return run_array(self.stepper(), events, sample_us, next_t, cap)

    def step(self, long long t, int x, int y):
        return kstep(&self.st, t, x, y)

    def springs(self):
        ksprings(&self.st)

    def snapshot(self, long long t):
        """Dict of per-tracker arrays at event time t."""
        cdef KState* s = &self.st
        n = s.n
        act = np.array([kactivity(s, i, t) for i in range(n)])
        return dict(x=np.array([s.mx[i] for i in range(n)]),
                    y=np.array([s.my[i] for i in range(n)]),
                    sxx=np.array([s.sxx[i] for i in range(n)]),
                    sxy=np.array([s.sxy[i] for i in range(n)]),
                    syy=np.array([s.syy[i] for i in range(n)]),
                    activity=act, active=act > s.act_thr,
                    sensitive=np.array([bool((s.sensitive_mask >> i) & 1) for i in range(n)]))

    def energies(self):
        """(3, nc) array of the last spring update's energies: euclidean, torsional, cartesian."""
        cdef KState* s = &self.st
        return np.array([[s.energy[q][k] for k in range(s.nc)] for q in range(3)]).reshape(3, s.nc)

    @property
    def mean_energy(self):
        return self.st.mean_energy

    def frame(self):
        """The similarity frame of the last spring update (st_fit_frame): (c, sn, gx, gy)
        with s R = [[c, -sn], [sn, c]] and (gx, gy) the image of the rest centre of mass;
        (1, 0, G0) until a spring update fits one."""
        return (self.st.sim_c, self.st.sim_s, self.st.sim_gx, self.st.sim_gy)

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
