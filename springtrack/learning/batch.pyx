# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The learner's per-event loop: a pool of free Gaussian trackers, eqs. (2)-(6), no springs.

``pool_batch`` runs a batch of events through the pool whose state ``st`` (float64, one
row per field, one column per tracker, see the ``F_*`` indices) it updates in place; it
touches no Python object per event.  Per event it writes the winner (eq. 2: the tracker
with the smallest Mahalanobis distance d^2 inside the gate, or -1) and, when a second
tracker's gate holds the event too, counts the pair in ``overlap`` (the learner merges
trackers that keep sharing events: springtrack/learning/learner.py).  Births, merges and deaths
happen between batches, in Python.

The update is the reference tracker's (springtrack/reference.py): eq. (3) with alpha_1
weighting the event, eqs. (4)-(5) about the pre-update mean divided by the gate's bias,
sigma and rho bounded, eq. (6) decaying the winner's activity since its last event.
"""
from libc.math cimport exp, sqrt, ceil, lround
from libc.stdint cimport int64_t, int32_t

import numpy as np
cimport numpy as cnp

from springtrack.events cimport Event
from springtrack.events import EVENT_DTYPE
from springtrack.gate import RHO_MAX as _RHO_MAX

cnp.import_array()

# rows of the state array
FIELDS = ("mx", "my", "sxx", "sxy", "syy", "ia", "ib", "ic", "act", "tlast")
cdef enum:
    F_MX = 0
    F_MY = 1
    F_SXX = 2
    F_SXY = 3
    F_SYY = 4
    F_IA = 5
    F_IB = 6
    F_IC = 7
    F_ACT = 8
    F_TLAST = 9
    N_FIELDS = 10

cdef double RHO_MAX = _RHO_MAX


cdef inline void clamp_invert(double[:, ::1] st, int i, double smin2, double smax2) noexcept nogil:
    """Bound sigma_x, sigma_y and |rho| as the reference does, then refresh Sigma^-1."""
    cdef double sxx = min(max(st[F_SXX, i], smin2), smax2)
    cdef double syy = min(max(st[F_SYY, i], smin2), smax2)
    cdef double lim = RHO_MAX * sqrt(sxx * syy)
    cdef double sxy = min(max(st[F_SXY, i], -lim), lim)
    cdef double inv_det = 1.0 / (sxx * syy - sxy * sxy)
    st[F_SXX, i] = sxx
    st[F_SXY, i] = sxy
    st[F_SYY, i] = syy
    st[F_IA, i] = syy * inv_det
    st[F_IB, i] = -sxy * inv_det
    st[F_IC, i] = sxx * inv_det


def refresh(double[:, ::1] st, int i, double smin2, double smax2):
    """Bound tracker ``i``'s covariance and recompute its inverse (after Python edits)."""
    clamp_invert(st, i, smin2, smax2)


def pool_batch(events, double[:, ::1] st, int n, double a1, double cov_gain, double a2,
               double gate, double tau_us, double smin2, double smax2, int width, int height,
               int32_t[::1] winner, double[:, ::1] overlap, int32_t[:, ::1] net,
               int64_t[:, ::1] last):
    """Run ``events`` (EVENT_DTYPE, time order) through the first ``n`` trackers of ``st``.

    ``winner[k]``: the index of the tracker that took event k, -1 if none, -2 if the event
    lies outside the ``width`` x ``height`` sensor.  ``overlap[i, j]`` (i < j) counts the
    events taken by one of i, j that fell inside the other's gate too.  ``net``
    (height x width) counts each pixel's ON minus OFF events: the change of its log
    intensity in contrast thresholds; ``last`` (height x width) each pixel's latest event
    time (µs)."""
    cdef cnp.ndarray arr = np.ascontiguousarray(events)
    if arr.dtype != EVENT_DTYPE:
        raise TypeError("pool_batch needs EVENT_DTYPE events")
    cdef Py_ssize_t m = arr.shape[0], k
    if winner.shape[0] < m:
        raise ValueError("winner buffer shorter than the batch")
    if n > st.shape[1] or n > overlap.shape[0]:
        raise ValueError("more trackers than the state holds")
    if net.shape[0] < height or net.shape[1] < width:
        raise ValueError("the polarity map is smaller than the sensor")
    if last.shape[0] < height or last.shape[1] < width:
        raise ValueError("the time map is smaller than the sensor")
    cdef const Event* ev = <const Event*> cnp.PyArray_DATA(arr)
    cdef int i, best, second
    cdef double fx, fy, dx, dy, d2, best_d2, second_d2, p, keep = 1.0 - a2
    with nogil:
        for k in range(m):
            if ev[k].x >= width or ev[k].y >= height:
                winner[k] = -2
                continue
            net[ev[k].y, ev[k].x] += 1 if ev[k].p else -1
            last[ev[k].y, ev[k].x] = ev[k].t
            fx = ev[k].x
            fy = ev[k].y
            # eq. (2) in the log domain: smallest d^2 inside the gate, and the runner-up
            best = -1
            second = -1
            best_d2 = gate
            second_d2 = gate
            for i in range(n):
                dx = fx - st[F_MX, i]
                dy = fy - st[F_MY, i]
                d2 = st[F_IA, i] * dx * dx + st[F_IC, i] * dy * dy + 2.0 * st[F_IB, i] * dx * dy
                if d2 < best_d2:
                    second_d2 = best_d2
                    second = best
                    best_d2 = d2
                    best = i
                elif d2 < second_d2:
                    second_d2 = d2
                    second = i
            winner[k] = best
            if best < 0:
                continue
            if second >= 0:
                if best < second:
                    overlap[best, second] += 1.0
                else:
                    overlap[second, best] += 1.0
            i = best
            p = exp(-0.5 * best_d2)
            # eq. (6): A = A exp(-dt / tau) + p
            st[F_ACT, i] = st[F_ACT, i] * exp(-(ev[k].t - st[F_TLAST, i]) / tau_us) + p
            st[F_TLAST, i] = ev[k].t
            dx = fx - st[F_MX, i]                      # eq. (5) about the pre-update mean
            dy = fy - st[F_MY, i]
            st[F_MX, i] = st[F_MX, i] + a1 * dx        # eq. (3): mu = mu + a1 (u - mu)
            st[F_MY, i] = st[F_MY, i] + a1 * dy
            # eq. (4): Sigma = (1 - a2) Sigma + a2 dSigma / bias
            st[F_SXX, i] = keep * st[F_SXX, i] + cov_gain * (dx * dx)
            st[F_SXY, i] = keep * st[F_SXY, i] + cov_gain * (dx * dy)
            st[F_SYY, i] = keep * st[F_SYY, i] + cov_gain * (dy * dy)
            clamp_invert(st, i, smin2, smax2)
    return m


