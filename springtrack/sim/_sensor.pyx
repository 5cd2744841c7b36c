# cython: language_level=3
"""Per-pixel kernels of the simulated ATIS sensor (see springtrack/sim/sensor.py).

``render``  draws a scene frame (additive Gaussian blobs or soft-edged disks on a flat
            background, then opaque soft-edged ellipses composited on top) and takes
            its log, inside a rectangle only: pixels outside it hold the background.
``emit``    the contrast-threshold event model of ESIM (Rebecq et al. 2018) and v2e
            (Hu et al. 2021): between two rendered frames the log intensity of a pixel is
            linear in time; each crossing of the pixel's reference level by its ON/OFF
            threshold gives one event, timestamped where the line crosses; the
            reference moves by one threshold per crossing.  An event closer than the
            refractory period to the pixel's previous event is suppressed (counted) but
            still moves the reference, as in v2e.
Both loops run without the GIL on typed memoryviews.
"""
from libc.math cimport exp, expf, logf, sqrtf, floor, fabs
from libc.stdint cimport int64_t, uint16_t, uint8_t

from springtrack.events cimport Event


cdef inline int _clip(int v, int lo, int hi) noexcept nogil:
    return lo if v < lo else (hi if v > hi else v)


# logistic edge 1 / (1 + exp(u)) tabulated over u in [-6, 6] (the range render uses)
DEF _LUT_N = 2048
cdef float _LUT[_LUT_N + 1]
cdef float _LUT_LO = -6.0, _LUT_HI = 6.0
for _i in range(_LUT_N + 1):
    _LUT[_i] = 1.0 / (1.0 + exp(_LUT_LO + (_LUT_HI - _LUT_LO) * _i / _LUT_N))


cdef inline float _alpha(float u) noexcept nogil:
    cdef float f
    cdef int k
    if u <= _LUT_LO:
        return _LUT[0]
    if u >= _LUT_HI:
        return _LUT[_LUT_N]
    f = (u - _LUT_LO) * (_LUT_N / (_LUT_HI - _LUT_LO))
    k = <int>f
    f = f - k
    return _LUT[k] + f * (_LUT[k + 1] - _LUT[k])


DEF DISK_R = 1.4142135623730951    # disk radius in Mahalanobis units: the ring of edge
                                   # events then has covariance sigma^2 per axis


cdef void _disk(float[:, ::1] scratch, double cx, double cy, double a, double b, double c,
                double sxx, double syy, double amp, double edge,
                int x0, int y0, int x1, int y1) noexcept nogil:
    """intensity += amp / (1 + exp(edge (d - sqrt 2))): a flat disk with a soft edge."""
    cdef double rad = DISK_R + 6.0 / edge, inner = DISK_R - 6.0 / edge, dx, dy, d2
    cdef double rx = rad * sqrtf(<float>sxx), ry = rad * sqrtf(<float>syy)
    cdef int x, y
    cdef int bx0 = _clip(<int>floor(cx - rx), x0, x1), bx1 = _clip(<int>floor(cx + rx) + 1, x0, x1)
    cdef int by0 = _clip(<int>floor(cy - ry), y0, y1), by1 = _clip(<int>floor(cy + ry) + 1, y0, y1)
    inner = inner * inner if inner > 0 else -1.0
    for y in range(by0, by1):
        dy = y - cy
        for x in range(bx0, bx1):
            dx = x - cx
            d2 = a * dx * dx + 2.0 * b * dx * dy + c * dy * dy
            if d2 < inner:
                scratch[y, x] += <float>amp
            elif d2 < rad * rad:
                scratch[y, x] += <float>amp * _alpha(<float>(edge * (sqrtf(<float>d2) - DISK_R)))


