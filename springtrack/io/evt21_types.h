/* Prophesee RAW EVT 2.1 words: word types and fields (docs/formats.md#prophesee-raw-evt-21),
 * named as in OpenEB's evt21_event_types.h.
 *
 * 64-bit words, the type in bits 63..60 (read as one little-endian uint64; the IMX636's
 * "legacy" order sends the two 32-bit halves the other way round: evt21_swap):
 *   EVT_NEG, EVT_POS  change-detection events of one polarity (= type): t low 6 bits in
 *                     59..54, x base in 53..43, y in 42..32, valid mask in 31..0 -- an event
 *                     at (x base + i, y) for every set bit i
 *   EVT_TIME_HIGH     the time base: t >> 6 in 59..32 (a 28-bit count of 64 us)
 *   EXT_TRIGGER       external trigger (counted)
 *   OTHERS, CONTINUED extensions and their payload words (counted, not decoded)
 *   anything else     'unknown_type' */
#ifndef SPRINGTRACK_EVT21_TYPES_H
#define SPRINGTRACK_EVT21_TYPES_H

#include <stdint.h>

enum Evt21EventTypes {
    EVT21_EVT_NEG       = 0x0,
    EVT21_EVT_POS       = 0x1,
    EVT21_EVT_TIME_HIGH = 0x8,
    EVT21_EXT_TRIGGER   = 0xA,
    EVT21_OTHERS        = 0xE,
    EVT21_CONTINUED     = 0xF,
};

enum {
    EVT21_WORD_BYTES    = 8,
    EVT21_MAX_PER_WORD  = 32,     /* events one word can carry: its valid mask */
    EVT21_TYPE_SHIFT    = 60,
    EVT21_CD_SHIFT      = 61,     /* v >> 61 == 0: EVT_NEG or EVT_POS */
    EVT21_T_LOW_SHIFT   = 54,
    EVT21_TH_SHIFT      = 6,      /* TIME_HIGH unit: 2**6 = 64 us, the CD words' t low bits */
    EVT21_TH_BITS       = 28,     /* EVT_TIME_HIGH counter width */
    EVT21_X_SHIFT       = 43,
    EVT21_Y_SHIFT       = 32,     /* also the TIME_HIGH payload's */
    EVT21_COORD_MASK    = 0x7FF,  /* x and y: 11 bits, up to 2048 x 2048 */
    EVT21_HALF_SHIFT    = 32,     /* the legacy order's 32-bit halves */
    EVT21_GROUP_BITS    = 5,      /* a word covers the 32 columns [x base, x base + 32) */
};

static inline uint64_t evt21_swap(uint64_t v)      /* IMX636 order <-> 64-bit order */
{
    return (v << EVT21_HALF_SHIFT) | (v >> EVT21_HALF_SHIFT);
}
static inline uint32_t evt21_type(uint64_t v) { return (uint32_t)(v >> EVT21_TYPE_SHIFT); }
static inline uint32_t evt21_mask(uint64_t v) { return (uint32_t)v; }
static inline uint32_t evt21_x(uint64_t v)
{
    return (uint32_t)(v >> EVT21_X_SHIFT) & EVT21_COORD_MASK;
}
static inline uint32_t evt21_y(uint64_t v)
{
    return (uint32_t)(v >> EVT21_Y_SHIFT) & EVT21_COORD_MASK;
}
static inline uint32_t evt21_t_low(uint64_t v)
{
    return (uint32_t)(v >> EVT21_T_LOW_SHIFT) & ((1u << EVT21_TH_SHIFT) - 1);
}
static inline uint32_t evt21_time_high(uint64_t v)
{
    return (uint32_t)(v >> EVT21_Y_SHIFT) & ((1u << EVT21_TH_BITS) - 1);
}

/* words for the encoder (the inverse of the fields above) */
static inline uint64_t evt21_time_high_word(uint64_t count)
{
    return ((uint64_t)EVT21_EVT_TIME_HIGH << EVT21_TYPE_SHIFT)
           | ((count & ((1u << EVT21_TH_BITS) - 1)) << EVT21_Y_SHIFT);
}
static inline uint64_t evt21_cd_word(uint32_t pol, uint32_t t_low, uint32_t x, uint32_t y,
                                     uint32_t mask)
{
    return ((uint64_t)(pol ? EVT21_EVT_POS : EVT21_EVT_NEG) << EVT21_TYPE_SHIFT)
           | ((uint64_t)(t_low & ((1u << EVT21_TH_SHIFT) - 1)) << EVT21_T_LOW_SHIFT)
           | ((uint64_t)(x & EVT21_COORD_MASK) << EVT21_X_SHIFT)
           | ((uint64_t)(y & EVT21_COORD_MASK) << EVT21_Y_SHIFT) | mask;
}

#endif /* SPRINGTRACK_EVT21_TYPES_H */
