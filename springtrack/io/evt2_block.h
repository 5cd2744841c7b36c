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

/* Decode the n words at p (n <= EVT2_BLOCK) into the event records at out
 * (springtrack.events.EVENT_DTYPE: per record the int64 t, then x, y (uint16) and p
 * (uint8) in the low bytes of the second 8, padding zero) with the time base th (the
 * TIME_HIGH bits, already shifted); returns f, the number of leading words that are CD
 * events with x < width and y < height: out[0:f] are then right, the records after them
 * garbage (decode word f word by word).  Two uint64 per record, indexed with size_t:
 * contiguous loads and stores that GCC vectorises; bit k of `other` marks word k. */
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
        other |= ((uint32_t)(evt2_type(v) > EVT2_CD_ON) | (uint32_t)(x >= width)
                  | (uint32_t)(y >= height)) << k;
        out[2 * k] = (uint64_t)(th | (int64_t)evt2_t_low(v));
        out[2 * k + 1] = (uint64_t)x | ((uint64_t)y << 16) | ((uint64_t)evt2_type(v) << 32);
    }
    return other ? __builtin_ctz(other) : n;
}

#if IO_AVX2_BUILD
/* evt2_decode_plain for a whole block with AVX2 intrinsics, 8 words per step: each
 * record's four 32-bit parts -- the low half of t (th's low half | t low bits), th's high
 * half, x | y << 16, the type (CD_OFF / CD_ON: the polarity) -- interleaved by unpacks
 * and put in order by 128-bit permutes; a word that is not a CD event inside the sensor
 * sets its bit of the mask (movemask), the first one ends the block's good words. */
IO_AVX2 static int evt2_decode_plain_avx2(const uint8_t *restrict p, int64_t th,
                                          uint32_t width, uint32_t height,
                                          void *restrict out_)
{
    uint8_t *restrict out = (uint8_t *)out_;
    const __m256i coord = _mm256_set1_epi32(EVT2_COORD_MASK);
    const __m256i tmask = _mm256_set1_epi32((1 << EVT2_TH_SHIFT) - 1);
    const __m256i cd_max = _mm256_set1_epi32(EVT2_CD_ON);
    const __m256i xmax = _mm256_set1_epi32((int)width - 1);
    const __m256i ymax = _mm256_set1_epi32((int)height - 1);
    const __m256i tlo = _mm256_set1_epi32((int)(uint32_t)th);
    const __m256i thi = _mm256_set1_epi32((int)(uint32_t)((uint64_t)th >> 32));
    uint32_t other = 0;
    for (int s = 0; s < EVT2_BLOCK / 8; s++) {
        __m256i v = _mm256_loadu_si256((const __m256i *)(p + 32 * s));
        __m256i typ = _mm256_srli_epi32(v, EVT2_TYPE_SHIFT);
        __m256i x = _mm256_and_si256(_mm256_srli_epi32(v, EVT2_X_SHIFT), coord);
        __m256i y = _mm256_and_si256(v, coord);
        __m256i a = _mm256_or_si256(tlo, _mm256_and_si256(_mm256_srli_epi32(v,
                                                          EVT2_T_LOW_SHIFT), tmask));
        __m256i c = _mm256_or_si256(x, _mm256_slli_epi32(y, 16));
        /* x, y < 2048 and the type < 16: signed comparisons are exact */
        __m256i bad = _mm256_or_si256(_mm256_cmpgt_epi32(typ, cd_max),
                                      _mm256_or_si256(_mm256_cmpgt_epi32(x, xmax),
                                                      _mm256_cmpgt_epi32(y, ymax)));
        other |= (uint32_t)_mm256_movemask_ps(_mm256_castsi256_ps(bad)) << (8 * s);
        __m256i ab_lo = _mm256_unpacklo_epi32(a, thi);    /* words 0 1 | 4 5: t */
        __m256i ab_hi = _mm256_unpackhi_epi32(a, thi);    /* words 2 3 | 6 7 */
        __m256i cd_lo = _mm256_unpacklo_epi32(c, typ);    /* x y p */
        __m256i cd_hi = _mm256_unpackhi_epi32(c, typ);
        __m256i r04 = _mm256_unpacklo_epi64(ab_lo, cd_lo);    /* records 0 | 4 */
        __m256i r15 = _mm256_unpackhi_epi64(ab_lo, cd_lo);    /* records 1 | 5 */
        __m256i r26 = _mm256_unpacklo_epi64(ab_hi, cd_hi);
        __m256i r37 = _mm256_unpackhi_epi64(ab_hi, cd_hi);
        uint8_t *o = out + 16 * 8 * s;
        _mm256_storeu_si256((__m256i *)o, _mm256_permute2x128_si256(r04, r15, 0x20));
        _mm256_storeu_si256((__m256i *)(o + 32), _mm256_permute2x128_si256(r26, r37, 0x20));
        _mm256_storeu_si256((__m256i *)(o + 64), _mm256_permute2x128_si256(r04, r15, 0x31));
        _mm256_storeu_si256((__m256i *)(o + 96), _mm256_permute2x128_si256(r26, r37, 0x31));
    }
    return other ? __builtin_ctz(other) : EVT2_BLOCK;
}
#endif

/* A block of EVT2_BLOCK words: evt2_decode_plain, by hand with AVX2 where io_avx2()
 * allows it (clones.h). */
static inline int evt2_decode_block(const uint8_t *restrict p, int64_t th, uint32_t width,
                                    uint32_t height, void *restrict out)
{
#if IO_AVX2_BUILD
    if (io_avx2())
        return evt2_decode_plain_avx2(p, th, width, height, out);
#endif
    return evt2_decode_plain(p, EVT2_BLOCK, th, width, height, out);
}

#endif /* SPRINGTRACK_EVT2_BLOCK_H */