def render(float[:, ::1] logimg, double[:, ::1] blobs, double[:, ::1] occluders,
           double background, int x0, int y0, int x1, int y1, float[:, ::1] scratch):
    """Write log(intensity) into ``logimg[y0:y1, x0:x1]``.

    blobs: (n, 7) rows x, y, sxx, sxy, syy, amplitude, edge (d: Mahalanobis distance) --
    edge = 0: Gaussian, intensity += a exp(-d^2/2), truncated at d = 3.5;
    edge > 0: flat disk of radius d = sqrt(2) with a logistic edge (see _disk), absent
    beyond d = sqrt(2) + 6/edge.  occluders: (m, 7) rows x, y, sxx,
    sxy, syy, intensity, edge -- an ellipse of 'radius' d = 1 with a logistic edge of
    width 1/edge (in d units), alpha-composited over what is below, in row order
    (opaque for d < 1 - 6/edge, absent for d > 1 + 6/edge).
    ``scratch`` is a float32 image of the sensor size used as the linear buffer.
    """
    cdef Py_ssize_t k
    cdef int x, y, bx0, bx1, by0, by1
    cdef double sxx, sxy, syy, det, a, b, c, cx, cy, amp, rx, ry, dx, dy, d2, rad, edge
    cdef double inten, g, r, q, inner2
    cdef float al, v, lbg
    cdef Py_ssize_t nb = blobs.shape[0], no = occluders.shape[0]
    with nogil:
        for y in range(y0, y1):
            for x in range(x0, x1):
                scratch[y, x] = <float>background
        for k in range(nb):
            cx = blobs[k, 0]; cy = blobs[k, 1]
            sxx = blobs[k, 2]; sxy = blobs[k, 3]; syy = blobs[k, 4]; amp = blobs[k, 5]
            edge = blobs[k, 6]
            det = sxx * syy - sxy * sxy
            if det <= 0:
                continue
            a = syy / det; b = -sxy / det; c = sxx / det     # inverse covariance
            if edge > 0:
                _disk(scratch, cx, cy, a, b, c, sxx, syy, amp, edge, x0, y0, x1, y1)
                continue
            rx = 3.5 * sqrtf(<float>sxx); ry = 3.5 * sqrtf(<float>syy)
            bx0 = _clip(<int>floor(cx - rx), x0, x1); bx1 = _clip(<int>floor(cx + rx) + 1, x0, x1)
            by0 = _clip(<int>floor(cy - ry), y0, y1); by1 = _clip(<int>floor(cy + ry) + 1, y0, y1)
            q = exp(-a)
            for y in range(by0, by1):
                dy = y - cy
                dx = bx0 - cx
                # along a row, g(dx) = amp exp(-d2/2) obeys g(dx+1) = g(dx) r(dx) and
                # r(dx+1) = r(dx) exp(-a): two exp() per row instead of one per pixel
                g = amp * exp(-0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy))
                r = exp(-0.5 * (a * (2.0 * dx + 1.0) + 2.0 * b * dy))
                for x in range(bx0, bx1):
                    dx = x - cx
                    d2 = a * dx * dx + 2.0 * b * dx * dy + c * dy * dy
                    if d2 < 12.25:
                        scratch[y, x] += <float>g
                    g = g * r
                    r = r * q
        for k in range(no):
            cx = occluders[k, 0]; cy = occluders[k, 1]
            sxx = occluders[k, 2]; sxy = occluders[k, 3]; syy = occluders[k, 4]
            inten = occluders[k, 5]; edge = occluders[k, 6]
            det = sxx * syy - sxy * sxy
            if det <= 0 or edge <= 0:
                continue
            a = syy / det; b = -sxy / det; c = sxx / det
            rad = 1.0 + 6.0 / edge       # alpha < 2.5e-3 beyond this radius
            inner2 = 1.0 - 6.0 / edge
            inner2 = inner2 * inner2 if inner2 > 0 else -1.0
            rx = rad * sqrtf(<float>sxx); ry = rad * sqrtf(<float>syy)
            bx0 = _clip(<int>floor(cx - rx), x0, x1); bx1 = _clip(<int>floor(cx + rx) + 1, x0, x1)
            by0 = _clip(<int>floor(cy - ry), y0, y1); by1 = _clip(<int>floor(cy + ry) + 1, y0, y1)
            for y in range(by0, by1):
                dy = y - cy
                for x in range(bx0, bx1):
                    dx = x - cx
                    d2 = a * dx * dx + 2.0 * b * dx * dy + c * dy * dy
                    if d2 < inner2:      # alpha > 1 - 2.5e-3: opaque
                        scratch[y, x] = <float>inten
                    elif d2 < rad * rad:
                        al = _alpha(<float>(edge * (sqrtf(<float>d2) - 1.0)))
                        scratch[y, x] = scratch[y, x] * (1.0 - al) + al * <float>inten
        lbg = logf(<float>background)
        for y in range(y0, y1):
            for x in range(x0, x1):
                v = scratch[y, x]
                logimg[y, x] = lbg if v == <float>background else logf(v)


