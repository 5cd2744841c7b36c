/* The fast path of the EVT 3.0 word decoder (springtrack/io/evt3.pxd): 16 words at a time
 * with AVX2, for blocks of the words that carry a recording's events -- EVT_ADDR_Y,
 * EVT_ADDR_X, VECT_BASE_X, VECT_12, VECT_8 and EVT_TIME_LOW -- whose events all lie
 * inside the sensor and have their row (and vector base) known.  Any other block (a time
 * high, a trigger, an orphan, an event that may lie outside, ...) is left to the word
 * loop, so events and counters are the word loop's (tests/test_springtrack/io/test_io_decoders.py).
 *
 * The word loop's state -- row, EVT_TIME_LOW bits, vector base and polarity -- becomes,
 * for every word of the block, the value in effect at that word: a "last value written"
 * scan over the 16 lanes (a running maximum of rank << bits | value, the carry from the
 * previous block below every rank), and for the vector base a running sum of the
 * vectors' advances (12 or 8) restarted at each VECT_BASE_X.  Each word then gives the
 * record of its first event (an EVT_ADDR_X its own, a vector the one at its lowest set
 * bit), stored at the index that the events of the words before it give; the rest of a
 * vector's events follow it.  No branch depends on the word types inside a block. */
#ifndef SPRINGTRACK_EVT3_BLOCK_H
#define SPRINGTRACK_EVT3_BLOCK_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "springtrack/io/clones.h"
#include "springtrack/io/evt3_types.h"

#define EVT3_BLOCK_WORDS 16
#define EVT3_BLOCK_BYTES (EVT3_BLOCK_WORDS * EVT3_WORD_BYTES)
/* output room a block needs: every word a full VECT_12 */
#define EVT3_BLOCK_MAX_EVENTS (EVT3_BLOCK_WORDS * EVT3_MAX_EVENTS_PER_WORD)
/* the largest advance of the vector base inside one block */
#define EVT3_BLOCK_ADVANCE (EVT3_BLOCK_WORDS * EVT3_VECT_12_BITS)
/* vector bases up to this value are carried through a block (12-bit scan values: the base
 * plus the block's largest advance stays below 4096) */
#define EVT3_BLOCK_BASE_MAX (4095 - EVT3_BLOCK_ADVANCE)

/* The word loop's state a block reads and updates. */
typedef struct {
    int64_t th;          /* t's bits 12 and up: the time base, shifted */
    int64_t t_low_last;  /* the time the last EVT_TIME_LOW word set */
    uint64_t tl_back;    /* EVT_TIME_LOW words below the previous one (IN_TIME_LOW_BACK) */
    int32_t tl;          /* t's bits 11..0, the last EVT_TIME_LOW value */
    int32_t y;           /* row, -1 before the first EVT_ADDR_Y */
    int32_t base;        /* vector base, -1 before the first VECT_BASE_X */
    int32_t vp;          /* vector polarity */
} Evt3Run;

#if IO_AVX2_BUILD
#define EVT3_BLOCK_SIMD 1

/* The vector constants of the block path, read from memory: left to itself the compiler
 * rebuilds each in every block (an immediate, a move and a broadcast) for want of
 * registers, where an operand in memory costs nothing. */
typedef struct {
    uint16_t v[16];
} __attribute__((aligned(32))) Evt3Vec;
#define EVT3_SPLAT(x) {{x, x, x, x, x, x, x, x, x, x, x, x, x, x, x, x}}
enum { K_ADDR_Y, K_ADDR_X, K_VECT_BASE_X, K_VECT_12, K_VECT_8, K_TIME_LOW, K_COORD,
       K_TIME_LOW_MASK, K_ONE, K_ADVANCE, K_V12_BITS, K_V8_BITS, K_V12_MASK, K_V8_MASK,
       K_V12_LAST, K_V8_LAST, K_DEBRUIJN, K_CTZ_LUT, K_LOW11, K_LOW12, K_RANK11, K_RANK12,
       K_LANE0, K_LANE7, K_POPCOUNT_LUT, K_NIBBLE, K_LOW_BYTE, K_LANE_INDEX, N_EVT3_CONSTS };
