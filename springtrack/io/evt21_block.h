/* The EVT 2.1 word layout (named once here, for evt21.pxd and the fast path below) and the
 * fast path of the word decoder (springtrack/io/evt21.pxd): a run of words that are all
 * change-detection words (EVT_NEG, EVT_POS) whose events lie inside the sensor, decoded
 * with the time base and counters in registers.  The fields and checks are those of
 * evt21_decode_word; the run stops at the first other word (time high, trigger, a word with
 * an event outside the sensor, ...), which the caller decodes word by word, so results and
 * counters are the word-by-word decoder's. */
#ifndef SPRINGTRACK_EVT21_BLOCK_H
#define SPRINGTRACK_EVT21_BLOCK_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "springtrack/io/clones.h"

enum evt21_type {                /* bits 63..60 of a word (OpenEB's Evt21EventTypes_4bits) */
    EVT21_NEG = 0x0,             /* OFF change-detection events (polarity 0) */
    EVT21_POS = 0x1,             /* ON change-detection events (polarity 1) */
    EVT21_TIME_HIGH = 0x8,
    EVT21_EXT_TRIGGER = 0xA,
    EVT21_OTHERS = 0xE,
    EVT21_CONTINUED = 0xF
};

enum evt21_layout {
    EVT21_WORD_BYTES = 8,
    EVT21_MAX_PER_WORD = 32,     /* events one word can carry (its valid mask) */
    EVT21_TYPE_SHIFT = 60,
    EVT21_CD_TYPES_SHIFT = 61,   /* v >> 61 == 0: EVT_NEG or EVT_POS */
    EVT21_T_SHIFT = 54,          /* t low bits */
    EVT21_T_BITS = 6,
    EVT21_T_MASK = 0x3F,
    EVT21_X_SHIFT = 43,
    EVT21_Y_SHIFT = 32,
    EVT21_XY_MASK = 0x7FF,       /* x and y are 11 bits */
    EVT21_TH_BITS = 28,          /* EVT_TIME_HIGH payload in bits 59..32 */
    EVT21_HALF_SHIFT = 32,       /* legacy order: the 32-bit halves swapped */
    EVT21_UNCHECKED = 0x10000    /* width/height of an unknown geometry: every x, y passes */
};

#define EVT21_MASK_TOP 0x80000000u   /* bit 31 of the valid mask: keeps ctz defined */

/* Decode words from p while they are plain change-detection words, at most n; write their
 * events to out (springtrack.events.EVENT_DTYPE records as two uint64: the int64 t, then
 * x | y << 16 | p << 32 with zero padding; room for 32 per word) with the time base th
 * (TIME_HIGH bits, shifted); return the number of words decoded and add the events written
 * to *nev.  legacy: the IMX636 word order (32-bit halves swapped).  Layout (evt21.pxd):
 * type 63..60, t 59..54, x base 53..43, y 42..32, valid mask 31..0. */
IO_CLONES static size_t evt21_decode_run(const uint8_t *restrict p, size_t n, int64_t th,
                                         uint32_t width, uint32_t height, int legacy,
                                         void *restrict out_, size_t *restrict nev)
{
    uint64_t *restrict out = (uint64_t *)out_;
    size_t i, k = 0;
    if (!IO_BLOCKS_LITTLE_ENDIAN)
        return 0;                   /* the loads and records below are little-endian */
    for (i = 0; i < n; i++) {
        uint64_t v;
        memcpy(&v, p + EVT21_WORD_BYTES * i, EVT21_WORD_BYTES);
        if (legacy)
            v = (v << EVT21_HALF_SHIFT) | (v >> EVT21_HALF_SHIFT);
        uint32_t m = (uint32_t)v;
        uint32_t x = (uint32_t)(v >> EVT21_X_SHIFT) & EVT21_XY_MASK;
        uint32_t y = (uint32_t)(v >> EVT21_Y_SHIFT) & EVT21_XY_MASK;
        uint32_t last = m ? 31 - (uint32_t)__builtin_clz(m) : 0;   /* highest set offset */
        if ((v >> EVT21_CD_TYPES_SHIFT) != 0 || y >= height || x + last >= width)
            break;                  /* not a CD word, or an event outside */
        uint64_t t = (uint64_t)(th | (int64_t)((v >> EVT21_T_SHIFT) & EVT21_T_MASK));
        /* the record's second 8 bytes: x | y << 16 | p << 32, p the type bit */
        uint64_t rest = (uint64_t)x | ((uint64_t)y << 16) | ((v >> EVT21_TYPE_SHIFT) << 32);
        /* the first two events written whatever the mask (k advances only for set bits;
           bit 31 keeps ctz defined): most words carry one or two, and a loop whose trip
           count changes from word to word costs a mispredicted branch per word */
        out[2 * k] = t;
        out[2 * k + 1] = rest + (uint64_t)__builtin_ctz(m | EVT21_MASK_TOP);
        k += m != 0;
        m &= m - 1;
        out[2 * k] = t;
        out[2 * k + 1] = rest + (uint64_t)__builtin_ctz(m | EVT21_MASK_TOP);
        k += m != 0;
        m &= m - 1;
        while (m) {
            out[2 * k] = t;
            out[2 * k + 1] = rest + (uint64_t)__builtin_ctz(m);
            k++;
            m &= m - 1;
        }
    }
    *nev += k;
    return i;
}

#endif /* SPRINGTRACK_EVT21_BLOCK_H */
