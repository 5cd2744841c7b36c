# Prophesee RAW EVT 2.0 words, C level: the decoder's state machine, for Evt2Decoder
# (evt2.pyx) and for loops that decode words themselves.
#
#   from springtrack.io.evt2 cimport Evt2State, evt2_init, evt2_decode_words
#   cdef Evt2State st
#   cdef DecodeCounts n                            # springtrack.io.base: words, anomalies, info
#   evt2_init(&st, width, height)                  # 0: geometry unknown, no check
#   used = evt2_decode_words(&st, &n, words, nw, out, &k)   # at most one event per word
#
# Word types and fields: evt2_types.h; EVT_TIME_HIGH through the time base of every
# decoder (timebase.pxd).
from libc.stdint cimport uint8_t, uint32_t, int64_t, uint64_t
from libc.string cimport memcpy

from springtrack.events cimport Event
from springtrack.io.base cimport (Decoder, DecodeCounts, count_time, geometry_bound,
                                  put_event, AN_OUT_OF_GEOMETRY, AN_UNKNOWN_TYPE,
                                  IN_TIME_HIGH, IN_TRIGGERS, IN_OTHERS, IN_BEFORE_TIME_HIGH)
from springtrack.io.timebase cimport (TimeBase, timebase_init, timebase_known,
                                      timebase_count, timebase_update)

cdef extern from "springtrack/io/evt2_types.h" nogil:
    enum Evt2EventTypes:
        EVT2_CD_OFF
        EVT2_CD_ON
        EVT2_EVT_TIME_HIGH
        EVT2_EXT_TRIGGER
        EVT2_OTHERS
        EVT2_CONTINUED
    enum:
        EVT2_TH_BITS
        EVT2_TH_SHIFT
        EVT2_WORD_BYTES
    uint32_t evt2_type(uint32_t v)
    uint32_t evt2_x(uint32_t v)
    uint32_t evt2_y(uint32_t v)
    uint32_t evt2_t_low(uint32_t v)
    uint32_t evt2_time_high(uint32_t v)
    uint32_t evt2_time_high_word(uint32_t count)
    uint32_t evt2_cd_word(uint32_t pol, uint32_t t_low, uint32_t x, uint32_t y)

cdef extern from "springtrack/io/evt2_block.h" nogil:
    enum:
        EVT2_BLOCK
    int evt2_decode_block(const uint8_t* p, int64_t th, uint32_t width, uint32_t height,
                          void* out)

cdef struct Evt2State:
    TimeBase tb                # the EVT_TIME_HIGH counter
    uint32_t width, height     # coordinates must stay below (geometry_bound)

cdef inline void evt2_init(Evt2State* s, int width, int height) noexcept nogil:
    timebase_init(&s.tb)
    s.width = geometry_bound(width)
    s.height = geometry_bound(height)

cdef inline Py_ssize_t evt2_decode_words(Evt2State* s, DecodeCounts* n, const uint8_t* p,
                                         Py_ssize_t nw, Event* out, Py_ssize_t* nout) noexcept nogil:
    """Decode the nw words at p into out from index nout[0] (room for nw events needed),
    advance nout[0]; count in n; return the words consumed (nw)."""
    cdef Py_ssize_t i = 0, k = nout[0]
    cdef uint32_t v, typ, x, y
    cdef uint32_t W = s.width, H = s.height
    cdef TimeBase tb = s.tb        # in a local while the loop runs
    cdef int64_t th = timebase_count(&tb) << EVT2_TH_SHIFT
    # events from out[k0] on have no time base (counted at the first time-high word);
    # k0 = -1 once the time base is known
    cdef Py_ssize_t k0 = -1 if timebase_known(&tb) else k
    cdef Py_ssize_t next_block = 0     # no block before this word
    cdef int f
    while i < nw:
        # blocks of plain CD words at once (evt2_block.h), up to the first other word (a
        # time high, a trigger, an event outside), which goes word by word; after a block
        # that stopped at its first word, the next EVT2_BLOCK words go word by word (runs
        # of other words never cost a block each).  Blocks need the time base and never
        # write past out[nout[0] + nw): k <= nout[0] + i
        if i >= next_block and i + EVT2_BLOCK <= nw and k0 < 0:
            f = evt2_decode_block(p + EVT2_WORD_BYTES * i, th, W, H, &out[k])
            k += f
            i += f
            if f == EVT2_BLOCK:
                continue
            if f == 0:
                next_block = i + EVT2_BLOCK
        memcpy(&v, p + EVT2_WORD_BYTES * i, EVT2_WORD_BYTES)   # little-endian host assumed
        i += 1
        typ = evt2_type(v)
        if typ == EVT2_CD_OFF or typ == EVT2_CD_ON:
            x = evt2_x(v)
            y = evt2_y(v)
            if x >= W or y >= H:
                n.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                continue
            put_event(&out[k], th | evt2_t_low(v), x, y, typ)
            k += 1
        elif typ == EVT2_EVT_TIME_HIGH:
            n.info[<int>IN_TIME_HIGH] += 1
            th = timebase_update(&tb, evt2_time_high(v), EVT2_TH_BITS) << EVT2_TH_SHIFT
            if k0 >= 0:
                n.info[<int>IN_BEFORE_TIME_HIGH] += k - k0
                k0 = -1
        elif typ == EVT2_EXT_TRIGGER:
            n.info[<int>IN_TRIGGERS] += 1
        elif typ == EVT2_OTHERS or typ == EVT2_CONTINUED:
            n.info[<int>IN_OTHERS] += 1
        else:
            n.anomalies[<int>AN_UNKNOWN_TYPE] += 1
    s.tb = tb
    count_time(n, &tb)
    if k0 >= 0:
        n.info[<int>IN_BEFORE_TIME_HIGH] += k - k0
    n.words += i
    nout[0] = k
    return i


cdef class Evt2Decoder(Decoder):
    cdef Evt2State st
