# The time base of every word decoder: one policy for counter wraps and backward jumps
# (docs/formats.md#time-base), used by the CCam, EVT 2.0, EVT 3.0 and DAT decoders and,
# through the CCam decoder, by firmware_sim's fused loop.
#
#   from springtrack.io.timebase cimport TimeBase, timebase_init, timebase_update
#   cdef TimeBase tb
#   timebase_init(&tb)
#   t_base = timebase_update(&tb, raw, bits) << shift     # at every time-high word
#
# A format sends its coarse time as a free-running counter of `bits` bits counting units of
# 2**shift us (CCam time-high: 24 bits of 2048 us; EVT 2.0 TIME_HIGH: 28 bits of 64 us;
# EVT 3.0 TIME_HIGH: 12 bits of 4096 us; DAT: the 32-bit timestamp itself, 1 us).
# timebase_update() turns each raw value into a count that never decreases:
#   * a value below the last one by more than half the range (2**(bits-1)) is a wrap of
#     the counter: one range (2**bits) is added, counted in `wraps`;
#   * a smaller step back is a backward jump (a camera that restarted its counter, a
#     corrupt word): counted in `backwards` and rebased, the count going on one unit after
#     the last one as if the counter had advanced by one; later values follow from there.
# So the time base never goes back, and an event stamped after a backward jump is later than
# every event stamped before it.  Before the first value the count is 0 (timebase_known()
# is False: decoders count such events as 'before_time_high').
from libc.stdint cimport int64_t, uint64_t

cdef struct TimeBase:
    int64_t epoch        # counter units added to the raw value (wraps and rebases)
    int64_t last         # last raw value, -1 before the first
    uint64_t wraps       # wrap-arounds of the counter
    uint64_t backwards   # backward jumps, rebased

cdef inline void timebase_init(TimeBase* tb) noexcept nogil:
    tb.epoch = 0
    tb.last = -1
    tb.wraps = 0
    tb.backwards = 0

cdef inline bint timebase_known(const TimeBase* tb) noexcept nogil:
    """True once a counter value has been seen."""
    return tb.last >= 0

cdef inline int64_t timebase_count(const TimeBase* tb) noexcept nogil:
    """The current count (counter units since the stream's time 0); 0 before the first."""
    return tb.epoch + tb.last if tb.last >= 0 else 0

cdef inline int64_t timebase_update(TimeBase* tb, int64_t raw, int bits) noexcept nogil:
    """Take the counter's raw value (0 <= raw < 2**bits); return the new count (above)."""
    cdef int64_t last = tb.last
    if raw < last:
        if last - raw > (<int64_t>1 << (bits - 1)):
            tb.epoch += <int64_t>1 << bits
            tb.wraps += 1
        else:
            tb.epoch += last - raw + 1
            tb.backwards += 1
    tb.last = raw
    return tb.epoch + raw