def segment_gaps(int32_t[:, ::1] net, double[::1] xa, double[::1] ya, double[::1] xb,
                 double[::1] yb, double level, int sign, double[::1] out):
    """For each segment (xa, ya) -> (xb, yb): the longest stretch (px) of it whose pixels
    stand below ``level`` in ``sign`` * ``net`` (or lie outside the map), sampled every
    pixel or less along the segment, both ends included."""
    cdef Py_ssize_t p, s, k, run, longest
    cdef Py_ssize_t h = net.shape[0], w = net.shape[1]
    cdef double d, u
    cdef long ix, iy
    cdef bint covered
    for p in range(xa.shape[0]):
        d = sqrt((xb[p] - xa[p]) * (xb[p] - xa[p]) + (yb[p] - ya[p]) * (yb[p] - ya[p]))
        k = <Py_ssize_t>ceil(d) + 1
        if k < 2:
            k = 2
        run = 0
        longest = 0
        for s in range(k):
            u = <double>s / (k - 1)
            ix = lround(xa[p] + u * (xb[p] - xa[p]))
            iy = lround(ya[p] + u * (yb[p] - ya[p]))
            covered = 0 <= ix < w and 0 <= iy < h and sign * net[iy, ix] >= level
            if covered:
                run = 0
            else:
                run += 1
                if run > longest:
                    longest = run
        out[p] = longest * d / (k - 1)


def recent_components(int64_t[:, ::1] last, int64_t t_from, int32_t[:, ::1] label,
                      int32_t[::1] stack):
    """Label the 8-connected components of the pixels that fired at or after ``t_from``
    and have a neighbour (of their 8) that did too (a lone pixel is noise): ``label`` 0
    elsewhere, 1..n on them (``stack``: scratch of height x width entries).  Returns n."""
    cdef Py_ssize_t h = last.shape[0], w = last.shape[1], y, x, yy, xx, top
    cdef int dy, dx, nb
    cdef int32_t n = 0
    cdef int32_t q
    if label.shape[0] != h or label.shape[1] != w or stack.shape[0] < h * w:
        raise ValueError("label map or stack does not match the time map")
    with nogil:
        for y in range(h):
            for x in range(w):
                label[y, x] = 0
                if last[y, x] < t_from:
                    continue
                nb = 0
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        yy = y + dy
                        xx = x + dx
                        if (dy or dx) and 0 <= yy < h and 0 <= xx < w and last[yy, xx] >= t_from:
                            nb += 1
                if nb:
                    label[y, x] = -1                   # recent, not yet labelled
        for y in range(h):
            for x in range(w):
                if label[y, x] != -1:
                    continue
                n += 1
                label[y, x] = n
                stack[0] = <int32_t>(y * w + x)
                top = 1
                while top:
                    top -= 1
                    q = stack[top]
                    for dy in range(-1, 2):
                        for dx in range(-1, 2):
                            yy = q // w + dy
                            xx = q % w + dx
                            if 0 <= yy < h and 0 <= xx < w and label[yy, xx] == -1:
                                label[yy, xx] = n
                                stack[top] = <int32_t>(yy * w + xx)
                                top += 1
    return n
