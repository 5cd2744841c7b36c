# cython: language_level=3
"""The two inner loops of pose acquisition (see springtrack/acquisition/acquire.py).

``score_grid``  the coarse search: for every candidate rotation/scale (a row of tracker
                offsets and blur levels) and every translation of a grid, the sum over
                trackers of a per-level score image read at the tracker's cell; keeps
                the best translation-local maxima of all poses in a small table.
``moments``     for placed trackers (means, covariances), the weighted event count and
                first moments of a count image inside each tracker's gate.
``surround``    each tracker's local background: the count and area of an annulus
                around it, outside every tracker's gate.
``refine``      the annealed EM of the refinement from one pose: ``moments`` as the
                E-step, a weighted similarity fit (Umeyama 1991, closed form in 2-D) as
                the M-step, robust (Cauchy) weights on the residuals.
All run without the GIL on typed memoryviews; no allocation per pose, pixel or iteration
(``refine`` takes its scratch arrays from the caller).
"""
from libc.math cimport atan2, ceil, cos, floor, hypot, sin, sqrt


cdef extern from "springtrack/csrc/acquire_grid.h" nogil:
    void acq_pose_plane(const float *levels, const int *off, const int *lev, const float *w,
                        int n_k, long hw, int wp, int ny, int nx, float *plane)


def score_grid(const float[:, :, ::1] levels, const int[:, ::1] off, const int[:, ::1] lev,
               const float[::1] weight, int ny, int nx, float[:, ::1] plane,
               int[:, ::1] best_idx, float[::1] best_score):
    """Score every (pose p, translation cell y, x) and keep the best local maxima.

    levels: (L, Hp, Wp) padded score images; off[p, k]: flat offset, within one level
    image, of tracker k's cell for pose p when the model centre is at translation cell
    (0, 0); lev[p, k]: its level.  The score of (p, y, x) is
    sum_k weight[k] * levels[lev[p, k]].flat[off[p, k] + y * Wp + x].
    plane: scratch of at least (ny, nx).  best_idx (N, 3) rows (p, y, x) and
    best_score (N,) (initialised to -inf by the caller) receive the N highest scores
    among translation-local maxima (8-neighbourhood, ties kept); returns nothing.
    """
    cdef Py_ssize_t P = off.shape[0], K = off.shape[1], Wp = levels.shape[2]
    cdef Py_ssize_t HW = levels.shape[1] * Wp, N = best_score.shape[0]
    cdef Py_ssize_t p, y, x, j, worst
    cdef float v, lo
    with nogil:
        worst = 0
        lo = best_score[0]
        for j in range(N):
            if best_score[j] < lo:
                lo = best_score[j]
                worst = j
        for p in range(P):
            acq_pose_plane(&levels[0, 0, 0], &off[p, 0], &lev[p, 0], &weight[0], <int>K, HW,
                           <int>Wp, ny, nx, &plane[0, 0])
            for y in range(ny):
                for x in range(nx):
                    v = plane[y, x]
                    if v <= lo:
                        continue
                    if (x > 0 and plane[y, x - 1] > v) or (x + 1 < nx and plane[y, x + 1] > v):
                        continue
                    if y > 0 and (plane[y - 1, x] > v or (x > 0 and plane[y - 1, x - 1] > v)
                                  or (x + 1 < nx and plane[y - 1, x + 1] > v)):
                        continue
                    if y + 1 < ny and (plane[y + 1, x] > v or (x > 0 and plane[y + 1, x - 1] > v)
                                       or (x + 1 < nx and plane[y + 1, x + 1] > v)):
                        continue
                    best_score[worst] = v
                    best_idx[worst, 0] = <int>p
                    best_idx[worst, 1] = <int>y
                    best_idx[worst, 2] = <int>x
                    lo = best_score[0]
                    worst = 0
                    for j in range(N):
                        if best_score[j] < lo:
                            lo = best_score[j]
                            worst = j


cdef struct Sparse:
    # the nonzero pixels of a count image, row by row (compressed sparse rows)
    const int *row             # (H + 1,) start of each row in col / val
    const int *col             # x of each nonzero pixel, increasing within a row
    const float *val           # its count
    int h, w


cdef inline Sparse _sparse(const int[::1] row, const int[::1] col, const float[::1] val,
                           int w):
    cdef Sparse sp
    sp.row, sp.col, sp.val = &row[0], &col[0], &val[0]
    sp.h, sp.w = row.shape[0] - 1, w
    return sp


