# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The float64 kernel's springs and energy criteria, eqs. (7)-(22), and its state guard.

Translates springtrack/reference.py springs(), fit_frame() and _energy_criteria() ([ref]
marks the lines translated) in structure-of-arrays passes over the connections: gather,
branch-free arithmetic that GCC vectorises in csrc/springs.h, scatter; with
per-connection coefficients (kind-masked stiffnesses, 1/mass of both ends) precomputed
by init_springs, and eq. (14)'s angles measured in a frame that follows the mean angle
(one atan per connection, no octant logic, while no connection strays far: see
ksprings).  Unlike the per-event step, the springs do not keep the reference's order of
operations (see ksprings), so the two differ by rounding, ~1e-13 px over a million
events.

Several model instances (springtrack.instances): each tracking instance's springs and
criteria run on its own ranges of the arrays (its connections [g_c0, g_c1), its trackers
[g_t0, g_t1), at most 64: its masks are one word relative to g_t0), with its own
parameters, mean energy and frames, in instance order as in the reference.

After every spring update of an instance the state guard (guard_instance, the
reference's _guard) checks each of its means against the position box (springtrack.limits.position_box): a mean outside it,
or not a number, is a state no valid model reaches, and resets its instance to the
model's state.
"""
from libc.math cimport cos, sin, fabs, ceil, floor, M_PI
from libc.stdint cimport int64_t, uint64_t

from springtrack import reference as _ref

from springtrack.kernel.state cimport (KState, MAX_TRACKERS, MAX_CONNECTIONS, K_TRACKING)
from springtrack.kernel.index cimport reindex, set_reach
from springtrack.kernel.covariance cimport clamp_and_invert
from springtrack.kernel.activity cimport flush_activity
from springtrack.kernel.motion cimport predict_dt, still

cdef extern from "springtrack/csrc/springs.h" nogil:
    double st_sum(int n, const double* x)
    void st_over_ends(int nc, const double* e, double thr, const uint64_t* ends,
                      uint64_t* pulled, uint64_t* calm)
    void st_pull(int n, uint64_t pulled, double gx, double gy, double c, double sn, double gain,
                 const double* dis, const double* gdx0, const double* gdy0, double* mx,
                 double* my)
    double ST_FRAME_SCALE_MIN, ST_FRAME_SCALE_MAX, ST_FRAME_MIN_SPREAD, ST_FRAME_AGREE_PX2
    double ST_FRAME_RAMP
    void st_fit_frame(int n, uint64_t fit, const double* mass, const double* gdx0,
                      const double* gdy0, const double* mx, const double* my, double rx,
                      double ry, double* c, double* sn, double* gx, double* gy)
    int popcount "__builtin_popcountll"(uint64_t m)
    uint64_t st_frame_weights(int n, uint64_t fit, double scale, const double* mass,
                              double* wt, double* wm, const double* gdx0, const double* gdy0,
                              const double* mx, const double* my, double c, double sn,
                              double gx, double gy)
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
    void st_boxes_left(int n, const double* mx, const double* my, const double* sxx,
                       const double* syy, const double* bcx, const double* bcy,
                       const double* dev_x, const double* dev_y, const double* sxx_lim,
                       const double* syy_lim, int64_t* out)
    void st_bounds(int n, const double* x, double* lo, double* hi)

assert (_ref.FRAME_SCALE_MIN, _ref.FRAME_SCALE_MAX, _ref.FRAME_MIN_SPREAD,
        _ref.FRAME_AGREE_PX2, _ref.FRAME_RAMP) == (
    ST_FRAME_SCALE_MIN, ST_FRAME_SCALE_MAX, ST_FRAME_MIN_SPREAD, ST_FRAME_AGREE_PX2,
    ST_FRAME_RAMP), "springs.h disagrees with reference.py"

cdef double TWO_PI = 2.0 * M_PI
cdef int FRAME_REFITS = _ref.FRAME_REFITS
cdef int SPRING_BOX_PX = _ref.SPRING_BOX_PX
cdef int SPRING_BOX_ALL = _ref.SPRING_BOX_ALL
# The frame of eq. (14)'s fast path (st_torsion_angles_framed) follows the mean angle once
# it is this far (rad) from it: connections within 3 pi/8 - pi/16 of the mean angle then
# stay on the fast path.
cdef double FRAME_SLACK = M_PI / 16


cdef inline double wrap_angle(double a) noexcept nogil:
    # [ref] wrap_angle: [-3 pi, 3 pi) -> [-pi, pi)
    if a >= M_PI:
        return a - TWO_PI
    if a < -M_PI:
        return a + TWO_PI
    return a


cdef inline uint64_t all_of(int n) noexcept nogil:
    """Bits 0 .. n-1 (n <= 64)."""
    return ~(<uint64_t>0) if n >= 64 else ((<uint64_t>1) << n) - 1


cdef void compose_sensitive(KState* s) noexcept nogil:
    """The event assignment's words from each instance's isens: instance g's bit j is
    tracker g_t0 + j's, bit (g_t0 + j) & 63 of word (g_t0 + j) >> 6."""
    cdef int g, w, b, t0
    cdef uint64_t m
    if s.ni == 1:                                  # one instance: its own word
        s.sensitive[0] = s.isens[0]
        return
    for w in range(s.nw):
        s.sensitive[w] = 0
    for g in range(s.ni):
        t0 = s.g_t0[g]
        m = s.isens[g]
        w = t0 >> 6
        b = t0 & 63
        s.sensitive[w] |= m << b
        if b and s.g_t1[g] - t0 + b > 64:          # it runs into the next word
            s.sensitive[w + 1] |= m >> (64 - b)


cdef void kspring_update(KState* s, int g) noexcept nogil:
    # [ref] spring_update(g): instance g's springs and criteria if it is tracking; then its
    # state guard; then its trackers whose gate boxes left their indexed boxes re-indexed
    # (the other instances' trackers did not move)
    cdef int64_t left[MAX_TRACKERS]
    cdef int i, t0 = s.g_t0[g], n = s.g_t1[g] - s.g_t0[g]
    cdef int64_t t = s.last_t
    cdef double lead
    s.n_spring_updates += 1
    if s.state[g] == K_TRACKING:
        for i in range(t0, t0 + n):                  # [ref] eq. (M1): the springs act on
            lead = predict_dt(s, i, t)                # the means at the update's time
            s.mx[i] = s.mx[i] + s.vx[i] * lead
            s.my[i] = s.my[i] + s.vy[i] * lead
            s.tm[i] = t
        instance_springs(s, g)
    guard_instance(s, g)
    compose_sensitive(s)
    for i in range(t0, t0 + n):          # eq. (M8) changed velocities: their reach
        set_reach(s, i)
    st_boxes_left(n, s.mx + t0, s.my + t0, s.sxx + t0, s.syy + t0, s.bcx + t0, s.bcy + t0,
                  s.mdev_x + t0, s.mdev_y + t0, s.sxx_lim + t0, s.syy_lim + t0, left)
    for i in range(n):
        if left[i]:
            reindex(s, t0 + i)
    spring_box(s, g)


cdef inline void spring_box(KState* s, int g) noexcept nogil:
    # [ref] _spring_box(g): [ceil(min) - SPRING_BOX_PX, floor(max) + SPRING_BOX_PX] of
    # instance g's means on each axis
    cdef int t0 = s.g_t0[g], n = s.g_t1[g] - s.g_t0[g]
    cdef double x0, x1, y0, y1
    st_bounds(n, s.mx + t0, &x0, &x1)
    st_bounds(n, s.my + t0, &y0, &y1)
    s.sbox[g][0] = <int>ceil(x0) - SPRING_BOX_PX
    s.sbox[g][1] = <int>floor(x1) + SPRING_BOX_PX
    s.sbox[g][2] = <int>ceil(y0) - SPRING_BOX_PX
    s.sbox[g][3] = <int>floor(y1) + SPRING_BOX_PX


cdef void ksprings(KState* s) noexcept nogil:
    # [ref] springs: every instance's spring update, in instance order
    cdef int g
    for g in range(s.ni):
        kspring_update(s, g)


cdef void kclocks(KState* s, int owner) noexcept nogil:
    # [ref] step's spring clocks: an instance's update runs when its count reaches the
    # period (due[g] <= n_free), only the clocks the event moved, in instance order
    cdef int g
    cdef int64_t nd = s.due[0]
    for g in range(s.ni):
        if (owner < 0 or g == owner) and s.due[g] <= s.n_free:
            s.due[g] = s.n_free + s.period                   # its count restarts
            kspring_update(s, g)
        if s.due[g] < nd:
            nd = s.due[g]
    s.next_due = nd


cdef void set_period(KState* s, int period) noexcept nogil:
    # [ref] set_params: each clock's count, period - (due - n_free), kept; a count at or
    # past a shorter period runs its update at the next event the clock counts
    cdef int g
    cdef int64_t d = period - s.period
    s.period = period
    for g in range(s.ni):
        s.due[g] += d
    s.next_due += d


cdef inline void instance_springs(KState* s, int g) noexcept nogil:
    # [ref] _springs(g), in structure-of-arrays passes over instance g's connections
    # (csrc/springs.h, vectorised):
    #   1. gather r = end b - end a;  2. eq. (14) angles, in the frame of a recent mean
    #   angle (fast) or from the rest directions;  3. eq. (15) mean angle;  4. eqs.
    #   (15)-(17) deviation, torsional energy and rotation (0. before them all, in the
    #   similarity frame: the Cartesian rest offsets turned and scaled);  5. eqs. (10)-(12), (16),
    #   (18)-(20) branch-free (a_euc/a_tor/a_car are 0 for kinds a connection lacks),
    #   displacements divided by each end's mass;  6. scatter onto the ends' means
    #   (scalar);  7. energy criteria (OR-reduced bit masks).
    # Rounding-level differences from the reference, none larger than ~1e-15 relative: the
    # three kinds' displacements are summed per connection and added straight to the means
    # (the reference adds them one by one to per-tracker sums, then those to the means);
    # the mean angle and the mean energy are summed in four interleaved partial sums
    # (st_sum: a chain of n/4 additions instead of n; both gate the rest of the update).
    cdef int c0 = s.g_c0[g], nc = s.g_c1[g] - s.g_c0[g], k, i, j
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
    cdef const double* dx0 = s.dx0 + c0
    cdef const double* dy0 = s.dy0 + c0
    cdef double mean_dth = 0.0
    if s.car_sim[g]:                   # 0. eq. (18): s R d0 in the last update's frame
        st_turn_offsets(nc, s.sim_c[g], s.sim_s[g], dx0, dy0, odx, ody)
        dx0 = odx
        dy0 = ody
    cdef const int* ca = s.ca + c0                   # the instance's connections' ends
    cdef const int* cb = s.cb + c0
    for k in range(nc):                                              # 1. gather
        i = ca[k]
        j = cb[k]
        rx[k] = s.mx[j] - s.mx[i]
        ry[k] = s.my[j] - s.my[i]
    if s.need_torsion[g]:
        if st_torsion_angles_framed(nc, rx, ry, s.qdx + c0, s.qdy + c0, s.frame_phi[g],  # 2.
                                    th):                             # eq. (14)
            s.n_frame_misses += 1
            st_torsion_angles(nc, rx, ry, s.rdx + c0, s.rdy + c0, s.dth_zero + c0, th)
        mean_dth = st_sum(nc, th) / nc                               # 3. eq. (15)
        if fabs(mean_dth - s.frame_phi[g]) > FRAME_SLACK:
            set_frame(s, g, mean_dth)
        st_torsion_rotation(nc, th, mean_dth, s.half_a + c0, s.a_tor + c0,        # 4.
                            s.energy[1] + c0, eps, sn, cm1)
    else:
        for k in range(nc):
            s.energy[1][c0 + k] = 0.0
            sn[k] = 0.0
            cm1[k] = 0.0
    st_spring_terms_batch(nc, rx, ry, sn, cm1, s.l0 + c0, s.half_a + c0, dx0, dy0,  # 5.
                          s.c0 + c0, s.s0 + c0, s.a_euc + c0, s.a_car + c0, s.wa + c0,
                          s.wb + c0, s.energy[0] + c0, s.energy[2] + c0, uax, uay, ubx, uby)
    for k in range(nc):                                              # 6. scatter
        i = ca[k]
        j = cb[k]
        s.mx[i] += uax[k]
        s.my[i] += uay[k]
        s.mx[j] -= ubx[k]
        s.my[j] -= uby[k]
    energy_criteria(s, g)                                            # 7.


cdef void guard_instance(KState* s, int g) noexcept nogil:
    """[ref] _guard(g): a mean of instance g outside the position box, or not a number, is
    a state no model within springtrack.limits reaches: counted, and the instance reset to
    the model."""
    cdef int i
    cdef bint out = False
    for i in range(s.g_t0[g], s.g_t1[g]):
        out |= not (s.mx[i] >= s.pos_lo_x and s.mx[i] < s.pos_hi_x
                    and s.my[i] >= s.pos_lo_y and s.my[i] < s.pos_hi_y)
    if out:
        s.n_resets += 1
        reset_instance(s, g)


cdef void reset_instance(KState* s, int g) noexcept nogil:
    """[ref] _reset_instance, then its covariances clamped and inverted and its trackers
    re-indexed: instance g's tracker state of the model, its state, counters and time
    kept."""
    cdef int k, q, t0 = s.g_t0[g], t1 = s.g_t1[g]
    rest_trackers(s, g)
    for q in range(3):
        for k in range(s.g_c0[g], s.g_c1[g]):
            s.energy[q][k] = 0.0
    s.mean_energy[g] = 0.0
    s.isens[g] = all_of(t1 - t0) if s.state[g] == K_TRACKING else 0
    rest_frame(s, g)
    set_frame(s, g, 0.0)


cdef void rest_trackers(KState* s, int g) noexcept nogil:
    """Instance g's trackers at their model's rest state: means and covariances, activities
    0 (the increments logged so far flushed first), covariances clamped and inverted,
    trackers re-indexed."""
    cdef int i
    flush_activity(s)
    for i in range(s.g_t0[g], s.g_t1[g]):
        s.mx[i] = s.rest_x[i]
        s.my[i] = s.rest_y[i]
        s.sxx[i] = s.rest_sxx[i]
        s.sxy[i] = s.rest_sxy[i]
        s.syy[i] = s.rest_syy[i]
        s.act[i] = 0.0
        still(s, i)
        clamp_and_invert(s, i)
        reindex(s, i)


cdef inline void rest_frame(KState* s, int g) noexcept nogil:
    """[ref] _rest_frame: instance g's frame before its first fit, the identity about G0
    at rest."""
    cdef int t0 = s.g_t0[g]
    s.sim_c[g] = 1.0
    s.sim_s[g] = 0.0
    s.sim_gx[g] = s.mx[t0] - s.gdx0[t0]
    s.sim_gy[g] = s.my[t0] - s.gdy0[t0]


cdef void set_frame(KState* s, int g, double phi) noexcept nogil:
    """Turn instance g's rest directions by phi for st_torsion_angles_framed (a cache: any
    phi gives the same angles, up to rounding; one near the mean angle lets the fast path
    apply)."""
    cdef double c = cos(phi), sn = sin(phi)
    cdef int k
    s.frame_phi[g] = phi
    for k in range(s.g_c0[g], s.g_c1[g]):
        s.qdx[k] = c * s.rdx[k] - sn * s.rdy[k]
        s.qdy[k] = sn * s.rdx[k] + c * s.rdy[k]
    s.n_frame_moves += 1


cdef void fit_frame(KState* s, int g, uint64_t fit, double* dis) noexcept nogil:
    """[ref] fit_frame: instance g's frame fitted to the trackers of the mask fit, refitted
    up to FRAME_REFITS times weighted by how well they agree with it (st_frame_weights);
    dis[i] = how much tracker i (relative to the instance's first) disagrees, 0 outside
    the fit."""
    cdef int t0 = s.g_t0[g], n = s.g_t1[g] - s.g_t0[g], r, i
    cdef uint64_t pos, all = all_of(n)
    cdef double wt[64]
    cdef double wm[64]
    fit &= all
    if popcount(fit) < 2:
        fit = all
    for i in range(n):
        wt[i] = 1.0
        dis[i] = 0.0
    st_fit_frame(n, fit, s.mass + t0, s.gdx0 + t0, s.gdy0 + t0, s.mx + t0, s.my + t0,
                 s.sim_gx[g], s.sim_gy[g], &s.sim_c[g], &s.sim_s[g], &s.sim_gx[g],
                 &s.sim_gy[g])
    if not s.energy_scale[g] < s.g_c1[g] - s.g_c0[g]:
        return
    for r in range(FRAME_REFITS):
        pos = st_frame_weights(n, fit, s.energy_scale[g], s.mass + t0, wt, wm, s.gdx0 + t0,
                               s.gdy0 + t0, s.mx + t0, s.my + t0, s.sim_c[g], s.sim_s[g],
                               s.sim_gx[g], s.sim_gy[g])
        if pos == 0:
            break
        st_fit_frame(n, pos, wm, s.gdx0 + t0, s.gdy0 + t0, s.mx + t0, s.my + t0,
                     s.sim_gx[g], s.sim_gy[g], &s.sim_c[g], &s.sim_s[g], &s.sim_gx[g],
                     &s.sim_gy[g])
    for i in range(n):
        if (fit >> i) & 1:
            dis[i] = 1.0 - wt[i]


cdef inline void pull_velocities(KState* s, int g, uint64_t pulled) noexcept nogil:
    # [ref] _pull_velocities(g), eq. (M8): the pulled trackers' velocities toward the
    # mean velocity of the instance's trackers left alone
    cdef int t0 = s.g_t0[g], n = s.g_t1[g] - s.g_t0[g], j, i
    cdef double w = 0.0, vx = 0.0, vy = 0.0, a = s.energy_gain[g]
    if s.tau_m <= 0.0 or pulled == 0:
        return
    for j in range(n):
        if not (pulled >> j) & 1:
            i = t0 + j
            w += s.mass[i]
            vx += s.mass[i] * s.vx[i]
            vy += s.mass[i] * s.vy[i]
    if w > 0.0:
        vx = vx / w
        vy = vy / w
    for j in range(n):
        if (pulled >> j) & 1:
            i = t0 + j
            s.vx[i] = s.vx[i] + a * (vx - s.vx[i])
            s.vy[i] = s.vy[i] + a * (vy - s.vy[i])


cdef inline void pull_half_offsets(KState* s, int g, uint64_t pulled,
                                   const double* dis) noexcept nogil:
    # [ref] eq. (M9): each tracker eq. (22) pulls by gain a (a_en, or a_en times how much
    # it disagrees with the frame) has its half offset taken toward 0: h = h - a h
    cdef int t0 = s.g_t0[g], n = s.g_t1[g] - s.g_t0[g], j, i
    cdef double a, a_en = s.energy_gain[g]
    if s.c_h <= 0.0:
        return
    for j in range(n):
        a = a_en if (pulled >> j) & 1 else a_en * dis[j]
        if a > 0.0:
            i = t0 + j
            s.hx[i] = s.hx[i] - a * s.hx[i]
            s.hy[i] = s.hy[i] - a * s.hy[i]


cdef inline void energy_criteria(KState* s, int g) noexcept nogil:
    # [ref] _energy_criteria(g); masks relative to the instance's first tracker t0
    cdef int t0 = s.g_t0[g], n = s.g_t1[g] - s.g_t0[g], c0 = s.g_c0[g]
    cdef int nc = s.g_c1[g] - c0, i
    cdef const double* e = s.energy[s.ekind[g]] + c0
    cdef double thr, msum = s.mass_sum[g], gx = 0.0, gy = 0.0
    cdef uint64_t pulled, calm
    cdef double dis[64]
    if nc == 0:
        return
    s.mean_energy[g] = st_sum(nc, e) / nc                            # eq. (13)
    thr = s.energy_scale[g] * s.mean_energy[g]
    st_over_ends(nc, e, thr, s.ends + c0, &pulled, &calm)
    for i in range(n):
        dis[i] = 0.0
    if s.pull_sim[g] or s.car_sim[g]:    # [ref] fit_frame over the trackers left alone,
        fit_frame(s, g, ~pulled, dis)    # weighted by agreement; eq. (22) pulls by 1 - that
    if s.pull_sim[g]:                    # eq. (22) toward G + s R dG0, the fitted frame
        st_pull(n, pulled, s.sim_gx[g], s.sim_gy[g], s.sim_c[g], s.sim_s[g], s.energy_gain[g],
                dis, s.gdx0 + t0, s.gdy0 + t0, s.mx + t0, s.my + t0)
    else:
        for i in range(t0, t0 + n):                                  # eq. (22): G
            gx += s.mass[i] * s.mx[i]
            gy += s.mass[i] * s.my[i]
        gx = gx / msum
        gy = gy / msum
        st_pull(n, pulled, gx, gy, 1.0, 0.0, s.energy_gain[g], dis, s.gdx0 + t0, s.gdy0 + t0,
                s.mx + t0, s.my + t0)
    pull_velocities(s, g, pulled)        # eq. (M8)
    pull_half_offsets(s, g, pulled, dis) # eq. (M9)
    s.isens[g] = calm | s.isolated[g]    # eq. (21): insensitive if all its connections are over


cdef void init_instance(KState* s, int g) noexcept nogil:
    """Instance g's springs state derived from its model as loaded (ca, cb, kinds, stiff,
    th0, dx0, dy0 of each of its connections; mass, gdx0, gdy0 and the means of each of
    its trackers); its state and isens kept."""
    cdef int t0 = s.g_t0[g], t1 = s.g_t1[g], i, k
    cdef uint64_t linked = 0
    for k in range(s.g_c0[g], s.g_c1[g]):
        s.ends[k] = ((<uint64_t>1) << (s.ca[k] - t0)) | ((<uint64_t>1) << (s.cb[k] - t0))
        linked |= s.ends[k]
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
    set_frame(s, g, 0.0)
    s.mass_sum[g] = 0.0
    for i in range(t0, t1):
        s.mass_sum[g] += s.mass[i]        # [ref] msum, summed in the same order
    s.isolated[g] = all_of(t1 - t0) & ~linked
    rest_frame(s, g)                      # [ref] G0, the frame before the first fit


cdef void init_springs(KState* s) noexcept nogil:
    """Every instance's springs state (init_instance), all its trackers sensitive."""
    cdef int g
    for g in range(s.ni):
        init_instance(s, g)
        s.isens[g] = all_of(s.g_t1[g] - s.g_t0[g])
        s.sbox[g][0] = -SPRING_BOX_ALL          # [ref] SPRING_BOX_ALL: every event
        s.sbox[g][1] = SPRING_BOX_ALL
        s.sbox[g][2] = -SPRING_BOX_ALL
        s.sbox[g][3] = SPRING_BOX_ALL
    s.n_frame_moves = 0
    compose_sensitive(s)