static const Evt3Vec evt3_consts[N_EVT3_CONSTS] = {
    [K_ADDR_Y] = EVT3_SPLAT(EVT3_EVT_ADDR_Y),
    [K_ADDR_X] = EVT3_SPLAT(EVT3_EVT_ADDR_X),
    [K_VECT_BASE_X] = EVT3_SPLAT(EVT3_VECT_BASE_X),
    [K_VECT_12] = EVT3_SPLAT(EVT3_VECT_12),
    [K_VECT_8] = EVT3_SPLAT(EVT3_VECT_8),
    [K_TIME_LOW] = EVT3_SPLAT(EVT3_EVT_TIME_LOW),
    [K_COORD] = EVT3_SPLAT(EVT3_COORD_MASK),
    [K_TIME_LOW_MASK] = EVT3_SPLAT(EVT3_TIME_LOW_MASK),
    [K_ONE] = EVT3_SPLAT(1),
    [K_ADVANCE] = EVT3_SPLAT(EVT3_BLOCK_ADVANCE),
    [K_V12_BITS] = EVT3_SPLAT(EVT3_VECT_12_BITS),
    [K_V8_BITS] = EVT3_SPLAT(EVT3_VECT_8_BITS),
    [K_V12_MASK] = EVT3_SPLAT((1 << EVT3_VECT_12_BITS) - 1),
    [K_V8_MASK] = EVT3_SPLAT((1 << EVT3_VECT_8_BITS) - 1),
    [K_V12_LAST] = EVT3_SPLAT(EVT3_VECT_12_BITS - 1),
    [K_V8_LAST] = EVT3_SPLAT(EVT3_VECT_8_BITS - 1),
    [K_DEBRUIJN] = EVT3_SPLAT(0x09AF),
    /* bytes: the lowest set bit of v from (v * 0x09AF) >> 12 (entry 0: v = 0 or 1) */
    [K_CTZ_LUT] = {{0x0100, 0x0502, 0x0903, 0x0B06, 0x040F, 0x0A08, 0x070E, 0x0C0D,
                    0x0100, 0x0502, 0x0903, 0x0B06, 0x040F, 0x0A08, 0x070E, 0x0C0D}},
    [K_LOW11] = EVT3_SPLAT(0x07FF),
    [K_LOW12] = EVT3_SPLAT(0x0FFF),
    [K_RANK11] = {{1 << 11, 2 << 11, 3 << 11, 4 << 11, 5 << 11, 6 << 11, 7 << 11, 8 << 11,
                   9 << 11, 10 << 11, 11 << 11, 12 << 11, 13 << 11, 14 << 11, 15 << 11,
                   16 << 11}},
    [K_RANK12] = {{0, 1 << 12, 2 << 12, 3 << 12, 4 << 12, 5 << 12, 6 << 12, 7 << 12, 8 << 12,
                   9 << 12, 10 << 12, 11 << 12, 12 << 12, 13 << 12, 14 << 12, 15 << 12}},
    [K_LANE0] = {{0xFFFF, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}},
    [K_LANE7] = EVT3_SPLAT(0x0F0E),      /* pshufb: lane 7 of each half */
    [K_POPCOUNT_LUT] = {{0x0100, 0x0201, 0x0201, 0x0302, 0x0201, 0x0302, 0x0302, 0x0403,
                         0x0100, 0x0201, 0x0201, 0x0302, 0x0201, 0x0302, 0x0302, 0x0403}},
    [K_NIBBLE] = EVT3_SPLAT(0x0F0F),
    [K_LOW_BYTE] = EVT3_SPLAT(0x00FF),
    [K_LANE_INDEX] = {{0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15}},
};
#define EVT3_K(i) _mm256_load_si256((const __m256i *)&K[i])