cdef inline bint _box(double mx, double my, double sxx, double syy, double reach2, int w,
                      int h, int *x0, int *y0, int *x1, int *y1) noexcept nogil:
    """The pixels (x0..x1, y0..y1) of the bounding box of d^2 < reach2 on the sensor;
    False when it misses the sensor."""
    cdef double bx = sqrt(reach2 * sxx), by = sqrt(reach2 * syy)
    if not (mx + bx >= 0 and my + by >= 0 and mx - bx <= w - 1 and my - by <= h - 1):
        return False
    x0[0] = <int>ceil(mx - bx) if mx - bx > 0 else 0
    y0[0] = <int>ceil(my - by) if my - by > 0 else 0
    x1[0] = <int>floor(mx + bx) if mx + bx < w - 1 else w - 1
    y1[0] = <int>floor(my + by) if my + by < h - 1 else h - 1
    return True


cdef inline int _first_at(Sparse img, int y, int x0) noexcept nogil:
    """Index of the first nonzero pixel of row y at x >= x0."""
    cdef int lo = img.row[y], hi = img.row[y + 1], mid
    while lo < hi:
        mid = (lo + hi) >> 1
        if img.col[mid] < x0:
            lo = mid + 1
        else:
            hi = mid
    return lo


cdef void _moments_one(Sparse img, double mx, double my, double sxx, double sxy,
                       double syy, double flat2, double gate2, double *out) noexcept nogil:
    """out = (sum w, sum w dx, sum w dy) of one tracker (``moments``)."""
    cdef int x0, x1, y0, y1, y, i
    cdef double det = sxx * syy - sxy * sxy, ia, ib, ic, dx, dy, d2, w, v
    cdef double sw = 0.0, swx = 0.0, swy = 0.0
    cdef double taper = 1.0 / (gate2 - flat2) if gate2 > flat2 else 0.0
    out[0] = out[1] = out[2] = 0.0
    if not det > 0 or not _box(mx, my, sxx, syy, gate2, img.w, img.h, &x0, &y0, &x1, &y1):
        return
    ia, ib, ic = syy / det, -sxy / det, sxx / det
    for y in range(y0, y1 + 1):
        dy = y - my
        i = _first_at(img, y, x0)
        while i < img.row[y + 1] and img.col[i] <= x1:
            v = img.val[i]
            dx = img.col[i] - mx
            i += 1
            d2 = ia * dx * dx + 2.0 * ib * dx * dy + ic * dy * dy
            if d2 >= gate2:
                continue
            w = v if d2 <= flat2 else v * (gate2 - d2) * taper
            sw += w
            swx += w * dx
            swy += w * dy
    out[0] = sw
    out[1] = swx
    out[2] = swy


def moments(const int[::1] row, const int[::1] col, const float[::1] val, int width,
            const double[::1] mx, const double[::1] my,
            const double[::1] sxx, const double[::1] sxy, const double[::1] syy,
            double flat2, double gate2, double[:, ::1] out):
    """Weighted count and first moments of a count image about each tracker.

    The image: its nonzero pixels by rows (row (H + 1,) offsets into col, val: x and
    count, x increasing within a row), ``width`` W.  Tracker k: mean (mx, my) px,
    covariance [[sxx, sxy], [sxy, syy]] px^2; a pixel of count c at Mahalanobis
    distance d weighs w = c for d^2 <= flat2, c (gate2 - d^2) / (gate2 - flat2) up to
    gate2, 0 beyond: a flat top, so that the weighted mean of a ring or a blob of the
    tracker's size is its centre wherever it lies within the top.  out[k] = (sum w,
    sum w dx, sum w dy), dx = x - mx.
    """
    cdef Py_ssize_t k
    cdef Sparse img = _sparse(row, col, val, width)
    with nogil:
        for k in range(mx.shape[0]):
            _moments_one(img, mx[k], my[k], sxx[k], sxy[k], syy[k], flat2, gate2, &out[k, 0])


cdef inline double _d2(double ia, double ib, double ic, double dx, double dy) noexcept nogil:
    return ia * dx * dx + 2.0 * ib * dx * dy + ic * dy * dy


