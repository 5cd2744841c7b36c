# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The float64 kernel's internals, for the tests (never installed; tests/support/probes.py
builds it with setup.py's flags): csrc/fastmath.h and the eq. (14) fast path of
csrc/springs.h on float64 arrays, and a Kernel's spatial index and means.

    kp = probes.load("kernel_probe")
    kp.place(kernel, i, x, y)            # move tracker i's mean (then kernel.springs())
    assert kp.check_index(kernel)
"""
from libc.math cimport sqrt
from libc.stdint cimport int64_t

import numpy as np

from springtrack.kernel.kernel cimport Kernel, KState
from springtrack.kernel.index cimport reindex

cdef extern from "springtrack/csrc/fastmath.h" nogil:
    double st_exp(double x)
    void st_exp_batch(const double* x, double* out, int n)
    void st_atan2_batch(const double* y, const double* x, double* out, int n)
    void st_sincos_batch(const double* e, double* sn, double* cm1, int n)

cdef extern from "springtrack/csrc/springs.h" nogil:
    int64_t st_torsion_angles_framed(int n, const double* rx, const double* ry,
                                     const double* qdx, const double* qdy, double phi,
                                     double* th)


# ---- a Kernel's state ----------------------------------------------------------------
def place(Kernel kernel, int i, double x, double y):
    """Move tracker i's mean to (x, y) px and re-index it (a configuration for springs())."""
    cdef KState* s = &kernel.st
    if not 0 <= i < s.n:
        raise IndexError(f"tracker {i} out of range [0, {s.n})")
    s.mx[i] = x
    s.my[i] = y
    reindex(s, i)


def check_index(Kernel kernel):
    """The spatial index invariant: each tracker's exact gate box, about its mean and about
    its mean predicted the horizon ahead (eq. M1: every prediction lies between the two),
    lies inside its indexed box and its bit is set in every cell of that box."""
    cdef KState* s = &kernel.st
    cdef int i, cx, cy
    for i in range(s.n):
        hx = sqrt(s.gate * s.sxx[i])
        hy = sqrt(s.gate * s.syy[i])
        for x, y in ((s.mx[i], s.my[i]),
                     (s.mx[i] + s.vx[i] * s.horizon, s.my[i] + s.vy[i] * s.horizon)):
            if (x - hx < s.bx_lo[i] or x + hx > s.bx_hi[i]
                    or y - hy < s.by_lo[i] or y + hy > s.by_hi[i]):
                return False
        for cy in range(s.box_y0[i], s.box_y1[i] + 1):
            for cx in range(s.box_x0[i], s.box_x1[i] + 1):
                if not (s.cells[(cy * s.gw + cx) * s.nw + (i >> 6)] >> (i & 63)) & 1:
                    return False
    return True


# ---- csrc/fastmath.h and springs.h ---------------------------------------------------
def fastmath_atan2(y, x):
    """st_atan2_batch over two float64 arrays (the kernel's eq. 14 atan2)."""
    cdef double[::1] vy = np.ascontiguousarray(y, np.float64)
    cdef double[::1] vx = np.ascontiguousarray(x, np.float64)
    if vy.shape[0] != vx.shape[0]:
        raise ValueError("y and x must have the same length")
    out = np.empty(vy.shape[0])
    cdef double[::1] vo = out
    if vy.shape[0]:
        st_atan2_batch(&vy[0], &vx[0], &vo[0], <int>vy.shape[0])
    return out


def torsion_angles_framed(rx, ry, qdx, qdy, double phi):
    """st_torsion_angles_framed over float64 arrays: (th, far), the kernel's fast eq. (14)."""
    cdef double[::1] vrx = np.ascontiguousarray(rx, np.float64)
    cdef double[::1] vry = np.ascontiguousarray(ry, np.float64)
    cdef double[::1] vqx = np.ascontiguousarray(qdx, np.float64)
    cdef double[::1] vqy = np.ascontiguousarray(qdy, np.float64)
    cdef Py_ssize_t n = vrx.shape[0]
    if not (vry.shape[0] == vqx.shape[0] == vqy.shape[0] == n):
        raise ValueError("rx, ry, qdx and qdy must have the same length")
    th = np.empty(n)
    cdef double[::1] vo = th
    cdef int64_t far = 0
    if n:
        far = st_torsion_angles_framed(<int>n, &vrx[0], &vry[0], &vqx[0], &vqy[0], phi, &vo[0])
    return th, bool(far)


def fastmath_sincos(e):
    """st_sincos_batch: (sin e, cos e - 1) over a float64 array (the kernel's eq. 16)."""
    cdef double[::1] ve = np.ascontiguousarray(e, np.float64)
    sn = np.empty(ve.shape[0])
    cm1 = np.empty(ve.shape[0])
    cdef double[::1] vs = sn, vc = cm1
    if ve.shape[0]:
        st_sincos_batch(&ve[0], &vs[0], &vc[0], <int>ve.shape[0])
    return sn, cm1


def fastmath_exp(x):
    """st_exp elementwise over a float64 array (the kernel's eqs. 2 and 6)."""
    cdef double[::1] vx = np.ascontiguousarray(x, np.float64)
    out = np.empty(vx.shape[0])
    cdef double[::1] vo = out
    cdef Py_ssize_t k
    for k in range(vx.shape[0]):
        vo[k] = st_exp(vx[k])
    return out


def fastmath_exp_batch(x):
    """st_exp_batch over a float64 array (the kernel's activity log, eq. 6)."""
    cdef double[::1] vx = np.ascontiguousarray(x, np.float64)
    out = np.empty(vx.shape[0])
    cdef double[::1] vo = out
    if vx.shape[0]:
        st_exp_batch(&vx[0], &vo[0], <int>vx.shape[0])
    return out
