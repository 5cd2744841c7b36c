# The float64 kernel's springs and energy criteria, eqs. (7)-(22), and its state guard
# (springtrack/_ksprings.pyx).
#
# An extension module of its own: the per-event step (_kstep.pxd) calls ksprings once per
# spring_period events, through the function pointer Cython imports for a cdef function
# of another module (one indirect call per spring update).
from springtrack._kstate cimport KState

# one spring update: eqs. (10)-(20) move the trackers, eqs. (13), (21)-(22) then decide
# which are sensitive and pull the others back; the state guard then resets the state to
# the model's if a mean left the position box
cdef void ksprings(KState* s) noexcept nogil
# the springs' state derived from a loaded model (connections, masses, means): per-
# connection coefficients, eq. (14)'s frame, eq. (21)'s masks, eq. (22)'s sums and frame
cdef void init_springs(KState* s) noexcept nogil