def surround(const int[::1] row, const int[::1] col, const float[::1] val, int width,
             const double[::1] mx, const double[::1] my,
             const double[::1] sxx, const double[::1] sxy, const double[::1] syy,
             double gate2, double sur2, unsigned char[:, ::1] mask, double[:, ::1] out):
    """Each tracker's local background: the count and the area (px) of the annulus
    gate2 <= d^2 < sur2 around it, on the sensor and outside every tracker's gate
    (where the model expects no part).  The image as for ``moments``; mask: (H, W)
    scratch.  out[k] = (count, area)."""
    cdef Py_ssize_t K = mx.shape[0], k
    cdef Sparse img = _sparse(row, col, val, width)
    cdef int x0, x1, y0, y1, x, y, i
    cdef double det, ia, ib, ic, dy, d2, count, area
    with nogil:
        mask[:, :] = 0
        for k in range(K):                      # the gates
            det = sxx[k] * syy[k] - sxy[k] * sxy[k]
            if not det > 0 or not _box(mx[k], my[k], sxx[k], syy[k], gate2, img.w, img.h,
                                       &x0, &y0, &x1, &y1):
                continue
            ia, ib, ic = syy[k] / det, -sxy[k] / det, sxx[k] / det
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    if _d2(ia, ib, ic, x - mx[k], y - my[k]) < gate2:
                        mask[y, x] = 1
        for k in range(K):
            out[k, 0] = out[k, 1] = 0.0
            det = sxx[k] * syy[k] - sxy[k] * sxy[k]
            if not det > 0 or not _box(mx[k], my[k], sxx[k], syy[k], sur2, img.w, img.h,
                                       &x0, &y0, &x1, &y1):
                continue
            ia, ib, ic = syy[k] / det, -sxy[k] / det, sxx[k] / det
            count = area = 0.0
            for y in range(y0, y1 + 1):
                dy = y - my[k]
                for x in range(x0, x1 + 1):
                    if mask[y, x] == 0:
                        d2 = _d2(ia, ib, ic, x - mx[k], dy)
                        if gate2 <= d2 < sur2:
                            area += 1.0
                i = _first_at(img, y, x0)
                while i < img.row[y + 1] and img.col[i] <= x1:
                    x = img.col[i]
                    if mask[y, x] == 0:
                        d2 = _d2(ia, ib, ic, x - mx[k], dy)
                        if gate2 <= d2 < sur2:
                            count += img.val[i]
                    i += 1
            out[k, 0] = count
            out[k, 1] = area


cdef void _similarity(const double[:, ::1] q, const double[::1] ox, const double[::1] oy,
                      const double[::1] w, double *pose) noexcept nogil:
    """pose = (tx, ty, theta, s) minimising sum_k w_k |o_k - (t + s R(theta) q_k)|^2."""
    cdef Py_ssize_t K = q.shape[0], k
    cdef double sw = 0, qx = 0, qy = 0, mx = 0, my = 0, a = 0, b = 0, qq = 0, dqx, dqy, dmx, dmy
    cdef double c, n, s
    for k in range(K):
        sw += w[k]
        qx += w[k] * q[k, 0]
        qy += w[k] * q[k, 1]
        mx += w[k] * ox[k]
        my += w[k] * oy[k]
    qx /= sw
    qy /= sw
    mx /= sw
    my /= sw
    for k in range(K):
        dqx, dqy = q[k, 0] - qx, q[k, 1] - qy
        dmx, dmy = ox[k] - mx, oy[k] - my
        a += w[k] * (dqx * dmx + dqy * dmy)
        b += w[k] * (dqx * dmy - dqy * dmx)
        qq += w[k] * (dqx * dqx + dqy * dqy)
    pose[2] = atan2(b, a)
    s = hypot(a, b) / qq if qq > 1e-12 else 1.0
    c, n = cos(pose[2]), sin(pose[2])
    pose[0] = mx - s * (c * qx - n * qy)
    pose[1] = my - s * (n * qx + c * qy)
    pose[3] = s


cdef inline double _clamp(double v, double lo, double hi) noexcept nogil:
    return lo if v < lo else (hi if v > hi else v)


