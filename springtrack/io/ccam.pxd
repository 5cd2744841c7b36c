# CCam ATIS USB words (the camera of Valeiras et al. 2015), C level, for fused nogil loops.
#
#   from springtrack.io.ccam cimport CCamState, ccam_init, ccam_decode_word, CCAM_CD
#   cdef CCamState st
#   cdef DecodeCounts n                            # springtrack.io.base: words, anomalies, info
#   ccam_init(&st)
#   kind = ccam_decode_word(&st, &n, word_ptr, &t, &x, &y, &p)  # per 4-byte word b0..b3
#   if ccam_decode_block(&st, &n, words, out): ...  # CCAM_BLOCK words at once, if all plain
#                                                    # events (ccam_block.h), counted as above
#
# Word types, fields and layout: ccam_types.h.  Time-high words go through the time base
# of every decoder (timebase.pxd: wraps of the 24-bit counter, backward jumps rebased).
# Checks: a word of an undefined type -> 'unknown'; x >= width or row >= height ->
# 'out_of_geometry'; both return CCAM_NONE.
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t

from springtrack.events cimport Event
from springtrack.io.base cimport (DecodeCounts, count_time, AN_UNKNOWN_TYPE,
                                  AN_OUT_OF_GEOMETRY, IN_TIME_HIGH, IN_EXPOSURE,
                                  IN_BEFORE_TIME_HIGH)
from springtrack.io.timebase cimport (TimeBase, timebase_init, timebase_known,
                                      timebase_update)

cdef extern from "springtrack/io/ccam_types.h" nogil:
    enum CCamWordTypes:
        CCAM_CD_OFF
        CCAM_CD_ON
        CCAM_EM_OFF
        CCAM_EM_ON
        CCAM_TIME_HIGH
    enum:
        CCAM_WORD_BYTES
        CCAM_EXPOSURE_FLAG
        CCAM_POLARITY_FLAG
        CCAM_TH_BITS
        CCAM_TH_SHIFT
        CCAM_WIDTH
        CCAM_HEIGHT
    uint32_t ccam_load(const uint8_t* p)
    uint32_t ccam_type(uint32_t w)
    bint ccam_is_time_high(uint32_t w)
    uint32_t ccam_time_high(uint32_t w)
    uint32_t ccam_x(uint32_t w)
    uint32_t ccam_row(uint32_t w)
    uint32_t ccam_t_low(uint32_t w)
    uint32_t ccam_time_high_word(uint32_t count)
    uint32_t ccam_event_word(uint32_t type, uint32_t t_low, uint32_t x, uint32_t row)

cdef extern from "springtrack/io/ccam_block.h" nogil:
    enum:
        CCAM_BLOCK
    int ccam_decode_plain(const uint8_t* p, int n, int64_t t_offset, uint32_t width,
                          uint32_t height, void* out)

cdef enum CCamKind:      # what ccam_decode_word made of a word
    CCAM_NONE = 0        # a word dropped and counted
    CCAM_CD = 1          # change-detection event: feeds the tracker
    CCAM_EXPOSURE = 2    # exposure-measurement event: kept apart (gray levels)
    CCAM_TIME_BASE = 3   # time-high word: the time base moved

cdef struct CCamState:
    TimeBase tb          # the time-high counter (timebase.pxd)
    int64_t t_offset     # current time base, us: count << CCAM_TH_SHIFT
    uint32_t width, height

cdef inline void ccam_init(CCamState* s) noexcept nogil:
    timebase_init(&s.tb)
    s.t_offset = 0
    s.width = CCAM_WIDTH
    s.height = CCAM_HEIGHT

cdef inline int ccam_decode_word(CCamState* s, DecodeCounts* n, const uint8_t* p, int64_t* t,
                                 uint16_t* x, uint16_t* y, uint8_t* pol) noexcept nogil:
    """Decode the word at p; return its CCamKind (t, x, y, pol set for CCAM_CD and
    CCAM_EXPOSURE) and count it in n."""
    cdef uint32_t w = ccam_load(p), typ = ccam_type(w), xx, row
    n.words += 1
    if ccam_is_time_high(w):
        n.info[<int>IN_TIME_HIGH] += 1
        s.t_offset = timebase_update(&s.tb, ccam_time_high(w), CCAM_TH_BITS) << CCAM_TH_SHIFT
        count_time(n, &s.tb)
        return CCAM_TIME_BASE
    if typ > CCAM_EM_ON:
        n.anomalies[<int>AN_UNKNOWN_TYPE] += 1
        return CCAM_NONE
    xx = ccam_x(w)
    row = ccam_row(w)
    if xx >= s.width or row >= s.height:
        n.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
        return CCAM_NONE
    if not timebase_known(&s.tb):
        n.info[<int>IN_BEFORE_TIME_HIGH] += 1
    t[0] = s.t_offset + ccam_t_low(w)
    x[0] = <uint16_t>xx
    y[0] = <uint16_t>(s.height - 1 - row)
    pol[0] = typ & CCAM_POLARITY_FLAG
    if typ & CCAM_EXPOSURE_FLAG:
        n.info[<int>IN_EXPOSURE] += 1
        return CCAM_EXPOSURE
    return CCAM_CD


cdef inline bint ccam_decode_block(CCamState* s, DecodeCounts* n, const uint8_t* w,
                                   Event* out) noexcept nogil:
    """CCAM_BLOCK words at once when the time base is known and every word is a plain
    change-detection event (ccam_block.h): out[0..CCAM_BLOCK) holds them and n counts them
    as ccam_decode_word would.  Else False, s and n untouched, out garbage: decode word
    by word."""
    if not timebase_known(&s.tb) or not ccam_decode_plain(w, CCAM_BLOCK, s.t_offset, s.width,
                                                          s.height, out):
        return False
    n.words += CCAM_BLOCK
    return True
