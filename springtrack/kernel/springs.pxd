# The float64 kernel's springs and energy criteria, eqs. (7)-(22), and its state guard
# (springtrack/kernel/springs.pyx), per model instance.
#
# An extension module of its own: the per-event step (kernel/step.pxd) calls kclocks when
# an instance's spring clock is due (once per spring_period of its events), through the
# function pointer Cython imports for a cdef function of another module (one indirect
# call per spring update).
from springtrack.kernel.state cimport KState

# instance g's spring update: if it is tracking, eqs. (10)-(20) move its trackers, eqs.
# (13), (21)-(22) then decide which are sensitive and pull the others back; the state
# guard then resets it to its model's state if one of its means left the position box
cdef void kspring_update(KState* s, int g) noexcept nogil
# every instance's spring update, in order (their clocks left as they are)
cdef void ksprings(KState* s) noexcept nogil
# the spring updates due on the instances' clocks (KState.due) after a valid event that
# instance `owner` took (only its clock moved), or no tracker took (owner -1: every
# clock moved), in instance order, each clock restarted; next_due set again
cdef void kclocks(KState* s, int owner) noexcept nogil
# the clocks of a new spring_period: each instance's count kept
cdef void set_period(KState* s, int period) noexcept nogil
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
