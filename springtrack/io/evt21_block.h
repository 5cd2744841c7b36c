/* The fast path of the EVT 2.1 word decoder (springtrack/io/evt21.pxd): a run of words that
 * are all change-detection words (EVT_NEG, EVT_POS) whose events lie inside the sensor,
 * decoded with the time base and counts in registers.  The fields and checks are those of
 * evt21_decode_word; the run stops at the first other word (time high, trigger, a word with
 * an event outside the sensor, ...), which the caller decodes word by word, so results and
 * counters are the word-by-word decoder's. */
#ifndef SPRINGTRACK_EVT21_BLOCK_H
#define SPRINGTRACK_EVT21_BLOCK_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "springtrack/io/clones.h"
#include "springtrack/io/evt21_types.h"

#define EVT21_MASK_TOP 0x80000000u   /* bit 31 of a valid mask: keeps ctz defined */

/* Decode words from p while they are plain change-detection words, at most n, and while
 * out has room for the next word's events (cap records; a word writes two records whatever
 * its mask, see below, so it needs its events + 2); write their events to out
 * (springtrack.events.EVENT_DTYPE records as two uint64: the int64 t, then
 * x | y << 16 | p << 32 with zero padding) with the time base th (TIME_HIGH count,
 * shifted); return the number of words decoded and add the events written to *nev.
 * legacy: the IMX636 word order (evt21_swap). */
IO_CLONES static size_t evt21_decode_run(const uint8_t *restrict p, size_t n, int64_t th,
                                         uint32_t width, uint32_t height, int legacy,
                                         void *restrict out_, size_t cap,
                                         size_t *restrict nev)
{
    uint64_t *restrict out = (uint64_t *)out_;
    size_t i, k = 0;
    if (!IO_BLOCKS_LITTLE_ENDIAN)
        return 0;                   /* the loads and records below are little-endian */
    for (i = 0; i < n; i++) {
        uint64_t v;
        memcpy(&v, p + EVT21_WORD_BYTES * i, EVT21_WORD_BYTES);
        if (legacy)
            v = evt21_swap(v);
        uint32_t m = evt21_mask(v), x = evt21_x(v), y = evt21_y(v);
        uint32_t last = m ? 31 - (uint32_t)__builtin_clz(m) : 0;   /* highest set offset */
        if ((v >> EVT21_CD_SHIFT) != 0 || y >= height || x + last >= width)
            break;                  /* not a CD word, or an event outside */
        if (cap - k < EVT21_MAX_PER_WORD + 2 && cap - k < (size_t)__builtin_popcount(m) + 2)
            break;                  /* no room for its records */
        uint64_t t = (uint64_t)(th | (int64_t)evt21_t_low(v));
        /* the record's second 8 bytes: x | y << 16 | p << 32, p the type */
        uint64_t rest = (uint64_t)x | ((uint64_t)y << 16) | ((uint64_t)evt21_type(v) << 32);
        /* the first two events written whatever the mask (k advances only for set bits):
           most words carry one or two, and a loop whose trip count changes from word to
           word costs a mispredicted branch per word */
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
