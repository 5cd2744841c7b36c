/* Function clones for the word decoders' vectorised block paths (ccam_block.h,
 * evt2_block.h): one build runs on any x86-64 and the loader picks the AVX2 clone where
 * the processor has it. */
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

#endif /* SPRINGTRACK_IO_CLONES_H */
