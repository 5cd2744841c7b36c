# Prophesee RAW EVT 2.1, C level, for fused nogil loops (layout: docs/formats.md#evt-21).
#
#   from springtrack.io.evt21 cimport Evt21State, evt21_init, evt21_decode_words
#   cdef Evt21State st
#   evt21_init(&st, width, height, legacy)       # 0 x 0: no geometry check
#   n = evt21_decode_words(&st, p, nwords, out, room, &used)   # events written, words used:
#       as many words as out's room surely holds (EVT21_MAX_PER_WORD each); runs of plain
#       CD words go through evt21_block.h
#   st.anomalies[AN_OUT_OF_GEOMETRY], st.info[IN_TIME_HIGH], ...   (base.pxd's enums)
#
# Word types and fields: evt21_types.h (OpenEB's Evt21Raw structs).  The IMX636 sends the
# two 32-bit halves of a word the other way round (OpenEB's Evt21LegacyRaw, format option
# endianness=legacy): evt21_word() swaps them so one decoder reads both.
# Events: one per set bit i of the valid mask, at (x base + i, y), i ascending.
# Time: evt21_time_high() is the EVT 2.0 policy (evt2.pyx): a time high below the previous
# one by more than half its range wrapped (+2**28 units); a smaller drop is the anomaly
# 'time_backwards' and is rebased so the time base never decreases.
from libc.stdint cimport uint8_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy, memset

from springtrack.events cimport Event
from springtrack.io.base cimport (Anomaly, Info, N_ANOMALY, N_INFO, AN_UNKNOWN_TYPE,
                                  AN_OUT_OF_GEOMETRY, AN_TIME_BACKWARDS, IN_TIME_HIGH,
                                  IN_TIME_WRAPS, IN_TRIGGERS, IN_OTHERS, IN_BEFORE_TIME_HIGH,
                                  put_event)

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
                            uint32_t height, int legacy, void* out, size_t* nev)

cdef enum:
    EVT21_UNCHECKED = 0x10000    # width/height 0: no geometry check (every uint16 passes)

cdef struct Evt21State:
    int64_t th               # current time base in us: (epoch + th_last) << EVT21_TH_SHIFT
    int64_t epoch            # time-high units added for wraps and backward-jump rebases
    int64_t th_last          # last raw 28-bit time-high value
    bint have_th             # a time-high word has been seen
    bint legacy              # IMX636 word order
    uint32_t width, height   # events with x >= width or y >= height are dropped
    uint64_t words, events
    uint64_t anomalies[<int>N_ANOMALY]
    uint64_t info[<int>N_INFO]


cdef inline void evt21_init(Evt21State* s, uint32_t width, uint32_t height,
                            bint legacy) noexcept nogil:
    memset(s, 0, sizeof(Evt21State))
    s.width = width if width else EVT21_UNCHECKED
    s.height = height if height else EVT21_UNCHECKED
    s.legacy = legacy


cdef inline uint64_t evt21_word(const Evt21State* s, const uint8_t* p) noexcept nogil:
    """The word at p as a 64-bit value in the standard layout (little-endian host)."""
    cdef uint64_t v
    memcpy(&v, p, EVT21_WORD_BYTES)
    return evt21_swap(v) if s.legacy else v


cdef inline void evt21_time_base(Evt21State* s, int64_t raw) noexcept nogil:
    s.info[<int>IN_TIME_HIGH] += 1
    if s.have_th and raw < s.th_last:
        if s.th_last - raw > (<int64_t>1 << (EVT21_TH_BITS - 1)):     # counter wrapped
            s.epoch += <int64_t>1 << EVT21_TH_BITS
            s.info[<int>IN_TIME_WRAPS] += 1
        else:                                                         # jumped back: rebase
            s.epoch += s.th_last - raw
            s.anomalies[<int>AN_TIME_BACKWARDS] += 1
    s.th_last = raw
    s.have_th = True
    s.th = (s.epoch + raw) << EVT21_TH_SHIFT


cdef inline int evt21_decode_word(Evt21State* s, uint64_t v, Event* out) noexcept nogil:
    """Decode one word (standard layout, from evt21_word); write its events to out (room for
    EVT21_MAX_PER_WORD) and return how many."""
    cdef uint32_t typ = evt21_type(v)
    cdef uint32_t m, x, y, xi
    cdef int64_t t
    cdef int k = 0
    s.words += 1
    if typ == EVT21_EVT_NEG or typ == EVT21_EVT_POS:
        m = evt21_mask(v)
        x = evt21_x(v)
        y = evt21_y(v)
        t = s.th | evt21_t_low(v)
        if y >= s.height:
            s.anomalies[<int>AN_OUT_OF_GEOMETRY] += __builtin_popcount(m)
            return 0
        while m:
            xi = x + <uint32_t>__builtin_ctz(m)
            m &= m - 1
            if xi >= s.width:
                s.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1 + __builtin_popcount(m)
                break                                # the remaining bits lie further right
            put_event(&out[k], t, xi, y, typ)
            k += 1
        if not s.have_th:
            s.info[<int>IN_BEFORE_TIME_HIGH] += k
        s.events += k
    elif typ == EVT21_EVT_TIME_HIGH:
        evt21_time_base(s, evt21_time_high(v))
    elif typ == EVT21_EXT_TRIGGER:
        s.info[<int>IN_TRIGGERS] += 1
    elif typ == EVT21_OTHERS or typ == EVT21_CONTINUED:
        s.info[<int>IN_OTHERS] += 1
    else:
        s.anomalies[<int>AN_UNKNOWN_TYPE] += 1
    return k


cdef inline Py_ssize_t evt21_decode_words(Evt21State* s, const uint8_t* p, Py_ssize_t nwords,
                                          Event* out, Py_ssize_t room,
                                          Py_ssize_t* used) noexcept nogil:
    """Decode words at p into out while words remain (nwords) and out has room for a word's
    worst case (EVT21_MAX_PER_WORD of its room events left); return the number of events
    written and set used[0] to the words decoded.  Once the time base is known, runs of
    plain change-detection words go through evt21_decode_run (same events and counters)."""
    cdef Py_ssize_t i = 0, k = 0, run, lim
    cdef size_t nev
    while i < nwords and room - k >= EVT21_MAX_PER_WORD:
        if s.have_th:
            lim = min(nwords - i, (room - k) // EVT21_MAX_PER_WORD)
            nev = 0
            run = evt21_decode_run(p + EVT21_WORD_BYTES * i, lim, s.th, s.width, s.height,
                                   s.legacy, &out[k], &nev)
            s.words += run
            s.events += nev
            k += nev
            i += run
            if run == lim:
                continue
        k += evt21_decode_word(s, evt21_word(s, p + EVT21_WORD_BYTES * i), &out[k])
        i += 1
    used[0] = i
    return k