def refine(const int[::1] row, const int[::1] col, const float[::1] val, int width,
           const double[:, ::1] q, const double[:, ::1] cov,
           const double[::1] sigma, double[::1] pose, const double[::1] lo,
           const double[::1] hi, const double[::1] tau, int max_iter, double converged_px,
           double rho, double flat2, double gate2, double gate_area, double kappa,
           double z, double n_min, double cauchy, double[:, ::1] scratch):
    """Annealed EM of the acquisition's refinement, from and into ``pose``.

    The count image as for ``moments``.
    q (K, 2): the model's points about its centre of mass; cov (K, 3): their covariances
    (sxx, sxy, syy); sigma (K,): their sizes sqrt(sqrt(det)); pose (4,): (tx, ty, theta,
    s), kept within [lo, hi] (4,) each; tau: the widening (px) of the first iterations,
    0 after them.  Per iteration, each tracker placed at the pose with covariance
    s^2 R cov R^T + tau^2 I: its moments (``moments``); the background's share
    b = rho * gate_area * sqrt(det) removed from the weighted count (net); the observed
    centre mean + first moment / net; the weight net / (net + kappa b + z sqrt(b) +
    n_min) (0 when net <= 0 or when the sensor's edge cuts the flat top), times a Cauchy
    weight
    1 / (1 + r^2 / (cauchy^2 (sigma^2 s^2 + tau^2))) of the residual r
    to the fit (two reweighting rounds); the pose <- the weighted similarity fit.  Stops
    after ``max_iter`` iterations, or when tau is 0 and no tracker moved more than
    ``converged_px``, or when fewer than 2 trackers hold events.  scratch: (7, K).
    Returns the number of iterations run.
    """
    cdef Py_ssize_t K = q.shape[0], k
    cdef Sparse img = _sparse(row, col, val, width)
    cdef int H = img.h, W = img.w
    cdef int it, r, n_ok
    cdef double t, c, n, s, cxx, cxy, cyy, rxx, rxy, ryy, det, bg, net
    cdef double fx, fy, d2, moved
    cdef double new[4]
    cdef double mom[3]
    cdef double[::1] ox = scratch[0]
    cdef double[::1] oy = scratch[1]
    cdef double[::1] wv = scratch[2]
    cdef double[::1] robust = scratch[3]
    cdef double[::1] wt = scratch[4]
    cdef double[::1] px = scratch[5]
    cdef double[::1] py = scratch[6]
    it = 0
    with nogil:
        for k in range(K):
            robust[k] = 1.0
        while it < max_iter:
            t = tau[it] if it < tau.shape[0] else 0.0
            it += 1
            c, n, s = cos(pose[2]), sin(pose[2]), pose[3]
            n_ok = 0
            for k in range(K):
                px[k] = pose[0] + s * (c * q[k, 0] - n * q[k, 1])
                py[k] = pose[1] + s * (n * q[k, 0] + c * q[k, 1])
                # s^2 R C R^T + t^2 I
                cxx, cxy, cyy = cov[k, 0], cov[k, 1], cov[k, 2]
                rxx = s * s * (c * c * cxx - 2 * c * n * cxy + n * n * cyy) + t * t
                rxy = s * s * (c * n * (cxx - cyy) + (c * c - n * n) * cxy)
                ryy = s * s * (n * n * cxx + 2 * c * n * cxy + c * c * cyy) + t * t
                _moments_one(img, px[k], py[k], rxx, rxy, ryy, flat2, gate2, mom)
                det = rxx * ryy - rxy * rxy
                bg = rho * gate_area * sqrt(det)        # the background's share
                net = mom[0] - bg
                ox[k], oy[k] = px[k], py[k]
                wv[k] = 0.0
                # a tracker whose flat top the sensor's edge cuts sees a biased mean
                fx, fy = sqrt(flat2 * rxx), sqrt(flat2 * ryy)
                if net > 0 and px[k] - fx >= 0 and py[k] - fy >= 0 and px[k] + fx <= W - 1 \
                        and py[k] + fy <= H - 1:
                    ox[k] = px[k] + mom[1] / net
                    oy[k] = py[k] + mom[2] / net
                    wv[k] = net / (net + kappa * bg + z * sqrt(bg) + n_min)
                    n_ok += 1
            if n_ok < 2:
                break
            for r in range(2):                          # reweighting on the residuals
                for k in range(K):
                    wt[k] = wv[k] * robust[k]
                _similarity(q, ox, oy, wt, new)
                c, n = cos(new[2]), sin(new[2])
                for k in range(K):
                    fx = new[0] + new[3] * (c * q[k, 0] - n * q[k, 1])
                    fy = new[1] + new[3] * (n * q[k, 0] + c * q[k, 1])
                    d2 = (ox[k] - fx) ** 2 + (oy[k] - fy) ** 2
                    robust[k] = 1.0 / (1.0 + d2 / (cauchy * cauchy
                                                   * (sigma[k] * sigma[k] * new[3] * new[3] + t * t)))
            for r in range(4):
                new[r] = _clamp(new[r], lo[r], hi[r])
            c, n, s = cos(new[2]), sin(new[2]), new[3]
            moved = 0.0
            for k in range(K):
                fx = new[0] + s * (c * q[k, 0] - n * q[k, 1]) - px[k]
                fy = new[1] + s * (n * q[k, 0] + c * q[k, 1]) - py[k]
                if fx * fx + fy * fy > moved:
                    moved = fx * fx + fy * fy
            for r in range(4):
                pose[r] = new[r]
            if t == 0.0 and moved < converged_px * converged_px:
                break
    return it