/* 16-bit lanes moved up by s inside each 128-bit half (zeros below) */
#define EVT3_UP_HALF(v, s) _mm256_slli_si256((v), 2 * (s))
/* lane 7 (the low half's last) in every lane of the high half, zeros in the low half */
#define EVT3_LOW_LAST(v)                                                                    \
    _mm256_permute2x128_si256(_mm256_shuffle_epi8((v), EVT3_K(K_LANE7)),                \
                              _mm256_setzero_si256(), 0x02)
/* lane i gets lane i - 1, zeros in lane 0 */
#define EVT3_UP1(v) _mm256_alignr_epi8((v), _mm256_permute2x128_si256((v), (v), 0x08), 14)

/* running maximum (unsigned) over the 16 lanes, lane 0 first */
IO_AVX2_INLINE __m256i evt3_prefix_max(const Evt3Vec *K, __m256i v)
{
    v = _mm256_max_epu16(v, EVT3_UP_HALF(v, 1));
    v = _mm256_max_epu16(v, EVT3_UP_HALF(v, 2));
    v = _mm256_max_epu16(v, EVT3_UP_HALF(v, 4));
    return _mm256_max_epu16(v, EVT3_LOW_LAST(v));
}

/* running sum over the 16 lanes */
IO_AVX2_INLINE __m256i evt3_prefix_sum(const Evt3Vec *K, __m256i v)
{
    v = _mm256_add_epi16(v, EVT3_UP_HALF(v, 1));
    v = _mm256_add_epi16(v, EVT3_UP_HALF(v, 2));
    v = _mm256_add_epi16(v, EVT3_UP_HALF(v, 4));
    return _mm256_add_epi16(v, EVT3_LOW_LAST(v));
}

/* For each lane i, the value of the last lane j <= i where valid, or carry if none.
 * Values below 2048: the rank j + 1 above them (5 bits), the carry at rank 0. */
IO_AVX2_INLINE __m256i evt3_last11(const Evt3Vec *K, __m256i valid, __m256i value,
                                     int carry)
{
    __m256i key = _mm256_and_si256(valid, _mm256_or_si256(EVT3_K(K_RANK11), value));
    key = _mm256_max_epu16(evt3_prefix_max(K, key), _mm256_set1_epi16((short)carry));
    return _mm256_and_si256(key, EVT3_K(K_LOW11));
}

/* The same for values below 4096: the rank j above them (4 bits), lane 0 the carry when
 * not valid itself. */
IO_AVX2_INLINE __m256i evt3_last12(const Evt3Vec *K, __m256i valid, __m256i value,
                                     int carry)
{
    __m256i key = _mm256_and_si256(valid, _mm256_or_si256(EVT3_K(K_RANK12), value));
    key = _mm256_blendv_epi8(key, _mm256_set1_epi16((short)carry),
                             _mm256_andnot_si256(valid, EVT3_K(K_LANE0)));
    return _mm256_and_si256(evt3_prefix_max(K, key), EVT3_K(K_LOW12));
}

/* bits set in each 16-bit lane */
IO_AVX2_INLINE __m256i evt3_popcount16(const Evt3Vec *K, __m256i v)
{
    const __m256i lut = EVT3_K(K_POPCOUNT_LUT), nib = EVT3_K(K_NIBBLE);
    __m256i c = _mm256_add_epi8(_mm256_shuffle_epi8(lut, _mm256_and_si256(v, nib)),
                                _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16(v, 4), nib)));
    return _mm256_add_epi16(_mm256_and_si256(c, EVT3_K(K_LOW_BYTE)), _mm256_srli_epi16(c, 8));
}

IO_AVX2_INLINE int evt3_lane15(__m256i v)
{
    return _mm256_extract_epi16(v, 15);
}

/* 16-bit lanes that are all ones where a <= b (unsigned) */
#define EVT3_LE(a, b) _mm256_cmpeq_epi16(_mm256_max_epu16((a), (b)), (b))
/* word masks of movemask_epi8 have two bits (2i, 2i + 1) per 16-bit lane i: the words
 * before the first set one */
#define EVT3_BELOW_FIRST(m) (((m) & (0u - (m))) - 1u)

