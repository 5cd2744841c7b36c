# The float64 kernel's per-event step (Algorithm 1): the most probable sensitive tracker
# takes the event (eq. 2) and moves toward it (eqs. 3-6); every spring_period valid events
# of an instance's spring clock its springs act (kernel/springs.pyx).
#
#     cdef KState* s = &kernel.st                  # kernel: a springtrack.kernel.kernel.Kernel
#     with nogil:
#         r = kstep(s, t, x, y)                    # one event; r >= 0: winning tracker
#         c = ksteps(s, ev, n, t_stop)             # a batch (the Stepper's steps())
#
# Translates springtrack.reference.ReferenceTracker.step() ([ref] marks the lines
# translated) and keeps its order of floating-point operations, so its decisions match
# even on exact ties.  Speed without changing a decision: argmin of the Mahalanobis
# distance d^2 (eq. 2 in the log domain, no exp per tracker) over the spatial index's
# candidates only (kernel/index.pxd), eq. (6)'s exps logged and batched (kernel/activity.pxd).
#
# cdef inline, like the index, the covariance clamp and the activity log it calls: the
# whole per-event path is compiled as one unit into springtrack.kernel.kernel, which exposes it
# (Kernel.stepper(), Kernel.step()).  The springs, once per spring_period events of an
# instance's clock, are a call into springtrack.kernel.springs.
from libc.stdint cimport int64_t, uint64_t

from springtrack.events cimport Event
from springtrack.backends.stepper cimport st_sample_due
from springtrack.kernel.state cimport (KState, CELL_SHIFT, K_NO_TRACKER, K_BACK_IN_TIME,
                                  K_OUT_OF_SENSOR)
from springtrack.kernel.index cimport check_index
from springtrack.kernel.covariance cimport clamp_and_invert
from springtrack.kernel.activity cimport log_activity, flush_activity, rescale_activity
from springtrack.kernel.springs cimport kclocks
from springtrack.kernel.motion cimport (predict_dt, motion_gain, motion_update, motion_mode,
                                        MOTION_REST, MOTION_EDGES, MOTION_FULL)

cdef extern from *:
    """
    static inline int st_ctz64(unsigned long long v) { return __builtin_ctzll(v); }
    """
    int st_ctz64(unsigned long long v) nogil


cdef inline void update_tracker(KState* s, int i, int64_t t, double fx, double fy, double d2,
                                int pol, bint one, int moving) noexcept nogil:
    # [ref] _update
    # ``moving`` (a constant in the callers' loops, motion.pxd motion_mode): below
    # MOTION_FULL the motion model's predictions and gain are exact zeros and alpha1, at
    # MOTION_REST its half offsets are zeros too; those terms are left out
    # eq. (6) with eq. (2)'s unnormalised kernel value p = exp(-d2/2) as the increment,
    # kept rescaled (kernel/activity.pxd): act += p * exp((t - act_t0) / tau), one exp (logged)
    if t - s.act_t0 > s.act_span:
        rescale_activity(s, t)
    log_activity(s, i, -0.5 * d2 + <double>(t - s.act_t0) * s.inv_tau)
    # its instance's gains (one instance: the first tracker's, at a constant address)
    cdef const double* gain = &s.gain[0][0] if one else &s.gain[i][0]
    cdef double kv = 0.0, a1, lead, px, py, dx, dy, sgn, rx, ry
    cdef double keep = gain[1], g = gain[2]
    if moving == MOTION_REST:
        a1 = gain[0]                                                 # eq. (3)
        s.tk[i] = t
        s.tm[i] = t
        dx = fx - s.mx[i]                                            # eq. (5)
        dy = fy - s.my[i]
        s.mx[i] = s.mx[i] + a1 * dx                                  # eq. (3)
        s.my[i] = s.my[i] + a1 * dy
    else:
        if moving == MOTION_FULL:
            lead = predict_dt(s, i, t)                               # eq. (M1): the mean
            a1 = motion_gain(s, i, t, gain[0], &kv)                  # eq. (M3)
            px = s.mx[i] + s.vx[i] * lead                            # predicted to t, as
            py = s.my[i] + s.vy[i] * lead                            # eq. (2) gated it
        else:                                                        # v = 0, tau_m = 0:
            a1 = gain[0]                                             # eq. (M3)'s alpha1
            s.tk[i] = t
            px = s.mx[i]                                             # eq. (M1) adds 0
            py = s.my[i]
        s.tm[i] = t
        dx = fx - px                                                 # eq. (5), pre-update
        dy = fy - py                                                 # (predicted) mean
        sgn = 1.0 if pol else -1.0                                   # eq. (M4)
        rx = dx - sgn * s.hx[i]
        ry = dy - sgn * s.hy[i]
        s.mx[i] = px + a1 * rx                                       # eq. (M5) = eq. (3)
        s.my[i] = py + a1 * ry
        motion_update(s, i, a1, kv, sgn, rx, ry)                     # eqs. (M6)-(M7)
    s.sxx[i] = keep * s.sxx[i] + g * (dx * dx)                       # eq. (4)
    s.sxy[i] = keep * s.sxy[i] + g * (dx * dy)
    s.syy[i] = keep * s.syy[i] + g * (dy * dy)
    clamp_and_invert(s, i)
    check_index(s, i)


