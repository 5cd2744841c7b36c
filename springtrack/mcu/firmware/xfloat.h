/* Arithmetic for converting parameters on a core without floating point (params.c):
 * IEEE-754 doubles as their bits, with add, multiply and divide rounded exactly as the
 * hardware rounds them (to nearest, ties to even), so that a formula of
 * springtrack/fixed/q.py evaluated here gives the host's double; and exp and log to
 * about 2^-60, rounded to the nearest double (the host's libm is within 0.52 ulp of the
 * same value: where the two roundings differ the quantised words can differ by one
 * unit, docs/mcu.md "PARAM_SET by name").  Only the finite, normal values the parameter
 * formulas meet are handled (zero included; no NaN, infinity or subnormal result).
 *   dbits_t: the bits; d_add, d_sub, d_mul, d_div, d_lt, d_le, d_from_int
 *   d_round_scaled(x, k): round(x 2^k) to an int64, ties to even (Python's round)
 *   d_ilogb(x): floor(log2 |x|) of a normal x
 *   d_exp_neg(x): exp(-x) for 0 <= x <= 700;  d_log(x): ln x for 0 < x < 2^1000 */
#ifndef SPRINGTRACK_FW_XFLOAT_H
#define SPRINGTRACK_FW_XFLOAT_H

#include <stdint.h>

typedef uint64_t dbits_t;

#define D_ZERO 0ull
#define D_ONE 0x3ff0000000000000ull
#define D_TWO 0x4000000000000000ull
#define D_HALF 0x3fe0000000000000ull
#define D_NEG(x) ((x) ^ 0x8000000000000000ull)

dbits_t d_add(dbits_t a, dbits_t b);
dbits_t d_sub(dbits_t a, dbits_t b);
dbits_t d_mul(dbits_t a, dbits_t b);
dbits_t d_div(dbits_t a, dbits_t b);
int d_lt(dbits_t a, dbits_t b);
int d_le(dbits_t a, dbits_t b);
int d_finite(dbits_t a);
dbits_t d_from_int(int64_t v);
int64_t d_round_scaled(dbits_t x, int k);
int d_ilogb(dbits_t x);
dbits_t d_exp_neg(dbits_t x);
dbits_t d_log(dbits_t x);

#endif
