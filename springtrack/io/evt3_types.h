/* Prophesee RAW EVT 3.0 words: word types and fields (docs/formats.md#prophesee-raw-evt-30),
 * named as in OpenEB's evt3_event_types.h.
 *
 * Little-endian 16-bit words, the type in bits 15..12; the decoder keeps the current row,
 * vector base / polarity and time:
 *   EVT_ADDR_Y     row = bits 10..0 (bit 11, the system type, ignored)
 *   EVT_ADDR_X     one event: x = bits 10..0, p = bit 11, at the current row and time
 *   VECT_BASE_X    vector base x = bits 10..0, polarity = bit 11
 *   VECT_12        an event at base + i for each set bit i of 11..0; base += 12
 *   VECT_8         an event at base + i for each set bit i of 7..0; base += 8
 *   EVT_TIME_LOW   t bits 11..0
 *   EVT_TIME_HIGH  the time base: t bits 23..12 (a 12-bit count of 4096 us)
 *   CONTINUED_4, CONTINUED_12, OTHERS, EXT_TRIGGER   counted, not decoded
 *   anything else (0x1, 0x9, 0xB, 0xC and OpenEB's IMU 0xD)   'unknown_type' */
#ifndef SPRINGTRACK_EVT3_TYPES_H
#define SPRINGTRACK_EVT3_TYPES_H

#include <stdint.h>

enum Evt3EventTypes {
    EVT3_EVT_ADDR_Y    = 0x0,
    EVT3_EVT_ADDR_X    = 0x2,
    EVT3_VECT_BASE_X   = 0x3,
    EVT3_VECT_12       = 0x4,
    EVT3_VECT_8        = 0x5,
    EVT3_EVT_TIME_LOW  = 0x6,
    EVT3_CONTINUED_4   = 0x7,
    EVT3_EVT_TIME_HIGH = 0x8,
    EVT3_EXT_TRIGGER   = 0xA,
    EVT3_OTHERS        = 0xE,
    EVT3_CONTINUED_12  = 0xF,
};

enum {
    EVT3_WORD_BYTES   = 2,
    EVT3_TYPE_SHIFT   = 12,
    EVT3_TH_BITS      = 12,       /* EVT_TIME_HIGH counter width */
    EVT3_TH_SHIFT     = 12,       /* its unit: 2**12 = 4096 us, the range of EVT_TIME_LOW */
    EVT3_TIME_LOW_MASK = (1 << EVT3_TH_SHIFT) - 1,
    EVT3_POL_SHIFT    = 11,
    EVT3_COORD_MASK   = 0x7FF,    /* x, y, vector base: 11 bits, up to 2048 x 2048 */
    EVT3_VECT_12_BITS = 12,
    EVT3_VECT_8_BITS  = 8,
    EVT3_MAX_EVENTS_PER_WORD = EVT3_VECT_12_BITS,
};

static inline uint32_t evt3_type(uint16_t v) { return (uint32_t)v >> EVT3_TYPE_SHIFT; }
static inline uint32_t evt3_coord(uint16_t v) { return v & EVT3_COORD_MASK; }
static inline uint32_t evt3_pol(uint16_t v) { return ((uint32_t)v >> EVT3_POL_SHIFT) & 1; }
static inline uint32_t evt3_time(uint16_t v) { return v & EVT3_TIME_LOW_MASK; }
static inline uint32_t evt3_vect_mask(uint16_t v, uint32_t bits) { return v & ((1u << bits) - 1); }

/* words for the encoder */
static inline uint16_t evt3_word(uint32_t type, uint32_t payload)
{
    return (uint16_t)((type << EVT3_TYPE_SHIFT) | (payload & ((1u << EVT3_TYPE_SHIFT) - 1)));
}
static inline uint16_t evt3_addr_x_word(uint32_t pol, uint32_t x)
{
    return evt3_word(EVT3_EVT_ADDR_X, ((pol != 0) << EVT3_POL_SHIFT) | (x & EVT3_COORD_MASK));
}

#endif /* SPRINGTRACK_EVT3_TYPES_H */