/* One block (see evt3_decode_run): returns the events written and sets *used to the words
 * decoded (16, or fewer when the block ends at a word of another type: a time high, ...);
 * or returns -1 and sets *used to the words to decode word by word (up to and including
 * the first that the fast path cannot take), nothing written. */
IO_AVX2_INLINE int evt3_block_avx2(const Evt3Vec *K, const uint8_t *p, Evt3Run *st,
                                     __m256i xmax, __m256i ymax, uint8_t *out, int *used)
{
    const __m256i zero = _mm256_setzero_si256();
    __m256i w = _mm256_loadu_si256((const __m256i *)p);
    __m256i type = _mm256_srli_epi16(w, EVT3_TYPE_SHIFT);
    __m256i is_y = _mm256_cmpeq_epi16(type, EVT3_K(K_ADDR_Y));
    __m256i is_x = _mm256_cmpeq_epi16(type, EVT3_K(K_ADDR_X));
    __m256i is_b = _mm256_cmpeq_epi16(type, EVT3_K(K_VECT_BASE_X));
    __m256i is_v12 = _mm256_cmpeq_epi16(type, EVT3_K(K_VECT_12));
    __m256i is_v8 = _mm256_cmpeq_epi16(type, EVT3_K(K_VECT_8));
    __m256i is_tl = _mm256_cmpeq_epi16(type, EVT3_K(K_TIME_LOW));
    __m256i is_v = _mm256_or_si256(is_v12, is_v8), is_ev = _mm256_or_si256(is_x, is_v);
    __m256i known = _mm256_or_si256(_mm256_or_si256(is_y, is_tl), _mm256_or_si256(is_b, is_ev));
    uint32_t m_known = (uint32_t)_mm256_movemask_epi8(known);
    *used = EVT3_BLOCK_WORDS;
    if (m_known != 0xFFFFFFFFu) {           /* a time high, trigger, unknown word, ... */
        int j = __builtin_ctz(~m_known) / 2;
        if (j == 0) {
            *used = 1;
            return -1;
        }
        /* the words before it make the block: later lanes neither change the state
         * nor have events */
        __m256i live = _mm256_cmpgt_epi16(_mm256_set1_epi16((short)j), EVT3_K(K_LANE_INDEX));
        is_y = _mm256_and_si256(is_y, live);
        is_x = _mm256_and_si256(is_x, live);
        is_b = _mm256_and_si256(is_b, live);
        is_v12 = _mm256_and_si256(is_v12, live);
        is_v8 = _mm256_and_si256(is_v8, live);
        is_tl = _mm256_and_si256(is_tl, live);
        is_v = _mm256_and_si256(is_v, live);
        is_ev = _mm256_and_si256(is_ev, live);
        *used = j;
    }
    uint32_t m_ev = (uint32_t)_mm256_movemask_epi8(is_ev);
    uint32_t m_v = (uint32_t)_mm256_movemask_epi8(is_v);
    uint32_t m_y = (uint32_t)_mm256_movemask_epi8(is_y);
    uint32_t m_b = (uint32_t)_mm256_movemask_epi8(is_b);
    uint32_t m_tl = (uint32_t)_mm256_movemask_epi8(is_tl);
    uint32_t orphans = st->y < 0 ? m_ev & EVT3_BELOW_FIRST(m_y) : 0;
    if ((m_v & EVT3_BELOW_FIRST(m_b)) && (st->base < 0 || st->base > EVT3_BLOCK_BASE_MAX))
        orphans |= m_v & EVT3_BELOW_FIRST(m_b);   /* a vector before any base (or too far) */
    if (orphans) {                          /* an event before any row, ... */
        *used = __builtin_ctz(orphans) / 2 + 1;
        return -1;
    }

    __m256i coord = _mm256_and_si256(w, EVT3_K(K_COORD));
    __m256i tlow = _mm256_and_si256(w, EVT3_K(K_TIME_LOW_MASK));
    __m256i pol = _mm256_and_si256(_mm256_srli_epi16(w, EVT3_POL_SHIFT), EVT3_K(K_ONE));
    /* the row, time low bits and vector polarity in effect at each word */
    __m256i y = evt3_last11(K, is_y, coord, st->y < 0 ? 0 : st->y);
    __m256i tl = evt3_last12(K, is_tl, tlow, st->tl);
    __m256i vp = evt3_last11(K, is_b, pol, st->vp);
    /* the vector base before each word: the last VECT_BASE_X (or the carried base) plus
     * the advances since, s = running sum of the advances (12 per VECT_12, 8 per VECT_8),
     * off keeps the scanned value coord - s non-negative */
    const __m256i off = EVT3_K(K_ADVANCE);
    __m256i inc = _mm256_or_si256(_mm256_and_si256(is_v12, EVT3_K(K_V12_BITS)),
                                  _mm256_and_si256(is_v8, EVT3_K(K_V8_BITS)));
    __m256i s = evt3_prefix_sum(K, inc);
    int carry_base = st->base < 0 || st->base > EVT3_BLOCK_BASE_MAX ? 0 : st->base;
    __m256i d = evt3_last12(K, is_b, _mm256_add_epi16(_mm256_sub_epi16(coord, s), off),
                            carry_base + EVT3_BLOCK_ADVANCE);
    __m256i base = _mm256_sub_epi16(_mm256_add_epi16(d, s), _mm256_add_epi16(inc, off));

    /* each word's events: bit i of m is an event at column xs + i */
    __m256i m = _mm256_or_si256(
        _mm256_or_si256(_mm256_and_si256(is_v12, _mm256_and_si256(w, EVT3_K(K_V12_MASK))),
                        _mm256_and_si256(is_v8, _mm256_and_si256(w, EVT3_K(K_V8_MASK)))),
        _mm256_and_si256(is_x, EVT3_K(K_ONE)));
    __m256i xs = _mm256_blendv_epi8(base, coord, is_x);
    __m256i pe = _mm256_blendv_epi8(vp, pol, is_x);
    /* inside the sensor: the row, and the word's last possible column (a vector's whole
     * width: a vector reaching past the edge goes to the word loop) */
    __m256i xl = _mm256_add_epi16(xs, _mm256_or_si256(
        _mm256_and_si256(is_v12, EVT3_K(K_V12_LAST)),
        _mm256_and_si256(is_v8, EVT3_K(K_V8_LAST))));
    __m256i inside = _mm256_and_si256(EVT3_LE(xl, xmax), EVT3_LE(y, ymax));
    uint32_t outside = (uint32_t)_mm256_movemask_epi8(_mm256_andnot_si256(inside, is_ev));
    if (outside) {
        *used = __builtin_ctz(outside) / 2 + 1;
        return -1;
    }

    /* EVT_TIME_LOW below the previous one, counted: the previous is the last one before
     * in the block, for the block's first the word loop's t_low_last */
    uint64_t nback = 0;
    if (m_tl) {
        __m256i prev = _mm256_blendv_epi8(EVT3_UP1(tl), _mm256_set1_epi16((short)st->tl),
                                          EVT3_K(K_LANE0));
        uint32_t m_back = (uint32_t)_mm256_movemask_epi8(
            _mm256_and_si256(is_tl, _mm256_cmpgt_epi16(prev, tlow)));
        uint16_t v;
        memcpy(&v, p + EVT3_WORD_BYTES * (__builtin_ctz(m_tl) / 2), EVT3_WORD_BYTES);
        /* the first one as the word loop compares it */
        nback = (uint64_t)__builtin_popcount(m_back) / 2
                + (uint64_t)((st->th | (int64_t)evt3_time(v)) < st->t_low_last)
                - (uint64_t)(st->tl > (int32_t)evt3_time(v));
    }

    /* the first event of each word: x = xs + (lowest set bit of m), by a de Bruijn
     * multiply (0x09AF) and a table; for m = 0 the table's entry 0 (0), ignored */
    const __m256i lut = EVT3_K(K_CTZ_LUT);
    __m256i low = _mm256_and_si256(m, _mm256_sub_epi16(zero, m));
    __m256i bit = _mm256_shuffle_epi8(
        lut, _mm256_srli_epi16(_mm256_mullo_epi16(low, EVT3_K(K_DEBRUIJN)), 12));
    __m256i xf = _mm256_add_epi16(xs, bit);
    __m256i rest = _mm256_and_si256(m, _mm256_sub_epi16(m, EVT3_K(K_ONE)));
    uint32_t m_more = ~(uint32_t)_mm256_movemask_epi8(_mm256_cmpeq_epi16(rest, zero));

    /* where each word's first event goes (bytes from out): after the events of the words
     * before it; a word without events writes just past the block's events (overwritten
     * later, or past the events returned) */
    __m256i none = _mm256_cmpeq_epi16(m, zero);
    __m256i cnt = m_more ? evt3_popcount16(K, m) : _mm256_andnot_si256(none, EVT3_K(K_ONE));
    __m256i incl = evt3_prefix_sum(K, cnt);
    int total = evt3_lane15(incl);
    __m256i at = _mm256_slli_epi16(_mm256_blendv_epi8(_mm256_sub_epi16(incl, cnt),
                                                      _mm256_set1_epi16((short)total), none), 4);
    uint16_t at16[EVT3_BLOCK_WORDS];
    _mm256_storeu_si256((__m256i *)at16, at);
    /* read back as 16 loads: cheaper than the 16 lane extracts the compiler makes of it */
    __asm__("" : "+m"(*(uint16_t(*)[EVT3_BLOCK_WORDS])at16));

    /* records (springtrack.events.EVENT_DTYPE as two uint64: t, then x | y << 16 | p << 32)
     * of the first events */
    __m256i xy_lo = _mm256_unpacklo_epi16(xf, y), xy_hi = _mm256_unpackhi_epi16(xf, y);
    __m256i th = _mm256_set1_epi64x(st->th);
    for (int h = 0; h < 2; h++) {
        /* x | y << 16 of words 8h + 0..7 */
        __m256i xy = h ? _mm256_permute2x128_si256(xy_lo, xy_hi, 0x31)
                       : _mm256_permute2x128_si256(xy_lo, xy_hi, 0x20);
        __m256i p32 = _mm256_cvtepu16_epi32(h ? _mm256_extracti128_si256(pe, 1)
                                              : _mm256_castsi256_si128(pe));
        __m256i t32 = _mm256_cvtepu16_epi32(h ? _mm256_extracti128_si256(tl, 1)
                                              : _mm256_castsi256_si128(tl));
        /* 64-bit lanes of words {0, 1, 4, 5} and {2, 3, 6, 7} of this half */
        __m256i hi_a = _mm256_unpacklo_epi32(xy, p32), hi_b = _mm256_unpackhi_epi32(xy, p32);
        __m256i t_a = _mm256_or_si256(_mm256_unpacklo_epi32(t32, zero), th);
        __m256i t_b = _mm256_or_si256(_mm256_unpackhi_epi32(t32, zero), th);
        __m256i r0 = _mm256_unpacklo_epi64(t_a, hi_a);      /* words 0, 4 */
        __m256i r1 = _mm256_unpackhi_epi64(t_a, hi_a);      /* words 1, 5 */
        __m256i r2 = _mm256_unpacklo_epi64(t_b, hi_b);      /* words 2, 6 */
        __m256i r3 = _mm256_unpackhi_epi64(t_b, hi_b);      /* words 3, 7 */
        const uint16_t *a = at16 + 8 * h;
        _mm_storeu_si128((__m128i *)(out + a[0]), _mm256_castsi256_si128(r0));
        _mm_storeu_si128((__m128i *)(out + a[1]), _mm256_castsi256_si128(r1));
        _mm_storeu_si128((__m128i *)(out + a[2]), _mm256_castsi256_si128(r2));
        _mm_storeu_si128((__m128i *)(out + a[3]), _mm256_castsi256_si128(r3));
        _mm_storeu_si128((__m128i *)(out + a[4]), _mm256_extracti128_si256(r0, 1));
        _mm_storeu_si128((__m128i *)(out + a[5]), _mm256_extracti128_si256(r1, 1));
        _mm_storeu_si128((__m128i *)(out + a[6]), _mm256_extracti128_si256(r2, 1));
        _mm_storeu_si128((__m128i *)(out + a[7]), _mm256_extracti128_si256(r3, 1));
    }
    if (m_more) {                           /* the other events of vectors, lowest first */
        uint16_t rest16[EVT3_BLOCK_WORDS], xs16[EVT3_BLOCK_WORDS];
        _mm256_storeu_si256((__m256i *)rest16, rest);
        _mm256_storeu_si256((__m256i *)xs16, xs);
        for (uint32_t mm = m_more & 0x55555555u; mm; mm &= mm - 1) {
            int i = __builtin_ctz(mm) / 2;
            uint64_t *e = (uint64_t *)(out + at16[i]);
            uint64_t t = e[0], yp = e[1] & ~(uint64_t)0xFFFF;
            for (uint32_t r = rest16[i]; r; r &= r - 1) {
                e += 2;
                e[0] = t;
                e[1] = yp | (uint64_t)(xs16[i] + (uint32_t)__builtin_ctz(r));
            }
        }
    }

    /* the state after the block */
    if (m_y)
        st->y = evt3_lane15(y);
    if (m_tl)
        st->t_low_last = st->th | (int64_t)evt3_lane15(tl);
    st->tl = evt3_lane15(tl);
    if (m_b)
        st->vp = evt3_lane15(vp);
    if (m_b | m_v)
        st->base = evt3_lane15(base) + evt3_lane15(inc);
    st->tl_back += nback;
    return total;
}

