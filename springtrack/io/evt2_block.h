/* The fast path of the EVT 2.0 word decoder (springtrack/io/evt2.pyx): a block of words
 * that are all change-detection events (CD_OFF, CD_ON) inside the sensor, decoded without
 * a branch so that GCC vectorises it (an AVX2 clone picked at load time: clones.h).  Word
 * types and fields are those of evt2_types.h, the checks those of the word loop in
 * evt2.pyx; the caller falls back to it, word by word, for a block with any other word
 * (time high, trigger, ...), and counts the words itself. */
#ifndef SPRINGTRACK_EVT2_BLOCK_H
#define SPRINGTRACK_EVT2_BLOCK_H

#include <stdint.h>
#include <string.h>

#include "springtrack/io/clones.h"
#include "springtrack/io/evt2_types.h"

#define EVT2_BLOCK 32        /* words per block: a time-high word every 64 us sends about
                                one block in several to the word-by-word path */

/* Decode the n words at p into the event records at out (springtrack.events.EVENT_DTYPE:
 * per record the int64 t, then x, y (uint16) and p (uint8) in the low bytes of the second
 * 8, padding zero) with the time base th (the TIME_HIGH bits, already shifted); returns 1
 * if every word was a CD event with x < width and y < height (out is then right), else 0
 * (out holds garbage: decode the block word by word).  Two uint64 per record, indexed
 * with size_t: contiguous loads and stores that GCC vectorises. */
IO_CLONES static int evt2_decode_plain(const uint8_t *restrict p, int n, int64_t th,
                                       uint32_t width, uint32_t height, void *restrict out_)
{
    uint64_t *restrict out = (uint64_t *)out_;
    uint32_t other = 0;
    if (!IO_BLOCKS_LITTLE_ENDIAN)
        return 0;                   /* the loads and records below are little-endian */
    for (size_t k = 0; k < (size_t)n; k++) {
        uint32_t v;
        memcpy(&v, p + 4 * k, 4);
        uint32_t x = evt2_x(v), y = evt2_y(v);
        other |= (uint32_t)(evt2_type(v) > EVT2_CD_ON) | (uint32_t)(x >= width)
                 | (uint32_t)(y >= height);
        out[2 * k] = (uint64_t)(th | (int64_t)evt2_t_low(v));
        out[2 * k + 1] = (uint64_t)x | ((uint64_t)y << 16) | ((uint64_t)evt2_type(v) << 32);
    }
    return other == 0;
}

#endif /* SPRINGTRACK_EVT2_BLOCK_H */
