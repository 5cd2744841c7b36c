# C view of springtrack.track.TRACK_DTYPE (aligned, 72 bytes): one tracker's state in a
# sample row.  springtrack.backends.samples checks at import that the two agree field by field.
from libc.stdint cimport uint8_t

cdef struct TrackRow:
    double x, y               # position, px (eq. 3)
    double sxx, sxy, syy      # covariance, px^2 (eq. 4)
    double activity           # A, eq. (6), decayed to the sample time
    double vx, vy             # velocity, px/s (eq. M7)
    uint8_t active            # A > activity threshold (0/1)
    uint8_t sensitive         # takes part in the energy criteria, eq. (21) (0/1)
    uint8_t state             # the model instance's state (springtrack.instances.InstanceState)
