# The streaming-decoder base class shared by every format module (see base.pyx).
from libc.stdint cimport uint8_t, uint32_t, uint64_t, int64_t
from springtrack.events cimport Event
from springtrack.io.timebase cimport TimeBase

# Recoverable problems, counted per kind (names in base.ANOMALY_NAMES, same order).
cdef enum Anomaly:
    AN_UNKNOWN_TYPE       # word type / code the format does not define: word skipped
    AN_OUT_OF_GEOMETRY    # event outside width x height: dropped
    AN_TIME_BACKWARDS     # time base went back (not a wrap): rebased (timebase.pxd)
    AN_ORPHAN             # event or vector before the address/base word it needs: dropped
    AN_TRUNCATED          # stream ended inside a word/event (finish() with bytes pending)
    N_ANOMALY

# Informational counters (legitimate content), names in base.INFO_NAMES.
cdef enum Info:
    IN_TIME_HIGH          # time-high words
    IN_TIME_WRAPS         # legitimate wrap-arounds of the time-high counter
    IN_TRIGGERS           # external-trigger words
    IN_OTHERS             # OTHERS / CONTINUED words (not decoded)
    IN_EXPOSURE           # exposure-measurement events (CCam, ES ATIS), kept apart
    IN_OVERFLOW           # Event Stream overflow bytes
    IN_RESET              # Event Stream reset bytes
    IN_BEFORE_TIME_HIGH   # events decoded before the first time-high word
    IN_TIME_LOW_BACK      # EVT 3.0 TIME_LOW smaller than the previous one (sensor jitter)
    N_INFO

cdef enum:
    MAX_WORD = 8          # bytes held between calls: the longest word
    ANY_COORD = 0x10000   # coordinate bound when the geometry is unknown (uint16 x, y)

# What a decoder counts: a Decoder's own counters, or those of a loop that runs a format's
# state machine itself (firmware_sim's fused loop).
cdef struct DecodeCounts:
    uint64_t words                 # words consumed (bytes for Event Stream)
    uint64_t anomalies[N_ANOMALY]  # by Anomaly
    uint64_t info[N_INFO]          # by Info

cdef inline void count_time(DecodeCounts* n, const TimeBase* tb) noexcept nogil:
    """The time base's wraps and backward jumps into the counters."""
    n.info[<int>IN_TIME_WRAPS] = tb.wraps
    n.anomalies[<int>AN_TIME_BACKWARDS] = tb.backwards

cdef inline uint32_t geometry_bound(int size) noexcept nogil:
    """Coordinates must stay below this: the sensor size, or any uint16 when unknown (0)."""
    return <uint32_t>size if size > 0 else ANY_COORD

cdef class Decoder:
    cdef readonly str format
    cdef readonly int word_size        # bytes per word (1 for the Event Stream byte machine)
    cdef int max_per_word              # most events one word can complete
    cdef int bound_den                 # first output guess: bytes / bound_den events
    cdef readonly int width, height    # 0 = unknown: no geometry check
    cdef readonly bint keep_exposure
    cdef uint8_t carry[MAX_WORD]
    cdef int ncarry
    cdef readonly uint64_t events_out
    cdef DecodeCounts n                # words, anomalies, info
    cdef object _exposure_parts
    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil
    cdef int _pending_state(self) noexcept
    cdef void _reset_state(self) noexcept
    cdef object _decode(self, buffer, object out, Py_ssize_t* nout_p)
    cdef object _feed(self, const uint8_t* p, Py_ssize_t n, object out, Py_ssize_t* nout,
                      object side, Py_ssize_t* nside)

from libc.string cimport memcpy as _memcpy

cdef inline void put_event(Event* o, int64_t t, uint64_t x, uint64_t y, uint64_t p) noexcept nogil:
    """Store one event as two 8-byte writes (t, then x|y|p with zeroed padding).

    memcpy keeps it aliasing-safe; compilers emit a single 8-byte store for it.
    """
    cdef uint64_t rest = x | (y << 16) | (p << 32)
    o.t = t
    _memcpy((<char*>o) + 8, &rest, 8)