/* The fast path over the nw words at p (see evt3_decode_run). */
IO_AVX2 static size_t evt3_run_avx2(const uint8_t *p, size_t nw, Evt3Run *st,
                                      uint32_t width, uint32_t height, uint8_t *out,
                                      size_t *k, size_t cap, size_t *scalar)
{
    const Evt3Vec *K = evt3_consts;
    __asm__("" : "+r"(K));              /* opaque: the constants stay in memory */
    const __m256i xmax = _mm256_set1_epi16((short)(width - 1));
    const __m256i ymax = _mm256_set1_epi16((short)(height - 1));
    size_t i = 0;
    *scalar = 0;
    while (nw - i >= EVT3_BLOCK_WORDS && cap - *k >= EVT3_BLOCK_MAX_EVENTS) {
        int used, c = evt3_block_avx2(K, p + EVT3_WORD_BYTES * i, st, xmax, ymax,
                                      out + 16 * *k, &used);
        if (c < 0) {
            *scalar = (size_t)used;
            break;
        }
        *k += (size_t)c;
        i += (size_t)used;
        if (used < EVT3_BLOCK_WORDS) {      /* the next word goes word by word */
            *scalar = 1;
            break;
        }
    }
    return i;
}
#else
#define EVT3_BLOCK_SIMD 0
#endif

/* Decode words from p, at most nw, 16 at a time while they take the fast path, into the
 * EVENT_DTYPE records at out from index *k (advanced; a block starts only while out has
 * room for EVT3_BLOCK_MAX_EVENTS before index cap), with the word loop's state st,
 * updated.  Returns the words decoded and sets *scalar to the number of words the caller
 * must decode word by word before calling again (a time high, an orphan, ...), or 0 if
 * the words or the room ran out (or there is no AVX2 path: io_avx2, clones.h): decode
 * the rest word by word. */
static inline size_t evt3_decode_run(const uint8_t *p, size_t nw, Evt3Run *st,
                                     uint32_t width, uint32_t height, void *out, size_t *k,
                                     size_t cap, size_t *scalar)
{
#if EVT3_BLOCK_SIMD
    if (io_avx2())
        return evt3_run_avx2(p, nw, st, width, height, (uint8_t *)out, k, cap, scalar);
#endif
    (void)p, (void)nw, (void)st, (void)width, (void)height, (void)out, (void)k, (void)cap;
    *scalar = 0;
    return 0;
}

#endif /* SPRINGTRACK_EVT3_BLOCK_H */
