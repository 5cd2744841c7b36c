# Prophesee RAW EVT 2.1 words, C level: the decoder's state machine, for Evt21Decoder
# (evt21.pyx) and for loops that decode words themselves (a fused firmware loop).
#
#   from springtrack.io.evt21 cimport Evt21State, evt21_init, evt21_decode_words
#   cdef Evt21State st
#   cdef DecodeCounts n                            # springtrack.io.base: words, anomalies, info
#   evt21_init(&st, width, height, legacy)         # 0: geometry unknown, no check
#   used = evt21_decode_words(&st, &n, words, nw, out, cap, &k)
#       # decodes words while out[k:cap] has room for them (a plain change-detection
#       # word: its events; another: EVT21_MAX_PER_WORD), advances k, returns the words
#       # consumed
#
# Word types and fields: evt21_types.h (OpenEB's Evt21Raw structs); EVT_TIME_HIGH through
# the time base of every decoder (timebase.pxd).  The IMX636 sends the two 32-bit halves of
# a word the other way round (OpenEB's Evt21LegacyRaw, format option endianness=legacy):
# evt21_word() swaps them so one decoder reads both.  Events: one per set bit i of the
# valid mask, at (x base + i, y), i ascending; runs of plain change-detection words go
# through evt21_block.h.
from libc.stdint cimport uint8_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy, memset

from springtrack.events cimport Event
from springtrack.io.base cimport (Decoder, DecodeCounts, count_time, geometry_bound,
                                  put_event, AN_OUT_OF_GEOMETRY, AN_UNKNOWN_TYPE,
                                  IN_TIME_HIGH, IN_TRIGGERS, IN_OTHERS, IN_BEFORE_TIME_HIGH)
from springtrack.io.timebase cimport (TimeBase, timebase_init, timebase_known,
                                      timebase_count, timebase_update)

cdef extern from *:
    int __builtin_ctz(unsigned int) nogil
    int __builtin_popcount(unsigned int) nogil

cdef extern from "springtrack/io/evt21_types.h" nogil:
    enum Evt21EventTypes:
        EVT21_EVT_NEG
        EVT21_EVT_POS
        EVT21_EVT_TIME_HIGH
        EVT21_EXT_TRIGGER
        EVT21_OTHERS
        EVT21_CONTINUED
    enum:
        EVT21_WORD_BYTES
        EVT21_MAX_PER_WORD
        EVT21_TH_BITS
        EVT21_TH_SHIFT
        EVT21_GROUP_BITS
    uint64_t evt21_swap(uint64_t v)
    uint32_t evt21_type(uint64_t v)
    uint32_t evt21_mask(uint64_t v)
    uint32_t evt21_x(uint64_t v)
    uint32_t evt21_y(uint64_t v)
    uint32_t evt21_t_low(uint64_t v)
    uint32_t evt21_time_high(uint64_t v)
    uint64_t evt21_time_high_word(uint64_t count)
    uint64_t evt21_cd_word(uint32_t pol, uint32_t t_low, uint32_t x, uint32_t y, uint32_t mask)

cdef extern from "springtrack/io/evt21_block.h" nogil:
    size_t evt21_decode_run(const uint8_t* p, size_t n, int64_t th, uint32_t width,
                            uint32_t height, int legacy, void* out, size_t cap, size_t* nev)

cdef struct Evt21State:
    TimeBase tb              # the EVT_TIME_HIGH counter
    int64_t th               # the time base in us: timebase_count(&tb) << EVT21_TH_SHIFT
    uint32_t width, height   # coordinates must stay below (geometry_bound)
    bint legacy              # IMX636 word order


cdef inline void evt21_init(Evt21State* s, int width, int height, bint legacy) noexcept nogil:
    timebase_init(&s.tb)
    s.th = 0
    s.width = geometry_bound(width)
    s.height = geometry_bound(height)
    s.legacy = legacy


cdef inline uint64_t evt21_word(const Evt21State* s, const uint8_t* p) noexcept nogil:
    """The word at p as a 64-bit value in the standard layout (little-endian host)."""
    cdef uint64_t v
    memcpy(&v, p, EVT21_WORD_BYTES)
    return evt21_swap(v) if s.legacy else v


cdef inline int evt21_decode_word(Evt21State* s, DecodeCounts* n, uint64_t v,
                                  Event* out) noexcept nogil:
    """Decode one word (standard layout, from evt21_word); write its events to out (room for
    EVT21_MAX_PER_WORD), count in n, and return how many events."""
    cdef uint32_t typ = evt21_type(v)
    cdef uint32_t m, x, y, xi
    cdef int64_t t
    cdef int k = 0
    n.words += 1
    if typ == EVT21_EVT_NEG or typ == EVT21_EVT_POS:
        m = evt21_mask(v)
        x = evt21_x(v)
        y = evt21_y(v)
        t = s.th | evt21_t_low(v)
        if y >= s.height:
            n.anomalies[<int>AN_OUT_OF_GEOMETRY] += __builtin_popcount(m)
            return 0
        while m:
            xi = x + <uint32_t>__builtin_ctz(m)
            m &= m - 1
            if xi >= s.width:
                n.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1 + __builtin_popcount(m)
                break                                # the remaining bits lie further right
            put_event(&out[k], t, xi, y, typ)
            k += 1
        if not timebase_known(&s.tb):
            n.info[<int>IN_BEFORE_TIME_HIGH] += k
    elif typ == EVT21_EVT_TIME_HIGH:
        n.info[<int>IN_TIME_HIGH] += 1
        s.th = timebase_update(&s.tb, evt21_time_high(v), EVT21_TH_BITS) << EVT21_TH_SHIFT
        count_time(n, &s.tb)
    elif typ == EVT21_EXT_TRIGGER:
        n.info[<int>IN_TRIGGERS] += 1
    elif typ == EVT21_OTHERS or typ == EVT21_CONTINUED:
        n.info[<int>IN_OTHERS] += 1
    else:
        n.anomalies[<int>AN_UNKNOWN_TYPE] += 1
    return k


cdef inline Py_ssize_t evt21_decode_words(Evt21State* s, DecodeCounts* n, const uint8_t* p,
                                          Py_ssize_t nw, Event* out, Py_ssize_t cap,
                                          Py_ssize_t* nout) noexcept nogil:
    """Decode the words at p into out from index nout[0] while words remain (nw) and
    out[:cap] has room for them: runs of plain change-detection words (once the time base
    is known: evt21_decode_run, same events and counters) while their own events fit, any
    other word only with room for a word's worst case (EVT21_MAX_PER_WORD events); advance
    nout[0], count in n, return the words consumed."""
    cdef Py_ssize_t i = 0, k = nout[0], run
    cdef size_t nev
    while i < nw:
        if timebase_known(&s.tb):
            nev = 0
            run = evt21_decode_run(p + EVT21_WORD_BYTES * i, nw - i, s.th, s.width, s.height,
                                   s.legacy, &out[k], cap - k, &nev)
            n.words += run
            k += nev
            i += run
            if i == nw:
                break
        if cap - k < EVT21_MAX_PER_WORD:
            break
        k += evt21_decode_word(s, n, evt21_word(s, p + EVT21_WORD_BYTES * i), &out[k])
        i += 1
    nout[0] = k
    return i


cdef class Evt21Decoder(Decoder):
    cdef Evt21State st