cdef inline int assign_event(KState* s, int64_t t, int x, int y, int pol,
                             bint one, int moving) noexcept nogil:
    """eqs. (2)-(6) for a valid event: the most probable sensitive tracker of every
    instance takes it (an event feeds at most one tracker of one instance).  ``one``:
    the state holds one instance (so at most 64 trackers: one mask word); ``moving``: what
    of the motion model may move a mean (motion.pxd motion_mode; below MOTION_FULL its
    predictions are exact zeros and are left out); constants in the callers' loops
    (ksteps), which then compile this path without the others."""
    cdef double fx = x, fy = y, dx, dy, d2, lead
    cdef double best_d2 = s.gate
    cdef int best = K_NO_TRACKER, i, w, nw = 1 if one else s.nw, base
    # eq. (2): candidates are the sensitive trackers indexed in this event's cell, in
    # increasing index order (word by word: one word per 64 trackers, one for one
    # instance), so ties resolve exactly as in the reference's full scan: the lowest
    # index, the first instance.  One loop over the words, best and best_d2 in locals
    # (registers), for one word and several.
    cdef Py_ssize_t c = ((y >> CELL_SHIFT) * s.gw + (x >> CELL_SHIFT)) * nw
    cdef uint64_t m
    for w in range(nw):
        m = s.cells[c + w] & s.sensitive[w]
        base = w << 6
        while m:
            i = base + st_ctz64(m)
            m &= m - 1
            if moving == MOTION_FULL:
                lead = predict_dt(s, i, t)                           # eq. (M1): about the
                dx = fx - (s.mx[i] + s.vx[i] * lead)                 # predicted mean
                dy = fy - (s.my[i] + s.vy[i] * lead)
            else:
                dx = fx - s.mx[i]
                dy = fy - s.my[i]
            d2 = s.ia[i] * dx * dx + s.ic[i] * dy * dy + s.ib2[i] * dx * dy
            if d2 < best_d2:
                best_d2 = d2
                best = i
    if best >= 0:
        update_tracker(s, best, t, fx, fy, best_d2, pol, one, moving)
        s.n_assigned += 1
    return best


cdef inline void count_own(KState* s, int g) noexcept nogil:
    """One count on instance g's clock alone: its update one event nearer (KState.due)."""
    cdef int64_t d = s.due[g] - 1
    s.due[g] = d
    if d < s.next_due:
        s.next_due = d


cdef inline void count_event(KState* s, int best, int x, int y) noexcept nogil:
    """[ref] step's spring clocks, after a valid event at (x, y): one that tracker
    ``best`` took moves its instance's clock only, one no tracker took (best < 0) the
    clocks of the instances whose spring boxes hold it, or every instance's if none does
    (KState.n_free: one count for all); kclocks runs the updates then due."""
    cdef int g = -1, q
    cdef bint near = False
    if best >= 0:
        g = s.inst[best]
        count_own(s, g)
    else:
        for q in range(s.ni):
            if (x >= s.sbox[q][0] and x <= s.sbox[q][1]
                    and y >= s.sbox[q][2] and y <= s.sbox[q][3]):
                near = True
                count_own(s, q)
        if not near:
            s.n_free += 1
    if s.n_free >= s.next_due:
        kclocks(s, g)


cdef inline Py_ssize_t ksteps_of(KState* s, const Event* ev, Py_ssize_t n, int64_t t_stop,
                                 bint one, int moving) noexcept nogil:
    """ksteps() for a state of one instance (``one``, a constant) or several, the motion
    model's mode (``moving``, a constant; assign_event).  One instance's clock
    counts every valid event: its count in a local (``since``)."""
    cdef Py_ssize_t k
    cdef int64_t t, last_t = s.last_t, n_back = 0, n_outside = 0, n_valid = 0
    cdef int period = s.period, since = period - <int>(s.due[0] - s.n_free)
    cdef int best
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
        best = assign_event(s, t, x, y, ev[k].p, one, moving)
        if one:
            since += 1
            if since >= period:
                since = 0
                s.last_t = last_t              # eq. (M1): the springs' time
                s.due[0] = s.n_free            # (at rest, they set no velocity: tau_m = 0)
                kclocks(s, 0)
        else:
            s.last_t = last_t
            count_event(s, best, x, y)
    else:
        k = n
    flush_activity(s)
    s.last_t = last_t
    if one:
        s.due[0] = s.n_free + period - since
        s.next_due = s.due[0]
    s.n_back += n_back
    s.n_outside += n_outside
    s.n_valid += n_valid
    return k


cdef inline Py_ssize_t ksteps(KState* s, const Event* ev, Py_ssize_t n, int64_t t_stop) noexcept nogil:
    """kstep() over ev[0..n), stopping before the first event with t >= t_stop that is not
    back in time (the sampling rule, csrc/sampling.h, with t_stop the next sample time);
    returns the events processed (the Stepper's steps(), backends/stepper.pxd).
    The counters and the last time live in locals for the batch and are written back at
    its end (nothing the step calls reads them).  Six copies of the loop: one instance
    (the common case, its per-event path as lean as a one-model kernel's) or several, times
    the motion model's three modes (motion.pxd motion_mode, decided per batch)."""
    cdef int moving = motion_mode(s)
    if s.ni == 1:
        if moving == MOTION_FULL:
            return ksteps_of(s, ev, n, t_stop, True, MOTION_FULL)
        if moving == MOTION_EDGES:
            return ksteps_of(s, ev, n, t_stop, True, MOTION_EDGES)
        return ksteps_of(s, ev, n, t_stop, True, MOTION_REST)
    if moving == MOTION_FULL:
        return ksteps_of(s, ev, n, t_stop, False, MOTION_FULL)
    if moving == MOTION_EDGES:
        return ksteps_of(s, ev, n, t_stop, False, MOTION_EDGES)
    return ksteps_of(s, ev, n, t_stop, False, MOTION_REST)


cdef inline int kstep(KState* s, int64_t t, int x, int y, int p) noexcept nogil:
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
    cdef int best = assign_event(s, t, x, y, p, s.ni == 1, MOTION_FULL)
    flush_activity(s)
    count_event(s, best, x, y)
    return best
