/* The fast path of the CCam ATIS word decoder (springtrack/io/ccam.pxd): a block of words
 * that are all plain change-detection events (CD_OFF / CD_ON, no time-high, exposure or
 * unknown word, coordinates inside the sensor), decoded without a branch so that GCC
 * vectorises it (an AVX2 clone picked at load time: clones.h).  Word types and fields are
 * those of ccam_types.h, the checks those of ccam_decode_word; the caller falls back to
 * it, word by word, for a block with any other word, and counts the words and events
 * itself. */
#ifndef SPRINGTRACK_CCAM_BLOCK_H
#define SPRINGTRACK_CCAM_BLOCK_H

#include <stdint.h>
#include <string.h>

#include "springtrack/io/clones.h"
#include "springtrack/io/ccam_types.h"

#define CCAM_BLOCK 32        /* words per block: a time-high word every ~2 ms sends one
                                block in a few to the word-by-word path */

/* Decode the n words at p into the event records at out (springtrack.events.EVENT_DTYPE,
 * events.pxd: per record the int64 t, then x, y (uint16) and p (uint8) in the low bytes of
 * the second 8, padding zero) with time base t_offset, for a width x height sensor;
 * returns 1 if every word was a plain change-detection event inside the sensor (out is
 * then right), else 0 (out holds garbage: decode the block word by word).  Written as two
 * uint64 per record and indexed with size_t, so that GCC sees contiguous loads and stores
 * and vectorises them. */
IO_CLONES static int ccam_decode_plain(const uint8_t *restrict p, int n, int64_t t_offset,
                                       uint32_t width, uint32_t height, void *restrict out_)
{
    uint64_t *restrict out = (uint64_t *)out_;
    uint32_t other = 0;
    if (!IO_BLOCKS_LITTLE_ENDIAN)
        return 0;                   /* the loads and records below are little-endian */
    for (size_t k = 0; k < (size_t)n; k++) {
        uint32_t w;
        memcpy(&w, p + 4 * k, 4);
        uint32_t x = ccam_x(w), row = ccam_row(w);
        other |= (uint32_t)(ccam_type(w) > CCAM_CD_ON) | (uint32_t)(x >= width)
                 | (uint32_t)(row >= height);
        out[2 * k] = (uint64_t)(t_offset + (int64_t)ccam_t_low(w));
        out[2 * k + 1] = (uint64_t)x | ((uint64_t)(height - 1 - row) << 16)
                         | ((uint64_t)(ccam_type(w) & CCAM_POLARITY_FLAG) << 32);
    }
    return other == 0;
}

#endif /* SPRINGTRACK_CCAM_BLOCK_H */
