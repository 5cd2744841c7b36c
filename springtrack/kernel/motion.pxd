# The float64 kernel's motion model (this project's extension of Algorithm 1, eqs. M1-M9 of
# springtrack/reference.py; docs/motion.md): each tracker's
# velocity, the half offset between its part's ON and OFF edges, and the Kalman filter
# whose gains fall below alpha1 where its events come fast.  [ref] marks the lines translated.
#
# cdef inline: compiled into the per-event step (step.pxd) and the springs (springs.pyx),
# which predict the means to an update's time.
from libc.math cimport sqrt
from libc.stdint cimport int64_t

from springtrack.kernel.state cimport KState

cdef extern from *:
    """
    /* springtrack/kernel/motion.pxd: eq. (M7)'s velocity bound, px/us, and a placed tracker's
       position variance (reference.VELOCITY_MAX, P_UNKNOWN) */
    #define ST_VELOCITY_MAX 0.25
    #define ST_P_UNKNOWN 1.0
    """
    const double ST_VELOCITY_MAX
    const double ST_P_UNKNOWN


cdef inline double clampd(double v, double lo, double hi) noexcept nogil:
    # [ref] min(max(v, lo), hi)
    if v < lo:
        v = lo
    if v > hi:
        return hi
    return v


cdef inline double predict_dt(const KState* s, int i, int64_t t) noexcept nogil:
    """[ref] predict_dt: eq. (M1)'s lead max(0, min(t, t_k + H) - t_m)."""
    cdef double end = <double>s.tk[i] + s.horizon, d
    if <double>t < end:
        end = <double>t
    d = end - <double>s.tm[i]
    return d if d > 0.0 else 0.0


cdef inline void still(KState* s, int i) noexcept nogil:
    """[ref] _still: tracker i still, one edge, position unknown."""
    s.vx[i] = 0.0
    s.vy[i] = 0.0
    s.hx[i] = 0.0
    s.hy[i] = 0.0
    s.fon[i] = 0.5
    s.tm[i] = 0
    s.tk[i] = 0
    s.kpp[i] = ST_P_UNKNOWN
    s.kpv[i] = 0.0
    s.kvv[i] = 0.0


cdef inline double kalman(KState* s, int i, int64_t t, double* kv) noexcept nogil:
    """[ref] _kalman, eq. (M3): tracker i's Kalman filter of position and velocity
    predicted over min(t - t_k, tau_m) and updated by one event; returns K_p, sets *kv."""
    cdef double d = <double>(t - s.tk[i]), q = s.q_m, pp, pv, vv, lim, sd, inv_s, kp
    if d > s.tau_m:
        d = s.tau_m
    pp = s.kpp[i] + d * (2.0 * s.kpv[i] + d * s.kvv[i]) + q * (d * d * d) / 3.0
    pv = s.kpv[i] + d * s.kvv[i] + q * (d * d) * 0.5
    vv = s.kvv[i] + q * d
    if vv > s.vv_max:
        vv = s.vv_max
    lim = sqrt(pp * vv)
    pv = clampd(pv, -lim, lim)
    sd = 1.0 + pp                                  # S = max(1 + pp, pp / alpha1)
    if pp * s.inv_a1[i] > sd:
        sd = pp * s.inv_a1[i]
    inv_s = 1.0 / sd
    kp = pp * inv_s
    kv[0] = pv * inv_s
    s.kpp[i] = pp - kp * pp
    s.kpv[i] = pv - kp * pv
    s.kvv[i] = vv - kv[0] * pv
    return kp


cdef inline double motion_gain(KState* s, int i, int64_t t, double a1, double* kv) noexcept nogil:
    """The mean's gain (eq. M3, or alpha1 when tau_m = 0, eq. 3) and the velocity's (*kv);
    t becomes the tracker's last event."""
    cdef double gain = a1
    kv[0] = 0.0
    if s.tau_m > 0.0:
        gain = kalman(s, i, t, kv)
    s.tk[i] = t
    return gain


cdef inline void motion_update(KState* s, int i, double gain, double kv, double sgn,
                               double rx, double ry) noexcept nogil:
    """[ref] eqs. (M6)-(M7): the half offset and the velocity move by the residual
    (rx, ry) about the edge of the event's polarity (sgn = +1 ON, -1 OFF)."""
    cdef double hmax = s.h_max
    cdef double f, b, ch
    if s.c_h > 0.0:
        if s.tau_m > 0.0:                                            # eq. (M6)
            s.hx[i] = clampd(s.hx[i] + s.c_h * gain * sgn * rx, -hmax, hmax)
            s.hy[i] = clampd(s.hy[i] + s.c_h * gain * sgn * ry, -hmax, hmax)
        else:
            # eq. (M6b): f = f + K (on - f), b = 4 f (1 - f),
            # h = h + c_h K (b s r - (1 - b) h)
            f = s.fon[i] + gain * ((1.0 if sgn > 0.0 else 0.0) - s.fon[i])
            s.fon[i] = f
            b = 4.0 * f * (1.0 - f)
            ch = s.c_h * gain
            s.hx[i] = clampd(s.hx[i] + ch * (b * sgn * rx - (1.0 - b) * s.hx[i]), -hmax, hmax)
            s.hy[i] = clampd(s.hy[i] + ch * (b * sgn * ry - (1.0 - b) * s.hy[i]), -hmax, hmax)
    if s.tau_m > 0.0:
        s.vx[i] = clampd(s.vx[i] + kv * rx, -ST_VELOCITY_MAX, ST_VELOCITY_MAX)
        s.vy[i] = clampd(s.vy[i] + kv * ry, -ST_VELOCITY_MAX, ST_VELOCITY_MAX)


cdef enum:
    MOTION_REST = 0          # no velocity, no half offset: eqs. (M1)-(M7) are eqs. (3)-(5)
    MOTION_EDGES = 1         # half offsets (c_h or an h), no velocity: no prediction (M1)
    MOTION_FULL = 2          # a velocity may move a mean


cdef inline int motion_mode(const KState* s) noexcept nogil:
    """How much of the motion model can move a mean: MOTION_FULL with tau_m on or a
    tracker holding a velocity; else MOTION_EDGES with c_h on or a tracker holding a half
    offset; else MOTION_REST.  Below MOTION_FULL every prediction of eq. (M1) adds an
    exact zero (v = 0) and the gain is alpha1; at MOTION_REST the half offsets are zeros
    too: the per-event path (kernel/step.pxd) leaves out what adds zeros and still
    computes the same bits."""
    cdef int i
    cdef bint edges = s.c_h > 0.0
    if s.tau_m > 0.0:
        return MOTION_FULL
    for i in range(s.n):
        if s.vx[i] != 0.0 or s.vy[i] != 0.0:
            return MOTION_FULL
        edges |= s.hx[i] != 0.0 or s.hy[i] != 0.0
    return MOTION_EDGES if edges else MOTION_REST
