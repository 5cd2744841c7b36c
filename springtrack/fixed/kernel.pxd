# C-level interface of the fixed-point tracker kernel (springtrack/fixed/kernel.pyx).
#
# Other Cython modules (e.g. a firmware loop) cimport this; the integer state stays
# opaque to them, so they need no C header:
#
#     from springtrack.fixed.kernel cimport FixedKernel, fixed_step
#     cdef void* st = (<FixedKernel>kernel).state
#     with nogil:
#         r = fixed_step(st, t, x, y)      # one event; r >= 0: winning tracker
#
# fixed_step() is springtrack/fixed/csrc/fixed_step.c's fx_step(): integer-only.
from libc.stdint cimport int64_t
from springtrack.backends.stepper cimport Stepper

cdef int fixed_step(void* state, int64_t t, int x, int y) noexcept nogil

cdef class FixedKernel:
    cdef void* state          # fx_state* (fixed/csrc/fixed_step.h), owned
    cdef object model
    cdef object params
    cdef Stepper stepper(self)
