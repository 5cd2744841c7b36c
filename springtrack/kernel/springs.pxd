# The float64 kernel's springs and energy criteria, eqs. (7)-(22), and its state guard
# (springtrack/kernel/springs.pyx), per model instance.
#
# An extension module of its own: the per-event step (kernel/step.pxd) calls ksprings once per
# spring_period events, through the function pointer Cython imports for a cdef function
# of another module (one indirect call per spring update).
from springtrack.kernel.state cimport KState

# one spring update: for every tracking instance, eqs. (10)-(20) move its trackers,
# eqs. (13), (21)-(22) then decide which are sensitive and pull the others back; the state
# guard then resets an instance to its model's state if one of its means left the
# position box
cdef void ksprings(KState* s) noexcept nogil
# the springs' state derived from the loaded models (connections, masses, means) of every
# instance, all of them sensitive: per-connection coefficients, eq. (14)'s frames, eq.
# (21)'s masks, eq. (22)'s sums and frames
cdef void init_springs(KState* s) noexcept nogil
# the same for instance g alone, its state and sensitivity kept (a model placed or moved)
cdef void init_instance(KState* s, int g) noexcept nogil
# instance g's trackers at their model's rest state (means, covariances, activities 0),
# covariances clamped and inverted, re-indexed (a reset, a placing)
cdef void rest_trackers(KState* s, int g) noexcept nogil
# the event assignment's words (KState.sensitive) from the instances' isens
cdef void compose_sensitive(KState* s) noexcept nogil
