# C-level interface of the float64 tracker kernel (springtrack/kernel/kernel.pyx).
#
# Other Cython modules reach it through kernel.stepper() (springtrack/backends/stepper.pxd), as
# firmware_sim's fused loop does (the fixed-point kernel offers the same), or run the
# per-event step on its state themselves (springtrack/kernel/step.pxd, compiled into the
# caller):
#
#     from springtrack.kernel.kernel cimport Kernel, KState
#     from springtrack.kernel.step cimport kstep
#     cdef KState* s = &kernel.st          # kernel: a springtrack.kernel.kernel.Kernel
#     with nogil:
#         r = kstep(s, t, x, y)            # one event; r >= 0: winning tracker
#
# kstep() translates springtrack.reference.ReferenceTracker.step(); it agrees with it to
# 1e-9 px (libm calls on the hot paths are replaced by csrc/fastmath.h, ~1 ulp).
from springtrack.kernel.state cimport KState
from springtrack.backends.stepper cimport Stepper

cdef class Kernel:
    cdef KState st
    cdef object model            # the springtrack.instances.ModelSet it holds
    cdef object params
    cdef Stepper stepper(self)
