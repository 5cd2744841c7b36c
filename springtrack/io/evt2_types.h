/* Prophesee RAW EVT 2.0 words: word types and fields (docs/formats.md#prophesee-raw-evt-20),
 * named as in OpenEB's evt2_event_types.h.
 *
 * Little-endian 32-bit words, the type in bits 31..28:
 *   CD_OFF, CD_ON    change-detection event (polarity = type): t low 6 bits in 27..22,
 *                    x in 21..11, y in 10..0
 *   EVT_TIME_HIGH    the time base: t >> 6 in 27..0 (a 28-bit count of 64 us)
 *   EXT_TRIGGER      external trigger (counted)
 *   OTHERS, CONTINUED  extensions and their payload words (counted, not decoded)
 *   anything else    'unknown_type' */
#ifndef SPRINGTRACK_EVT2_TYPES_H
#define SPRINGTRACK_EVT2_TYPES_H

#include <stdint.h>

enum Evt2EventTypes {
    EVT2_CD_OFF        = 0x0,
    EVT2_CD_ON         = 0x1,
    EVT2_EVT_TIME_HIGH = 0x8,
    EVT2_EXT_TRIGGER   = 0xA,
    EVT2_OTHERS        = 0xE,
    EVT2_CONTINUED     = 0xF,
};

enum {
    EVT2_WORD_BYTES  = 4,
    EVT2_TYPE_SHIFT  = 28,
    EVT2_TH_BITS     = 28,        /* EVT_TIME_HIGH counter width */
    EVT2_TH_SHIFT    = 6,         /* its unit: 2**6 = 64 us, the CD words' t low bits */
    EVT2_T_LOW_SHIFT = 22,
    EVT2_X_SHIFT     = 11,
    EVT2_COORD_MASK  = 0x7FF,     /* x and y: 11 bits, up to 2048 x 2048 */
};

static inline uint32_t evt2_type(uint32_t v) { return v >> EVT2_TYPE_SHIFT; }
static inline uint32_t evt2_x(uint32_t v) { return (v >> EVT2_X_SHIFT) & EVT2_COORD_MASK; }
static inline uint32_t evt2_y(uint32_t v) { return v & EVT2_COORD_MASK; }
static inline uint32_t evt2_t_low(uint32_t v)
{
    return (v >> EVT2_T_LOW_SHIFT) & ((1u << EVT2_TH_SHIFT) - 1);
}
static inline uint32_t evt2_time_high(uint32_t v) { return v & ((1u << EVT2_TH_BITS) - 1); }

/* words for the encoder (the inverse of the fields above) */
static inline uint32_t evt2_time_high_word(uint32_t count)
{
    return ((uint32_t)EVT2_EVT_TIME_HIGH << EVT2_TYPE_SHIFT) | (count & ((1u << EVT2_TH_BITS) - 1));
}
static inline uint32_t evt2_cd_word(uint32_t pol, uint32_t t_low, uint32_t x, uint32_t y)
{
    return ((pol ? (uint32_t)EVT2_CD_ON : (uint32_t)EVT2_CD_OFF) << EVT2_TYPE_SHIFT)
           | ((t_low & ((1u << EVT2_TH_SHIFT) - 1)) << EVT2_T_LOW_SHIFT)
           | ((x & EVT2_COORD_MASK) << EVT2_X_SHIFT) | (y & EVT2_COORD_MASK);
}

#endif /* SPRINGTRACK_EVT2_TYPES_H */
