# C view of springtrack.events.EVENT_DTYPE (aligned, 16 bytes per record).
from libc.stdint cimport int64_t, uint16_t, uint8_t

cdef struct Event:
    int64_t t
    uint16_t x
    uint16_t y
    uint8_t p
