# The float64 kernel's activity, eq. (6): A_i(t) = sum over tracker i's events k of
# p_k exp(-(t - t_k) / tau).
#
# Stored rescaled: act[i] = A_i(act_t0) = sum of p_k exp((t_k - act_t0) / tau), the same
# sum seen from a common time act_t0, so an event adds one term (one exp) instead of
# decaying the sum since the tracker's last event first (the reference's form; equal up to
# rounding, ~1e-15 relative).  Nothing in the event loop reads the activity (it only
# feeds the output), so the terms' exps are logged and computed in vectorised batches.
#
# cdef inline: compiled into the module that cimports it (springtrack.kernel.kernel, whose
# per-event step logs a term per assigned event).
from libc.math cimport exp
from libc.stdint cimport int64_t

from springtrack.kernel.state cimport KState, ACT_LOG

cdef extern from "springtrack/csrc/fastmath.h" nogil:
    void st_exp_batch(const double* x, double* out, int n)


cdef inline double activity_decay(const KState* s, int64_t t) noexcept nogil:
    """exp(-(t - act_t0) / tau): the factor from the stored activities to those at t, the
    same for every tracker."""
    return exp(-(<double>(t - s.act_t0)) * s.inv_tau)


cdef inline double kactivity(const KState* s, int i, int64_t t) noexcept nogil:
    """eq. (6) at time t, A_i(t) (the log flushed: outside the event loop it is)."""
    return s.act[i] * activity_decay(s, t)


cdef inline void flush_activity(KState* s) noexcept nogil:
    """Add the logged increments: their exps as one vectorised batch (st_exp_batch: the
    same values as st_exp, about a third of its instructions each), added in the order
    logged, so every act[i] is the same sum as if added at once."""
    cdef double v[ACT_LOG]
    cdef int k, n = s.act_n
    if n == 0:
        return
    st_exp_batch(s.act_arg, v, n)
    for k in range(n):
        s.act[s.act_i[k]] += v[k]
    s.act_n = 0


cdef inline void log_activity(KState* s, int i, double arg) noexcept nogil:
    """act[i] += exp(arg), deferred to flush_activity, which runs before act_t0 moves
    (rescale_activity), when the log is full, and whenever a batch of events ends (ksteps,
    kstep): outside them the log is empty."""
    cdef int n = s.act_n
    s.act_i[n] = i
    s.act_arg[n] = arg
    s.act_n = n + 1
    if n + 1 == ACT_LOG:
        flush_activity(s)


cdef inline void rescale_activity(KState* s, int64_t t) noexcept nogil:
    """Move act_t0 to t (every act_span = 32 tau of event time), so the terms added,
    p exp((t - act_t0) / tau) <= e^32, stay far from overflow and rounding loss."""
    cdef int i
    cdef double f = activity_decay(s, t)
    flush_activity(s)                  # the logged exponents are relative to the old act_t0
    for i in range(s.n):
        s.act[i] *= f
    s.act_t0 = t
