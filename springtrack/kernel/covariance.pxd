# The float64 kernel's covariances: eq. (4)'s update kept positive definite and inverted
# for eq. (2).
#
# A tracker's covariance is clamped as the reference clamps it (sigmas within
# [sigma_min_px, sigma_max_px], |correlation| <= RHO_MAX) and inverted with one division;
# the step (kernel/step.pxd) runs it after every update, the springs' state guard
# (kernel/springs.pyx) and the kernel's loading (kernel/kernel.pyx) on every tracker.
#
# cdef inline: compiled into each module that cimports it.
from libc.math cimport sqrt

from springtrack.kernel.state cimport KState

cdef extern from *:
    """
    /* springtrack/kernel/covariance.pxd: springtrack.reference.RHO_MAX, the |correlation|
       bound that keeps a covariance positive definite (kernel/kernel.pyx checks they agree),
       and its square made slightly low, so that the exact test never misses a clamp */
    #define ST_RHO_MAX 0.99
    #define ST_RHO_MAX2 (ST_RHO_MAX * ST_RHO_MAX * (1.0 - 1e-12))
    """
    const double ST_RHO_MAX
    const double ST_RHO_MAX2


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
    if sxy * sxy > ST_RHO_MAX2 * (sxx * syy):    # |rho| may exceed RHO_MAX: the exact test
        lim = ST_RHO_MAX * sqrt(sxx * syy)
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
