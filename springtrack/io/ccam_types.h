/* CCam ATIS USB words: word types, fields and time base (docs/formats.md#ccam-atis-usb-words).
 *
 * The camera of Valeiras et al. 2015, as read by the public ccam_atis_sepia driver from
 * bulk IN endpoint 0x81: 4-byte words b0..b3, taken here as the little-endian integer
 * w = b0 | b1 << 8 | b2 << 16 | b3 << 24.  The word type is w's top nibble (b3 >> 4):
 *
 *   CD_OFF, CD_ON   change-detection event, polarity = type bit 0
 *   EM_OFF, EM_ON   exposure-measurement event (type bit 1), the same fields
 *   TIME_HIGH       (b3 == 0x80 exactly) the time base, a 24-bit count of 2048 us in w's
 *                   low 24 bits
 *   anything else   never produced by the driver: counted as 'unknown_type'
 *
 * Event fields: x = w bits 16..8 (b1, and b2 bit 0 as x bit 8); row = b0, y = height-1-row
 * (the sensor's origin is its bottom-left corner); t = time base + w bits 27..17 (b3's low
 * nibble: t bits 10..7, b2 bits 7..1: t bits 6..0). */
#ifndef SPRINGTRACK_CCAM_TYPES_H
#define SPRINGTRACK_CCAM_TYPES_H

#include <stdint.h>

enum CCamWordTypes {
    CCAM_CD_OFF    = 0x0,
    CCAM_CD_ON     = 0x1,
    CCAM_EM_OFF    = 0x2,
    CCAM_EM_ON     = 0x3,
    CCAM_TIME_HIGH = 0x8,
};

enum {
    CCAM_WORD_BYTES    = 4,
    CCAM_TYPE_SHIFT    = 28,      /* type = w >> 28 */
    CCAM_EXPOSURE_FLAG = 0x2,     /* type bit: EM_OFF, EM_ON */
    CCAM_POLARITY_FLAG = 0x1,     /* type bit: CD_ON, EM_ON */
    CCAM_TH_BITS       = 24,      /* time-high counter width */
    CCAM_TH_SHIFT      = 11,      /* time-high unit: 2**11 = 2048 us */
    CCAM_T_LOW_SHIFT   = 17,
    CCAM_T_LOW_MASK    = (1 << CCAM_TH_SHIFT) - 1,
    CCAM_X_SHIFT       = 8,
    CCAM_X_MASK        = 0x1FF,
    CCAM_ROW_MASK      = 0xFF,
    CCAM_WIDTH         = 304,     /* the CCam ATIS sensor */
    CCAM_HEIGHT        = 240,
};

/* the word at p (little-endian on every host; one load where the host is little-endian) */
static inline uint32_t ccam_load(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static inline uint32_t ccam_type(uint32_t w) { return w >> CCAM_TYPE_SHIFT; }
static inline int ccam_is_time_high(uint32_t w)
{
    return (w >> (CCAM_TYPE_SHIFT - 4)) == (uint32_t)CCAM_TIME_HIGH << 4;
}
static inline uint32_t ccam_time_high(uint32_t w) { return w & ((1u << CCAM_TH_BITS) - 1); }
static inline uint32_t ccam_x(uint32_t w) { return (w >> CCAM_X_SHIFT) & CCAM_X_MASK; }
static inline uint32_t ccam_row(uint32_t w) { return w & CCAM_ROW_MASK; }
static inline uint32_t ccam_t_low(uint32_t w) { return (w >> CCAM_T_LOW_SHIFT) & CCAM_T_LOW_MASK; }

/* words for the encoder (the inverse of the fields above) */
static inline uint32_t ccam_time_high_word(uint32_t count)
{
    return ((uint32_t)CCAM_TIME_HIGH << CCAM_TYPE_SHIFT) | (count & ((1u << CCAM_TH_BITS) - 1));
}
static inline uint32_t ccam_event_word(uint32_t type, uint32_t t_low, uint32_t x, uint32_t row)
{
    return (type << CCAM_TYPE_SHIFT) | ((t_low & CCAM_T_LOW_MASK) << CCAM_T_LOW_SHIFT)
           | ((x & CCAM_X_MASK) << CCAM_X_SHIFT) | (row & CCAM_ROW_MASK);
}

#endif /* SPRINGTRACK_CCAM_TYPES_H */