def emit(float[:, ::1] lprev, float[:, ::1] lnew, float[:, ::1] lref,
         float[:, ::1] c_on, float[:, ::1] c_off, int64_t[:, ::1] last_t,
         int x0, int y0, int x1, int y1, Py_ssize_t start,
         double t0_us, double dt_us, int64_t refractory_us,
         size_t out_addr, Py_ssize_t out_pos, Py_ssize_t capacity):
    """Events for the step [t0_us, t0_us + dt_us) over the rectangle, pixel by pixel
    (row-major) starting at flat index ``start`` within the rectangle.

    Writes into the Event buffer at ``out_addr`` from ``out_pos``; stops before a pixel
    whose worst-case event count would overflow ``capacity`` and returns
    (new out_pos, index to resume at or -1 when done, refractory-suppressed count).
    ``lprev`` is updated to ``lnew`` for every processed pixel.
    """
    cdef Event* out = <Event*> out_addr
    cdef Py_ssize_t w = x1 - x0, pos = out_pos, resume = -1
    cdef Py_ssize_t suppressed = 0, bound
    cdef int x, y
    cdef float l0, l1, ref, con, coff, dl
    cdef double frac, tev
    cdef int64_t ti, t_end = <int64_t>(t0_us + dt_us)
    cdef int ys = <int>(y0 + start // w), xs = <int>(x0 + start % w)
    with nogil:
      for y in range(ys, y1):
        for x in range(xs if y == ys else x0, x1):
            l0 = lprev[y, x]
            l1 = lnew[y, x]
            if l1 == l0:
                continue
            ref = lref[y, x]
            con = c_on[y, x]
            coff = c_off[y, x]
            bound = <Py_ssize_t>(fabs(l1 - ref) / (con if con < coff else coff)) + 2
            if pos + bound > capacity:
                resume = (y - y0) * w + (x - x0)
                break
            dl = l1 - l0
            # ON crossings: the line l(t) rises through ref + con, ref + 2 con, ...
            while l1 - ref >= con:
                ref = ref + con
                frac = (ref - l0) / dl
                if frac < 0.0:
                    frac = 0.0   # float32 rounding guard
                tev = t0_us + frac * dt_us
                ti = <int64_t>floor(tev)
                if ti >= t_end:
                    ti = t_end - 1
                if ti - last_t[y, x] < refractory_us:
                    suppressed += 1
                    continue
                last_t[y, x] = ti
                out[pos].t = ti; out[pos].x = <uint16_t>x; out[pos].y = <uint16_t>y
                out[pos].p = 1
                pos += 1
            # OFF crossings
            while ref - l1 >= coff:
                ref = ref - coff
                frac = (ref - l0) / dl
                if frac < 0.0:
                    frac = 0.0
                tev = t0_us + frac * dt_us
                ti = <int64_t>floor(tev)
                if ti >= t_end:
                    ti = t_end - 1
                if ti - last_t[y, x] < refractory_us:
                    suppressed += 1
                    continue
                last_t[y, x] = ti
                out[pos].t = ti; out[pos].x = <uint16_t>x; out[pos].y = <uint16_t>y
                out[pos].p = 0
                pos += 1
            lref[y, x] = ref
            lprev[y, x] = l1
        if resume >= 0:
            break
    return pos, resume, suppressed
