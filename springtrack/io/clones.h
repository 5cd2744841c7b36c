/* Function clones for the word decoders' vectorised block paths (ccam_block.h,
 * evt2_block.h): one build runs on any x86-64 and the loader picks the AVX2 clone where
 * the processor has it; and the run-time choice of the hand-written AVX2 paths. */
#ifndef SPRINGTRACK_IO_CLONES_H
#define SPRINGTRACK_IO_CLONES_H

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define IO_CLONES __attribute__((unused, target_clones("default", "avx2")))
#else
#define IO_CLONES __attribute__((unused))
#endif

/* the block paths read words and write event records as little-endian integers */
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
#define IO_BLOCKS_LITTLE_ENDIAN 0
#else
#define IO_BLOCKS_LITTLE_ENDIAN 1
#endif

/* The hand-written AVX2 block paths (evt2_block.h, evt3_block.h): compiled with a target
 * attribute (never -mavx2) where the compiler speaks x86-64 intrinsics (IO_AVX2_BUILD),
 * run only where io_avx2() says so: the processor reports AVX2 (__builtin_cpu_supports,
 * asked once per extension module) and the environment does not set SPRINGTRACK_SIMD=0
 * (the portable paths alone: a check, or a processor that reports AVX2 wrongly).  Events
 * and counters never depend on the path. */
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define IO_AVX2_BUILD 1
#include <immintrin.h>
#include <stdlib.h>
#include <string.h>
#define IO_AVX2 __attribute__((target("avx2"), unused))
#define IO_AVX2_INLINE __attribute__((target("avx2"), always_inline, unused)) static inline

static int io_avx2_state = -1;

static inline int io_avx2(void)
{
    if (io_avx2_state < 0) {
        const char *env = getenv("SPRINGTRACK_SIMD");
        io_avx2_state = (env != NULL && strcmp(env, "0") == 0) ? 0
                        : __builtin_cpu_supports("avx2") ? 1 : 0;
    }
    return io_avx2_state;
}
#else
#define IO_AVX2_BUILD 0
static inline int io_avx2(void) { return 0; }
#endif

#endif /* SPRINGTRACK_IO_CLONES_H */
