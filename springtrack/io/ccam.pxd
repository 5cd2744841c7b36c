# CCam ATIS USB words (the camera of Valeiras et al. 2015), C level, for fused nogil loops.
#
#   from springtrack.io.ccam cimport CCamState, ccam_init, ccam_decode_word, CCAM_CD
#   cdef CCamState st
#   ccam_init(&st)
#   kind = ccam_decode_word(&st, word_ptr, &t, &x, &y, &p)   # per 4-byte word b0..b3
#   if ccam_decode_block(&st, words, out): ...    # CCAM_BLOCK words at once, if all plain
#                                                  # events (ccam_block.h), counted as above
#
# Layout (public ccam_atis_sepia driver, bulk IN endpoint 0x81):
#   b3 == 0x80          time-high word: t_offset = (b0 | b1<<8 | b2<<16) * 0x800 us
#   otherwise (event)   x = ((b2 & 1) << 8) | b1, y = 239 - b0,
#                       t = t_offset + (((b3 & 0x0F) << 7) | (b2 >> 1)),
#                       p = (b3 >> 4) & 1, exposure flag = (b3 >> 5) & 1
# Checks: b3 bits 7..6 set (other than 0x80) -> 'unknown', x >= 304 or b0 > 239 ->
# 'out_of_geometry'; both return CCAM_NONE.  A time-high value below the previous one by
# more than 2**23 is a wrap of the 24-bit counter (+2**24 units); a smaller step back is
# counted in 'backwards' and rebased so the time base never decreases.
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
from libc.string cimport memset

from springtrack.events cimport Event

cdef enum:
    CCAM_NONE = 0        # time-high word, or a word dropped and counted
    CCAM_CD = 1          # change-detection event: feeds the tracker
    CCAM_EXPOSURE = 2    # exposure-measurement event: kept apart (gray levels)
    CCAM_WIDTH = 304
    CCAM_HEIGHT = 240

cdef struct CCamState:
    int64_t t_offset     # current time base, us = (epoch + last_th) * 0x800
    int64_t epoch        # time-high units added for wraps and backward-jump rebases
    int64_t last_th      # last raw 24-bit time-high value, -1 before the first
    int64_t last_t       # timestamp of the last event returned
    uint64_t words, time_high, cd, exposure
    uint64_t wraps, backwards, out_of_geometry, unknown, before_time_high

cdef extern from "springtrack/io/ccam_block.h" nogil:
    enum:
        CCAM_BLOCK
    int ccam_decode_plain(const uint8_t* p, int n, int64_t t_offset, void* out)

cdef inline void ccam_init(CCamState* s) noexcept nogil:
    memset(s, 0, sizeof(CCamState))
    s.last_th = -1

cdef inline int ccam_decode_word(CCamState* s, const uint8_t* w, int64_t* t, uint16_t* x,
                                 uint16_t* y, uint8_t* p) noexcept nogil:
    cdef uint8_t b3 = w[3]
    cdef int64_t th
    cdef uint32_t xx
    s.words += 1
    if b3 == 0x80:
        th = <int64_t>w[0] | (<int64_t>w[1] << 8) | (<int64_t>w[2] << 16)
        s.time_high += 1
        if th < s.last_th:
            if s.last_th - th > (1 << 23):
                s.epoch += 1 << 24
                s.wraps += 1
            else:
                s.epoch += s.last_th - th
                s.backwards += 1
        s.last_th = th
        s.t_offset = (s.epoch + th) * 0x800
        return CCAM_NONE
    if b3 & 0xC0:
        s.unknown += 1
        return CCAM_NONE
    xx = ((<uint32_t>w[2] & 1) << 8) | w[1]
    if xx >= CCAM_WIDTH or w[0] >= CCAM_HEIGHT:
        s.out_of_geometry += 1
        return CCAM_NONE
    if s.last_th < 0:
        s.before_time_high += 1
    t[0] = s.t_offset + ((<int64_t>(b3 & 0x0F) << 7) | (w[2] >> 1))
    x[0] = <uint16_t>xx
    y[0] = <uint16_t>(CCAM_HEIGHT - 1 - w[0])
    p[0] = (b3 >> 4) & 1
    s.last_t = t[0]
    if b3 & 0x20:
        s.exposure += 1
        return CCAM_EXPOSURE
    s.cd += 1
    return CCAM_CD


cdef inline bint ccam_decode_block(CCamState* s, const uint8_t* w, Event* out) noexcept nogil:
    """CCAM_BLOCK words at once when the time base is known and every word is a plain
    change-detection event (ccam_block.h): out[0..CCAM_BLOCK) holds them and s counts them
    as ccam_decode_word would.  Else False, s untouched, out garbage: decode word by word."""
    if s.last_th < 0 or not ccam_decode_plain(w, CCAM_BLOCK, s.t_offset, out):
        return False
    s.words += CCAM_BLOCK
    s.cd += CCAM_BLOCK
    s.last_t = out[CCAM_BLOCK - 1].t
    return True
