# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# distutils: depends = springtrack/fixed/csrc/fixed_step.c springtrack/fixed/csrc/fixed_step.h springtrack/fixed/csrc/fixed_tables.h springtrack/fixed/csrc/fixed_arith.c springtrack/fixed/csrc/fixed_motion.c springtrack/fixed/csrc/fixed_index.c springtrack/fixed/csrc/fixed_tracker.c springtrack/fixed/csrc/fixed_set.c springtrack/fixed/csrc/fixed_spring.c springtrack/fixed/csrc/fixed_frame.c springtrack/fixed/csrc/fixed_update.c springtrack/fixed/csrc/fixed_load.c springtrack/fixed/csrc/fixed_move.c
"""The fixed-point kernel's internals, for the tests (never installed; tests/support/probes.py
builds it with setup.py's flags): the integer building blocks of fixed/csrc/fixed_step.c and a
FixedKernel's raw state and spatial index.

    fx = probes.load("fixed_probe")
    fx.isqrt(v)                          # a building block (constant tables: no state)
    fx.decay(kernel, dt)                 # one that reads the kernel's parameters
    fx.set_raw(kernel, i, x=8191 << 32)  # drive a tracker to a range limit

fixed/csrc/fixed_step.c is compiled into this module as into springtrack.fixed.kernel (same source,
same flags), and works on the FixedKernel's own state.
"""
from libc.stdint cimport int32_t, int64_t, uint32_t, uint64_t

from springtrack.fixed.kernel cimport FixedKernel

cdef extern from "springtrack/fixed/csrc/fixed_step.h" nogil:
    enum:
        FX_MAX_TRACKERS
    ctypedef struct fx_state:            # the members used here (the header has them all)
        int32_t n
        int64_t mx[FX_MAX_TRACKERS]
        int64_t my[FX_MAX_TRACKERS]
        int64_t act[FX_MAX_TRACKERS]
        int32_t energy_stale
    void fx_energies(fx_state* s)
    void fx_reindex(fx_state* s, int i)
    int fx_check_index(const fx_state* s)
    int64_t fx_mulsh(int64_t v, uint32_t g, int sh)
    uint64_t fx_udiv64(uint64_t n, uint32_t d, uint32_t* rem)
    uint32_t fx_divlu32(uint32_t u1, uint32_t u0, uint32_t v, uint32_t* rem)
    uint64_t fx_isqrt64(uint64_t v)
    uint32_t fx_exp2neg(int64_t w)
    int64_t fx_gauss(uint32_t d2)
    uint32_t fx_decay(const fx_state* s, int64_t dt)
    uint32_t fx_atan2(int64_t y, int64_t x)
    void fx_cossin(int64_t angle, int64_t* c, int64_t* sn)
    void fx_polar(int32_t x, int32_t y, uint32_t* ang, int32_t* len, int32_t* cx, int32_t* cy)
    uint32_t fx_d2(const fx_state* s, int i, int32_t x, int32_t y)

cdef extern from "springtrack/fixed/csrc/fixed_step.c":
    pass


cdef inline fx_state* state(FixedKernel k):
    return <fx_state*>k.state


# ---- a FixedKernel's state -----------------------------------------------------------
def set_raw(FixedKernel k, int i, x=None, y=None, act=None):
    """Overwrite tracker i's raw integer state (drive it to a range limit): x, y Q.32
    (int64), act Q.32; the spatial index is refreshed."""
    cdef fx_state* s = state(k)
    if not 0 <= i < s.n:
        raise IndexError(f"tracker index {i} out of range 0..{s.n - 1}")
    if x is not None:
        s.mx[i] = x
    if y is not None:
        s.my[i] = y
    if act is not None:
        s.act[i] = act
    fx_reindex(s, i)


def check_index(FixedKernel k):
    """The spatial index invariant holds (fixed/csrc/fixed_step.c's fx_check_index)."""
    return bool(fx_check_index(state(k)))


def recompute_energies(FixedKernel k):
    """Recompute every kind of the last spring update's energies from the spring vectors
    it kept, the criterion's kind too (the lazily computed kinds must be what the spring
    update would have computed)."""
    cdef fx_state* s = state(k)
    s.energy_stale = 7 | (s.energy_stale & 8)
    fx_energies(s)


# ---- integer building blocks ------------------------------------------------------------
def mulsh(long long v, unsigned int g, int sh):
    """(v * g) >> sh, rounded half up: two 32 x 32 products, exact."""
    return fx_mulsh(v, g, sh)


def udiv64(unsigned long long n, unsigned int d):
    """(floor(n / d), n mod d): what a 32-bit core builds from 32-bit divisions."""
    cdef uint32_t r
    q = fx_udiv64(n, d, &r)
    return q, r


def divlu32(unsigned int u1, unsigned int u0, unsigned int v):
    """(floor((u1 2^32 + u0) / v), remainder) for u1 < v from 32-bit divisions only, the
    path a 32-bit core takes (a 64-bit host divides natively: the same integers)."""
    cdef uint32_t r
    q = fx_divlu32(u1, u0, v, &r)
    return q, r


def isqrt(unsigned long long v):
    """floor(sqrt(v))."""
    return fx_isqrt64(v)


def exp2neg(long long w):
    """2^-w for w in Q.40, Q.30."""
    return fx_exp2neg(w)


def gauss(unsigned int d2):
    """exp(-d2 / 2) for d2 in Q.27 (0 <= d2 < 32), Q.30: the kernel value of eq. (2)."""
    return fx_gauss(d2)


def decay(FixedKernel k, long long dt):
    """exp(-dt / tau) for dt in us, Q.30: the activity decay of eq. (6) (the kernel's tau)."""
    return fx_decay(state(k), dt)


def d2(FixedKernel k, int i, int x, int y):
    """Tracker i's Mahalanobis d^2 (eq. 2) of pixel (x, y), Q.27, saturated at 2^32 - 1."""
    cdef fx_state* s = state(k)
    if not 0 <= i < s.n:
        raise IndexError(f"tracker index {i} out of range 0..{s.n - 1}")
    return fx_d2(s, i, x, y)


def atan2(long long y, long long x):
    """atan2(y, x) as a binary angle (2^32 per turn)."""
    return fx_atan2(y, x)


def polar(int x, int y):
    """(binary angle, length, cos Q.30, sin Q.30) of the vector (x, y)."""
    cdef uint32_t a
    cdef int32_t l, cx, cy
    fx_polar(x, y, &a, &l, &cx, &cy)
    return a, l, cx, cy


def cossin(long long angle):
    """(cos, sin) Q.30 of a binary angle."""
    cdef int64_t c, sn
    fx_cossin(angle, &c, &sn)
    return c, sn
