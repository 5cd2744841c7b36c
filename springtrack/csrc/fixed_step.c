/* Integer-only tracker step: the fixed-point translation of springtrack/_kernel.pyx, for
 * 32-bit cores.
 *
 * Equations cite Valeiras et al. 2015; [ref] names the function of
 * springtrack/reference.py a block mirrors.  Q formats are listed in fixed_step.h and
 * justified, with their error bounds, in docs/fixed_point.md.  No floating-point type
 * appears in this file: it compiles with `gcc -mgeneral-regs-only`, and every product is
 * a 32 x 32 -> 64-bit one (smul, umul below).
 */
#include "fixed_step.h"
#include "fixed_tables.h"
#include "sampling.h"

#define ONE_Q30 ((int64_t)1 << 30)
#define RHO_Q30 1063004406u        /* 0.99 (reference.RHO_MAX), Q.30 */
#define RHO2_Q30 1052374362u       /* 0.99^2, Q.30 */
#define PI_Q28 843314857u          /* pi, Q.28 */
#define PI_Q29 1686629713          /* pi, Q.29: binary angle * PI_Q29 / 2^30 = rad Q.30 */
#define SMALL_ANGLE ((int64_t)42722830)   /* 2^-4 rad as a binary angle */
#define ACT_MAX ((int64_t)1 << 61) /* activity saturates at 2^29 */
#define E_MAX ((int64_t)1 << 61)   /* an energy (Q.40) saturates at 2^21 px^2 */
#define D2_SAT 0xffffffffu         /* d^2 >= 32: beyond any gate */
/* A 64-bit host does a few steps in 64-bit words, where a 32-bit core uses two 32-bit ones
   (the candidate mask, d^2's final shift, the 64 / 32 divisions): the same integers
   either way, each in the target's natural word. */
#define FX_WORD64 (UINTPTR_MAX > 0xffffffffu)

/* ---- arithmetic building blocks ----------------------------------------------------- */

/* the only two multiplications of this unit: 32 x 32 -> 64 bits (SMULL, UMULL).  On
   Thumb-2 the signed one is written as its instruction: where a factor is masked or
   selected, LLVM widens the operands first and no longer recognises the sign-extended
   product, emitting a 64 x 64 multiply (UMULL and two MLAs) instead of one SMULL. */
static inline int64_t smul(int32_t a, int32_t b)
{
#if defined(__thumb2__) && !FX_WORD64
    uint32_t lo, hi;
    __asm__("smull %0, %1, %2, %3" : "=r"(lo), "=r"(hi) : "r"(a), "r"(b));
    return (int64_t)(((uint64_t)hi << 32) | lo);
#else
    return (int64_t)a * b;
#endif
}

static inline uint64_t umul(uint32_t a, uint32_t b)
{
    return (uint64_t)a * b;
}

/* v 2^k for 0 <= k < 64, also for v < 0 (a shift, not a multiplication) */
static inline int64_t shl64(int64_t v, int k)
{
    return (int64_t)((uint64_t)v << k);
}

/* round(v / 2^sh) half up; sh >= 1 */
static inline int64_t rshr(int64_t v, int sh)
{
    return (v + ((int64_t)1 << (sh - 1))) >> sh;
}

/* round(v g / 2^sh), half up, exact for |v| < 2^62, g < 2^31, 1 <= sh <= 62, provided the
   result fits int64 (callers' bounds): v = hi 2^32 + lo gives hi g 2^32 + lo g, two
   32 x 32 -> 64-bit products, recombined without loss */
static inline int64_t mulsh(int64_t v, uint32_t g, int sh)
{
    int64_t hi = smul((int32_t)(v >> 32), (int32_t)g);
    uint64_t lo = umul((uint32_t)v, g);
    if (sh <= 32)
        return shl64(hi, 32 - sh) + (int64_t)((lo + ((uint64_t)1 << (sh - 1))) >> sh);
    /* floor((hi 2^32 + L) / 2^sh) = floor((hi + floor(L / 2^32)) / 2^(sh - 32)) */
    return (hi + (int64_t)((lo + ((uint64_t)1 << (sh - 1))) >> 32)) >> (sh - 32);
}

int64_t fx_mulsh(int64_t v, uint32_t g, int sh)
{
    return mulsh(v, g, sh);
}

/* floor(v / 2^k) for 0 < k < 32: on a 32-bit core from v's two words (a variable 64-bit
   shift there is a longer sequence that also handles k >= 32) */
static inline int64_t sar64(int64_t v, int k)
{
#if FX_WORD64
    return v >> k;
#else
    uint32_t lo = (uint32_t)v, hi = (uint32_t)(v >> 32);
    return (int64_t)(((uint64_t)(uint32_t)((int32_t)hi >> k) << 32) | ((lo >> k) | (hi << (32 - k))));
#endif
}

/* v + round((inc gm - v am) / 2^sh), half up, 31 <= sh <= 62: eq. (4) with one rounding
   (gm, am < 2^31; |inc| < 2^58, 0 <= |v| < 2^53).  Each product is split into its high and
   low words as in mulsh; the 96-bit difference is hi 2^32 + lo. */
static inline int64_t ema(int64_t v, int64_t inc, uint32_t gm, uint32_t am, int sh)
{
    int64_t hi = smul((int32_t)(inc >> 32), (int32_t)gm) - smul((int32_t)(v >> 32), (int32_t)am);
    int64_t lo = (int64_t)umul((uint32_t)inc, gm) - (int64_t)umul((uint32_t)v, am);  /* < 2^63 each */
    int64_t a = hi + (lo >> 32);                         /* difference = a 2^32 + r */
    uint32_t r = (uint32_t)lo;
    if (sh > 32)                                         /* 1 <= sh - 32 <= 30 */
        return v + sar64(a + (int64_t)(1u << (sh - 33)), sh - 32);
    if (sh == 32)
        return v + a + (r >> 31);
    return v + shl64(a, 1) + ((r >> 30) + 1) / 2;       /* sh = 31: (2^32 a + r + 2^30) >> 31 */
}

static inline int bitlen32(uint32_t v)
{
    return v ? 32 - __builtin_clz(v) : 0;
}

static inline int bitlen64(uint64_t v)
{
    uint32_t hi = (uint32_t)(v >> 32);
    return hi ? 32 + bitlen32(hi) : bitlen32((uint32_t)v);
}

/* floor((u1 2^32 + u0) / v) for u1 < v, and the remainder: two 32-bit divisions by the
   normalised divisor's high half, each corrected by at most two steps (Knuth's algorithm
   D with 16-bit digits, as Hacker's Delight's divlu).  A 64-bit host has this division
   in one instruction; the quotient is exact either way, so both give the same integers
   (fx_divlu32 keeps the 32-bit one testable there). */
static uint32_t divlu32(uint32_t u1, uint32_t u0, uint32_t v, uint32_t *rem)
{
    const uint32_t b = 65536;
    uint32_t vn1, vn0, un32, un21, un10, un1, un0, q1, q0, rhat;
    int s = __builtin_clz(v);                            /* v != 0 */
    v <<= s;
    vn1 = v >> 16;
    vn0 = v & 0xffff;
    un32 = s ? (u1 << s) | (u0 >> (32 - s)) : u1;
    un10 = u0 << s;
    un1 = un10 >> 16;
    un0 = un10 & 0xffff;
    q1 = un32 / vn1;
    rhat = un32 - q1 * vn1;
    while (q1 >= b || q1 * vn0 > b * rhat + un1) {
        q1--;
        rhat += vn1;
        if (rhat >= b)
            break;
    }
    un21 = un32 * b + un1 - q1 * v;
    q0 = un21 / vn1;
    rhat = un21 - q0 * vn1;
    while (q0 >= b || q0 * vn0 > b * rhat + un0) {
        q0--;
        rhat += vn1;
        if (rhat >= b)
            break;
    }
    *rem = (un21 * b + un0 - q0 * v) >> s;
    return q1 * b + q0;
}

uint32_t fx_divlu32(uint32_t u1, uint32_t u0, uint32_t v, uint32_t *rem)
{
    return divlu32(u1, u0, v, rem);
}

static inline uint32_t divlu(uint32_t u1, uint32_t u0, uint32_t v, uint32_t *rem)
{
#if FX_WORD64
    uint64_t n = ((uint64_t)u1 << 32) | u0;
    uint32_t q = (uint32_t)(n / v);
    *rem = u0 - q * v;                                    /* < v: exact modulo 2^32 */
    return q;
#else
    return divlu32(u1, u0, v, rem);
#endif
}

/* floor(n / d) and n mod d for any n < 2^64, 0 < d < 2^32: two divlu steps */
static inline uint64_t udiv64(uint64_t n, uint32_t d, uint32_t *rem)
{
#if FX_WORD64
    uint64_t q = n / d;                                   /* a 64-bit host: one instruction */
    *rem = (uint32_t)n - (uint32_t)q * d;                 /* < d: exact modulo 2^32 */
    return q;
#else
    uint32_t hi = (uint32_t)(n >> 32), q1 = hi / d, q0;
    q0 = divlu32(hi - q1 * d, (uint32_t)n, d, rem);
    return ((uint64_t)q1 << 32) | q0;
#endif
}

uint64_t fx_udiv64(uint64_t n, uint32_t d, uint32_t *rem)
{
    return udiv64(n, d, rem);
}

/* floor(n / d), |n| < 2^63, 0 < d < 2^32; *rem = n - d floor(n / d) in [0, d) */
static inline int64_t floor_div(int64_t n, uint32_t d, uint32_t *rem)
{
    uint64_t q;
    if (n >= 0)
        return (int64_t)udiv64((uint64_t)n, d, rem);
    q = udiv64((uint64_t)-n, d, rem);                    /* -n = q d + r */
    if (*rem) {
        *rem = d - *rem;
        return -(int64_t)q - 1;
    }
    return -(int64_t)q;
}

/* n / d rounded half away from zero; 0 < d < 2^31 */
static inline int64_t div_round(int64_t n, uint32_t d)
{
    uint32_t r;
    if (n >= 0)
        return (int64_t)udiv64((uint64_t)n + d / 2, d, &r);
    return -(int64_t)udiv64((uint64_t)-n + d / 2, d, &r);
}

/* floor(sqrt(v)): normalise v to m = v 4^k in [2^62, 2^64), seed from the table of
   sqrt(j 2^54) / 2 with linear interpolation (relative error < 5e-7), one Newton step
   (error < 2^-40 relative), then an exact +-1 fix.  One 64 / 32 division. */
static inline uint64_t isqrt64(uint64_t v)
{
    uint64_t m, x, j, f, t0, t1;
    uint32_t r, rem;
    int k;
    if (v < 2)
        return v;
    k = (64 - bitlen64(v)) >> 1;                          /* v << 2k keeps v < 2^64 */
    m = v << (2 * k);
    j = (m >> FX_SQRT_SHIFT) - FX_SQRT_J0;                /* [0, 768) */
    f = (m >> (FX_SQRT_SHIFT - 24)) & 0xffffffu;          /* 24 bits of the fraction */
    t0 = FX_SQRT_TAB[j];
    t1 = FX_SQRT_TAB[j + 1];
    x = 2 * (t0 + (umul((uint32_t)(t1 - t0), (uint32_t)f) >> 24)) + 1;   /* ~ sqrt(m) */
    if (x > 0xffffffffu)                                  /* sqrt(m) < 2^32 */
        x = 0xffffffffu;
    x = (x + udiv64(m, (uint32_t)x, &rem)) >> 1;          /* m / x < 2^33 */
    x >>= k;
    r = x > 0xffffffffu ? 0xffffffffu : (uint32_t)x;
    while (umul(r, r) > v)
        r--;
    while (r < 0xffffffffu && umul(r + 1, r + 1) <= v)
        r++;
    return r;
}

uint64_t fx_isqrt64(uint64_t v)
{
    return isqrt64(v);
}

static inline int64_t sat_pos(fx_state *s, int64_t v)
{
    if (v >= FX_POS_LIM) {
        s->sat_position++;
        return FX_POS_LIM - 1;
    }
    if (v < -FX_POS_LIM) {
        s->sat_position++;
        return -FX_POS_LIM;
    }
    return v;
}

/* a position (Q.32) in Q.16, floor; |.| < 2^29 */
static inline int32_t pos16(int64_t v)
{
    return (int32_t)(v >> 16);
}

static inline int64_t sat_add(fx_state *s, int64_t a, int64_t b, int64_t lim)
{
    int64_t v = a + b;                                    /* |a|, |b| <= lim < 2^62 */
    if (v > lim) {
        s->sat_energy++;
        return lim;
    }
    return v;
}

/* 2^(-w) for w >= 0 in Q.40, result Q.30: table of 2^(-k/1024) and linear interpolation
   (relative error < 6e-8 + 2^-30, docs/fixed_point.md). */
static inline uint32_t exp2neg(int64_t w)
{
    int32_t ip;
    uint32_t idx, rem, v0, v1, v;
    if (w < 0)
        return (uint32_t)ONE_Q30;
    if ((w >> 40) > 31)
        return 0;
    ip = (int32_t)(w >> 40);
    idx = (uint32_t)(w >> (40 - FX_EXP2_BITS)) & (FX_EXP2_N - 1);
    rem = (uint32_t)(w >> (40 - FX_EXP2_BITS - 24)) & 0xffffffu;   /* 24 bits */
    v0 = FX_EXP2_LUT[idx];
    v1 = FX_EXP2_LUT[idx + 1];
    v = v0 - (uint32_t)((umul(v0 - v1, rem) + ((uint64_t)1 << 23)) >> 24);
    /* rounded shift by ip in [0, 31] without a branch (ip is data): half = 2^(ip-1), or 0 */
    return (uint32_t)(((uint64_t)v + ((1u << ip) >> 1)) >> ip);
}

uint32_t fx_exp2neg(int64_t w)
{
    return exp2neg(w);
}

/* exp(-d2 / 2), Q.30, for 0 <= d2 < 32 (Q.27; the gate is <= 31): d2 = hi 2^-5 + lo 2^-15
   + r, the product of two tables of exact roundings and 1 - r / 2 for the rest r < 2^-15
   (whose next term r^2 / 8 < 2^-33); error <= 2.1 units of Q.30 */
static inline int64_t gauss(uint32_t d2)
{
    uint32_t q = (uint32_t)((umul(FX_GAUSS_HI[d2 >> 22], FX_GAUSS_LO[(d2 >> 12) & (FX_GAUSS_N - 1)])
                             + ((uint64_t)1 << 29)) >> 30);
    return (int64_t)q - (int64_t)((umul(q, d2 & 4095) + ((uint64_t)1 << 27)) >> 28);
}

int64_t fx_gauss(uint32_t d2)
{
    return gauss(d2);
}

/* exp(-dt / tau), Q.30, for dt in us (eq. 6).  Below decay_span (2^18 us, or dt_max if
   that is less) the product of two tables of exact roundings, exp(-dt_hi 512 / tau) and
   exp(-dt_lo / tau) for dt = 512 dt_hi + dt_lo (error <= 1.5 units of Q.30); beyond it
   the exp2 table (which gives 0 from dt_max on). */
static inline uint32_t decay(const fx_state *s, int64_t dt)
{
    uint64_t w;
    if ((uint64_t)dt < (uint64_t)s->decay_span)
        return (uint32_t)((umul(s->decay_hi[(uint32_t)dt >> FX_DECAY_BITS],
                                s->decay_lo[(uint32_t)dt & (FX_DECAY_N - 1)]) + ((uint64_t)1 << 29)) >> 30);
    if (dt <= 0)
        return (uint32_t)ONE_Q30;
    if (dt >= s->dt_max)
        return 0;
    /* here dt_max > 2^18 us, so k_tau < 2^27 and dt k_tau < 2^46; dt >= 2^32 us (tau >
       3.9 min) splits dt in 16-bit halves */
    if ((uint64_t)dt >> 32)
        w = (umul((uint32_t)(dt >> 16), s->k_tau) << 16) + umul((uint32_t)dt & 0xffff, s->k_tau);
    else
        w = umul((uint32_t)dt, s->k_tau);
    return exp2neg((int64_t)w);
}

uint32_t fx_decay(const fx_state *s, int64_t dt)
{
    return decay(s, dt);
}

/* table look-up with linear interpolation at t in [0, 1] (Q.30), tables of 1024 intervals */
static inline int32_t unit_interp(const uint32_t *tab, uint32_t t)
{
    uint32_t idx = t >> (30 - FX_ATAN_BITS), rem = t & ((1 << (30 - FX_ATAN_BITS)) - 1);
    int32_t v0 = (int32_t)tab[idx], v1 = (int32_t)tab[idx + 1];
    return v0 + (int32_t)((smul(v1 - v0, (int32_t)rem) + (1 << (29 - FX_ATAN_BITS)))
                          >> (30 - FX_ATAN_BITS));
}

/* floor(a 2^30 / b) for 0 <= a <= b < 2^32, b > 0: in [0, 2^30] */
static inline uint32_t ratio30(uint32_t a, uint32_t b)
{
    uint32_t rem;
    return divlu(a >> 2, a << 30, b, &rem);
}

/* atan2(y, x) as a binary angle (2^32 = 2 pi), |x|, |y| <= 2^31: octant reduction, one
   division, table.  atan2(0, 0) = 0 as in C. */
static inline uint32_t atan2_bam(int64_t y, int64_t x)
{
    uint32_t ax = (uint32_t)(x < 0 ? -x : x), ay = (uint32_t)(y < 0 ? -y : y);
    int64_t a;
    if (ax == 0 && ay == 0)
        return 0;
    if (ay <= ax)
        a = unit_interp(FX_ATAN_TAB, ratio30(ay, ax));    /* [0, pi/4] */
    else
        a = ((int64_t)1 << 30) - unit_interp(FX_ATAN_TAB, ratio30(ax, ay));   /* pi/2 - atan(x/y) */
    if (x < 0)
        a = ((int64_t)1 << 31) - a;                       /* pi - a */
    if (y < 0)
        a = -a;
    return (uint32_t)((uint64_t)a & 0xffffffffu);
}

uint32_t fx_atan2(int64_t y, int64_t x)
{
    return atan2_bam(y, x);
}

/* sin r and cos r - 1 for r in radians, Q.30, |r| < 2^-4: Taylor series; below 2^-7 rad
   (r < 2^23, the usual torsion step) r2 <= 2^16 and r4 <= 4, and every r4 term rounds to
   exactly 0, so the short series is the same result */
static inline void series(int32_t r, int32_t *cm1, int32_t *sn)
{
    int32_t r2 = (int32_t)rshr(smul(r, r), 30), r4;
    if (r < (1 << 23) && r > -(1 << 23)) {
        *sn = (int32_t)rshr(smul(r, (int32_t)(ONE_Q30 - rshr(smul(r2, 715827883), 32))), 30);
        *cm1 = -(r2 >> 1);                                /* r2 >= 0 */
        return;
    }
    r4 = (int32_t)rshr(smul(r2, r2), 30);
    /* sin r = r (1 - r2/6 + r4/120), cos r = 1 - r2/2 + r4/24 - r2 r4/720: truncation
       < r^7/5040 < 1e-12 for |r| < 2^-4; constants 2^32/6, 2^32/120, 2^32/24, 2^32/720 */
    *sn = (int32_t)rshr(smul(r, (int32_t)(ONE_Q30 - rshr(smul(r2, 715827883), 32)
                                          + rshr(smul(r4, 35791394), 32))), 30);
    *cm1 = (int32_t)(-(r2 / 2) + rshr(smul(r4, 178956971), 32)
                     - rshr(smul((int32_t)rshr(smul(r2, r4), 30), 5965232), 32));
}

/* cos and sin of a binary angle, Q.30: the series below 2^-4 rad, else CORDIC in rotation
   mode (Q.60 inside: additions and shifts only) */
static inline void cossin(int64_t angle, int64_t *c, int64_t *sn)
{
    uint32_t u = (uint32_t)((uint64_t)angle & 0xffffffffu);
    int64_t z = (int64_t)u - ((int64_t)(u >> 31) << 32);  /* [-pi, pi), without a branch */
    int64_t x = FX_CORDIC_X0, y = 0;
    int neg = 0, i;
    if (z < SMALL_ANGLE && z > -SMALL_ANGLE) {            /* |z| < 2^-4 rad: Taylor series */
        int32_t cm1, s1;
        series((int32_t)rshr(smul((int32_t)z, PI_Q29), 30), &cm1, &s1);   /* radians Q.30 */
        *c = ONE_Q30 + cm1;
        *sn = s1;
        return;
    }
    if (z > ((int64_t)1 << 30)) {                          /* |z| > pi/2: use z -+ pi */
        z -= (int64_t)1 << 31;
        neg = 1;
    } else if (z < -((int64_t)1 << 30)) {
        z += (int64_t)1 << 31;
        neg = 1;
    }
    for (i = 0; i < FX_CORDIC_N; i++) {
        int64_t xn;
        if (z >= 0) {
            xn = x - (y >> i);
            y = y + (x >> i);
            z -= FX_ATAN_LUT[i];
        } else {
            xn = x + (y >> i);
            y = y - (x >> i);
            z += FX_ATAN_LUT[i];
        }
        x = xn;
    }
    x = rshr(x, 30);
    y = rshr(y, 30);
    *c = neg ? -x : x;
    *sn = neg ? -y : y;
}

void fx_cossin(int64_t angle, int64_t *c, int64_t *sn)
{
    cossin(angle, c, sn);
}

/* cos(z) - 1 and sin(z), Q.30, of a binary angle z, |z| < 2^32: the short series for the
   torsion's small rotation a dtheta (the same integers as cossin), cossin otherwise */
static inline void rotation(int64_t z, int32_t *cm1, int32_t *sn)
{
    int64_t c, s1;
    if (z <= 5340353 && z >= -5340353) {                  /* |r| < 2^23 below, 0.0078 rad */
        int32_t r = (int32_t)rshr(smul((int32_t)z, PI_Q29), 30), r2 = (int32_t)rshr(smul(r, r), 30);
        *sn = (int32_t)rshr(smul(r, (int32_t)(ONE_Q30 - rshr(smul(r2, 715827883), 32))), 30);
        *cm1 = -(r2 >> 1);
        return;
    }
    cossin(z, &c, &s1);
    *cm1 = (int32_t)(c - ONE_Q30);
    *sn = (int32_t)s1;
}

/* Polar form of r = (x, y), |x|, |y| < 2^30: its angle (binary), its length (unit of x,
   rounded; relative error < 2e-7) and its direction r / |r| (Q.30).  One division, the
   octant ratio t = min / max, then tables of atan(t), sqrt(1 + t^2), 1 / sqrt(1 + t^2).
   In two steps, so that the spring pass can do all the divisions first (they overlap):
   polar_ratio gives t, max(|x|, |y|) and the octant (bit 0: |y| > |x|, bit 1: x < 0,
   bit 2: y < 0); polar_finish the rest. */
static inline uint32_t polar_ratio(int32_t x, int32_t y, int32_t *big, int *oct)
{
    int32_t ax = x < 0 ? -x : x, ay = y < 0 ? -y : y;
    int swap = ay > ax;
    *big = swap ? ay : ax;
    *oct = swap | (x < 0) << 1 | (y < 0) << 2;
    if (*big == 0)
        return 0;
    return ratio30((uint32_t)(swap ? ax : ay), (uint32_t)*big);      /* [0, 2^30] */
}

static inline void polar_finish(uint32_t t, int32_t big, int oct, uint32_t *ang, int32_t *len,
                                int32_t *cx, int32_t *cy)
{
    int32_t a, h, cbig, csmall;
    if (big == 0) {
        *ang = 0;
        *len = *cx = *cy = 0;
        return;
    }
    a = unit_interp(FX_ATAN_TAB, t);
    *len = (int32_t)rshr(smul(big, unit_interp(FX_HYP_TAB, t)), 30);   /* big sqrt(1 + t^2) */
    h = unit_interp(FX_IHYP_TAB, t);                      /* cos of the octant angle */
    cbig = h;
    csmall = (int32_t)rshr((int64_t)umul(t, (uint32_t)h), 30);
    if (oct & 1) {
        a = (1 << 30) - a;
        *cx = csmall;
        *cy = cbig;
    } else {
        *cx = cbig;
        *cy = csmall;
    }
    if (oct & 2) {
        a = (int32_t)((1u << 31) - (uint32_t)a);
        *cx = -*cx;
    }
    if (oct & 4) {
        a = (int32_t)(0u - (uint32_t)a);
        *cy = -*cy;
    }
    *ang = (uint32_t)a;
}

void fx_polar(int32_t x, int32_t y, uint32_t *ang, int32_t *len, int32_t *cx, int32_t *cy)
{
    int32_t big;
    int oct;
    uint32_t t = polar_ratio(x, y, &big, &oct);
    polar_finish(t, big, oct, ang, len, cx, cy);
}

/* ---- spatial index ------------------------------------------------------------------- */
static inline int32_t max32(int32_t a, int32_t b)
{
    return a > b ? a : b;
}

static inline int32_t min32(int32_t a, int32_t b)
{
    return a < b ? a : b;
}

/* Move tracker i's bit from the cells of its indexed box to those of the box x0..x1,
   y0..y1: per row, only the cells of one box and not the other change (a box that moves by
   a cell changes a column and a row, not its whole area).  An empty row range is x0 > x1. */
static void index_move(fx_state *s, int i, int32_t x0, int32_t x1, int32_t y0, int32_t y1)
{
    uint64_t bit = (uint64_t)1 << i;
    int32_t ox0 = s->box_x0[i], ox1 = s->box_x1[i], oy0 = s->box_y0[i], oy1 = s->box_y1[i];
    int32_t ylo = min32(oy0, y0), yhi = max32(oy1, y1), y, x;
    if (ox0 > ox1 || oy0 > oy1)                           /* not indexed yet */
        ylo = y0, yhi = y1;
    for (y = ylo; y <= yhi; y++) {
        uint64_t *row = s->cells + y * s->gw;
        int old_row = y >= oy0 && y <= oy1 && ox0 <= ox1, new_row = y >= y0 && y <= y1;
        int32_t a0 = old_row ? ox0 : 0, a1 = old_row ? ox1 : -1;   /* old cells of the row */
        int32_t b0 = new_row ? x0 : 0, b1 = new_row ? x1 : -1;     /* new cells */
        for (x = a0; x <= min32(a1, b0 - 1); x++)          /* old, left of the new */
            row[x] &= ~bit;
        for (x = max32(a0, b1 + 1); x <= a1; x++)          /* old, right of the new */
            row[x] &= ~bit;
        for (x = b0; x <= min32(b1, a0 - 1); x++)          /* new, left of the old */
            row[x] |= bit;
        for (x = max32(b0, a1 + 1); x <= b1; x++)          /* new, right of the old */
            row[x] |= bit;
    }
}

static inline int32_t cell_of(int32_t v, int32_t gmax)
{
    int32_t c = v >> (16 + FX_CELL_SHIFT);                /* v Q.16 px; floor */
    return c < 0 ? 0 : (c > gmax ? gmax : c);
}

/* An upper bound of gate v (Q.32 px^2) for a variance v (Q.40, <= 2^52): the square of the
   gate box's half-width, for the spatial index (which needs a box that contains the gate
   box, not an exact one).  One 32 x 32 product: (v / 2^21 + 1) gate (Q.27) < 2^63, rounded
   up; relative excess < 2^-17 for v >= 0.25 px^2. */
static inline uint64_t gate_box2(const fx_state *s, int64_t v)
{
    return (umul((uint32_t)(v >> 21) + 1, s->gate) + 16383) >> 14;
}

/* half-width of the gate box for a variance v (Q.40), Q.16, rounded up */
static inline int32_t gate_half(const fx_state *s, int64_t v)
{
    return (int32_t)isqrt64(gate_box2(s, v)) + 1;
}

/* the variance up to which box_kept holds: 1/32 above v (sigma 1.5 % above), at most the
   clamp's sigma_max^2 (refresh never lets a variance exceed it) */
static inline int64_t var_lim(const fx_state *s, int64_t v)
{
    int64_t lim = v + (v >> 5);
    return lim < s->smax2 ? lim : s->smax2;
}

/* (Re)insert tracker i with its gate box sqrt(gate * sxx) x sqrt(gate * syy), enlarged by
   2^-FX_INDEX_GROW_SHIFT of itself and FX_INDEX_MARGIN, so that a covariance growing a
   little does not re-index at once (the index only selects candidates: any box that
   contains the gate box gives the same results). */
void fx_reindex(fx_state *s, int i)
{
    int32_t hx = gate_half(s, s->sxx[i]), hy = gate_half(s, s->syy[i]);     /* Q.16 */
    int32_t cx = pos16(s->mx[i]), cy = pos16(s->my[i]);
    int32_t x0, x1, y0, y1;
    hx += (hx >> FX_INDEX_GROW_SHIFT) + FX_INDEX_MARGIN;
    hy += (hy >> FX_INDEX_GROW_SHIFT) + FX_INDEX_MARGIN;
    s->bx_lo[i] = cx - hx;
    s->bx_hi[i] = cx + hx;
    s->by_lo[i] = cy - hy;
    s->by_hi[i] = cy + hy;
    /* box_kept's slack: while sxx <= sxx_lim the gate half-width is at most
       gate_half(sxx_lim), so the mean may move by the rest of hx (>= 0: the enlargement
       is 1/8 and 3 px, the growth allowed about 1/64) */
    s->sxx_lim[i] = var_lim(s, s->sxx[i]);
    s->syy_lim[i] = var_lim(s, s->syy[i]);
    s->bcx[i] = cx;
    s->bcy[i] = cy;
    s->devx[i] = max32(hx - gate_half(s, s->sxx_lim[i]), 0);
    s->devy[i] = max32(hy - gate_half(s, s->syy_lim[i]), 0);
    x0 = cell_of(s->bx_lo[i], s->gw - 1);
    x1 = cell_of(s->bx_hi[i], s->gw - 1);
    y0 = cell_of(s->by_lo[i], s->gh - 1);
    y1 = cell_of(s->by_hi[i], s->gh - 1);
    if (x0 != s->box_x0[i] || x1 != s->box_x1[i] || y0 != s->box_y0[i] || y1 != s->box_y1[i]) {
        index_move(s, i, x0, x1, y0, y1);                 /* the box covers other cells */
        s->box_x0[i] = x0;
        s->box_x1[i] = x1;
        s->box_y0[i] = y0;
        s->box_y1[i] = y1;
    }
    s->n_reindex++;
}

/* d >= h  <=>  d >= 0 and d^2 >= h^2 (h^2 = g2, Q.32); d is Q.16 */
static inline int inside(int32_t d, uint64_t g2)
{
    return d >= 0 && (uint64_t)smul(d, d) >= g2;
}

/* 1 if tracker i's gate box lies inside its indexed box (the exact test, for
   fx_check_index) */
static inline int box_ok(const fx_state *s, int i)
{
    /* positions to Q.16 (floor): an error < 2^-16 px, far inside the 3 px index margin;
       both sides of an axis are inside iff the nearer one is (one square per axis) */
    int32_t x = pos16(s->mx[i]), y = pos16(s->my[i]);
    return inside(min32(x - s->bx_lo[i], s->bx_hi[i] - x), gate_box2(s, s->sxx[i]))
        && inside(min32(y - s->by_lo[i], s->by_hi[i] - y), gate_box2(s, s->syy[i]));
}

/* 1 if tracker i's mean and variances are still within the slack fx_reindex noted: a
   sufficient test for box_ok, four comparisons (the exact one needs the gate box of the
   current variances, two products and two squares) */
static inline int box_kept(const fx_state *s, int i)
{
    int32_t dx = pos16(s->mx[i]) - s->bcx[i], dy = pos16(s->my[i]) - s->bcy[i];
    return (dx < 0 ? -dx : dx) <= s->devx[i] && (dy < 0 ? -dy : dy) <= s->devy[i]
        && s->sxx[i] <= s->sxx_lim[i] && s->syy[i] <= s->syy_lim[i];
}

/* Re-index tracker i if its gate box may have left the box it is indexed with. */
static inline void check_index(fx_state *s, int i)
{
    if (!box_kept(s, i))
        fx_reindex(s, i);
}

/* 1 if every tracker's gate box lies inside its indexed box and its bit is set in every
   cell of that box (tests). */
int fx_check_index(const fx_state *s)
{
    int i, cx, cy;
    for (i = 0; i < s->n; i++) {
        if (!box_ok(s, i))
            return 0;
        for (cy = s->box_y0[i]; cy <= s->box_y1[i]; cy++)
            for (cx = s->box_x0[i]; cx <= s->box_x1[i]; cx++)
                if (!((s->cells[cy * s->gw + cx] >> i) & 1))
                    return 0;
    }
    return 1;
}

/* ---- per tracker --------------------------------------------------------------------- */

/* round(v / 2^k) of 0 < v < 2^62 into a mantissa, k >= 1 */
static inline int32_t mant(int64_t v, int k)
{
    return (int32_t)rshr(v, k);
}

/* [ref] _clamp_and_invert: sigma_x, sigma_y in [sigma_min, sigma_max], |rho| <= 0.99,
   then the inverse covariance of eq. (2) as three mantissas with the tracker's exponent,
   and the shifts that put a candidate's offset and d^2 in 32 bits.  One 64 / 32
   division (a reciprocal).

   Block scaling: a, b, c = sxx, sxy, syy >> sh with the larger variance in [2^30, 2^31),
   so sigma_big^2 is in [2^(sh-10), 2^(sh-9)) px^2 and every product below is 32 x 32.
   det = ac - b^2 = m 2^e with m in [2^30, 2^31); r = floor(2^61 / m); then ia = syy / det
   = c r 2^(-21 - sh - e) px^-2 (Q.40 covariances), and likewise ic, ib.  The mantissas
   are the high words ia_m = c r / 2^32 (max(a, c) r < 2^62, so max(ia_m, ic_m) <= 2^30
   and |ib2_m| = |2 b r / 2^32| < 2^31), with f = sh + e - 11 fraction bits.

   Offsets are taken as u = (Q.32 offset) >> osh, osh = max(2, ceil((sh - 1) / 2) + 1):
   |u| < 2^31 covers |offset| < 2^(osh-1) px >= 16 sigma_big (and >= 2 px), and an offset
   whose whole pixels reach 2^(osh-1) is clamped: then |offset| > 2^(osh-1) - 1 px >= 8
   sigma_big + 1 px and d^2 > 64 sigma_big^2 / (2 sigma_big^2) = 32, beyond any gate
   (<= 31), so clamping decides nothing.  d^2 (Q.27) = (sum of mantissa u u / 2^32
   terms) >> dsh, dsh = f + 5 - 2 osh, which is e - 8 or e - 7 <= 24; kept >= 1 so that the
   shift works on 32-bit words. */
static inline void refresh(fx_state *s, int i)
{
    int64_t sxx = s->sxx[i], syy = s->syy[i], sxy = s->sxy[i], big, p, bb, det;
    int32_t a, b, c, sh, e, osh, dsh, f;
    uint32_t m, r, rem;
    sxx = sxx < s->smin2 ? s->smin2 : (sxx > s->smax2 ? s->smax2 : sxx);
    syy = syy < s->smin2 ? s->smin2 : (syy > s->smax2 ? s->smax2 : syy);
    big = sxx > syy ? sxx : syy;
    sh = bitlen64((uint64_t)big) - 31;
    if (sh < 0)
        sh = 0;
    a = (int32_t)(sxx >> sh);
    c = (int32_t)(syy >> sh);
    if (sxy > big)                                        /* |sxy| <= max keeps b^2 < 2^62 */
        sxy = big;
    if (sxy < -big)
        sxy = -big;
    b = (int32_t)(sxy >> sh);
    p = smul(a, c);
    bb = smul(b, b);
    /* |rho| > 0.99: clamp (b^2 <= p - p / 32 < 0.99^2 p: certainly not, without the product) */
    if (bb > p - (p >> 5) && bb > mulsh(p, RHO2_Q30, 30)) {
        /* 0.99 sqrt(sxx syy) = 0.99 sqrt(a c) 2^sh, Q.40, 31 significant bits */
        int64_t lim = mulsh(shl64((int64_t)isqrt64((uint64_t)p), sh), RHO_Q30, 30);
        sxy = sxy < 0 ? -lim : lim;
        b = (int32_t)(sxy >> sh);
        bb = smul(b, b);
    }
    s->sxx[i] = sxx;
    s->sxy[i] = sxy;
    s->syy[i] = syy;
    det = p - bb;                                         /* > 0.0199 p */
    if (det <= 0) {                                       /* cannot happen: |rho| <= 0.99 */
        det = 1;
        s->sat_inverse++;
    }
    e = bitlen64((uint64_t)det) - 31;
    m = (uint32_t)(e >= 0 ? det >> e : shl64(det, -e));
    r = divlu((uint32_t)1 << 29, 0, m, &rem);            /* 2^61 / m in (2^30, 2^31] */
    if (r > 0x7fffffffu)
        r = 0x7fffffffu;
    f = sh + e - 11;                                      /* 21 + sh + e - 32 */
    osh = sh > 3 ? sh / 2 + 1 : 2;                        /* ceil((sh - 1) / 2) + 1, >= 2 */
    dsh = f + 5 - 2 * osh;                                /* <= 24 (e <= 31) */
    if (dsh >= 1) {                                       /* mantissas: the products' high words */
        s->ia[i] = (int32_t)((umul((uint32_t)c, r) + 0x80000000u) >> 32);
        s->ic[i] = (int32_t)((umul((uint32_t)a, r) + 0x80000000u) >> 32);
        s->ib2[i] = -(int32_t)((smul(b, (int32_t)r) + 0x40000000) >> 31);
    } else {                      /* sigma_x / sigma_y beyond ~290 only: fewer bits, dsh = 1 */
        s->ia[i] = mant((int64_t)umul((uint32_t)c, r), 33 - dsh);
        s->ic[i] = mant((int64_t)umul((uint32_t)a, r), 33 - dsh);
        s->ib2[i] = -mant(smul(b, (int32_t)r), 32 - dsh);
        dsh = 1;
    }
    s->osh[i] = (uint8_t)osh;
    s->dsh[i] = (uint8_t)dsh;
}

void fx_refresh(fx_state *s, int i)
{
    refresh(s, i);
}

/* floor((v 2^32 - m) / 2^sh) for a pixel v and a Q.32 position m, 2 <= sh <= 31, in 32-bit
   arithmetic: with m = h 2^32 + l and d = v - h, it is the floor of d 2^32 - l; when
   |d| >= 2^(sh-1) it is clamped to +-(2^31 - 1) (the clamp decides nothing, see refresh) */
static inline int32_t offset32(int32_t v, int64_t m, int sh)
{
    int32_t d = v - (int32_t)(m >> 32);
    uint32_t l = (uint32_t)m, lim = 1u << (sh - 1), lo, hi;
    if ((uint32_t)d + lim >= 2 * lim)
        return d < 0 ? -0x7fffffff : 0x7fffffff;
    lo = 0u - l;                                          /* d 2^32 - l = hi 2^32 + lo */
    hi = (uint32_t)d - (l != 0);
    return (int32_t)((lo >> sh) | (hi << (32 - sh)));     /* its floor by 2^sh: fits int32 */
}

/* Mahalanobis d^2 = ia dx^2 + ib2 dx dy + ic dy^2 (eq. 2), Q.27, saturated at 2^32 - 1,
   of pixel (x, y) from tracker i: five 32 x 32 products (|pa|, |pc| <= 2^29, |pb| <= 2^30,
   |q| < 2^62); rounding: 2^-24 of d^2 from the mantissas plus up to |u| + 2|v| units of q
   from the floors of pa, pb, pc (docs/fixed_point.md) */
static inline uint32_t qform(const fx_state *s, int i, int32_t x, int32_t y)
{
    int sh = s->osh[i];
    int32_t u = offset32(x, s->mx[i], sh), v = offset32(y, s->my[i], sh);
    int32_t pa = (int32_t)(smul(s->ia[i], u) >> 32);
    int32_t pb = (int32_t)(smul(s->ib2[i], u) >> 32);
    int32_t pc = (int32_t)(smul(s->ic[i], v) >> 32);
    int64_t q = smul(pa, u) + smul(pb + pc, v);
    int k = s->dsh[i];                                    /* 1 .. 24 */
    if (q <= 0)
        return 0;
#if FX_WORD64
    q >>= k;
    return q > (int64_t)D2_SAT ? D2_SAT : (uint32_t)q;
#else
    {                                                     /* the same in 32-bit words */
        uint32_t hi = (uint32_t)((uint64_t)q >> 32), lo = (uint32_t)q;
        if (hi >> k)                                      /* q >> k >= 2^32 */
            return D2_SAT;
        return (lo >> k) | (hi << (32 - k));
    }
#endif
}

uint32_t fx_d2(const fx_state *s, int i, int32_t x, int32_t y)
{
    return qform(s, i, x, y);
}

/* [ref] _update: eqs. (2)-(6) for the winning tracker i; dx, dy Q.32 from the pre-update
   mean (|.| < 2^41 inside the gate), d2 Q.27. */
static __attribute__((noinline)) void update_tracker(fx_state *s, int i, int64_t t, int64_t dx,
                                                   int64_t dy, uint32_t d2)
{
    int64_t p = gauss(d2);                                /* eq. (2), Q.30 */
    int64_t act = mulsh(s->act[i], decay(s, t - s->tlast[i]), 30) + p * 4;  /* eq. (6) */
    int32_t ex = (int32_t)rshr(dx, 12), ey = (int32_t)rshr(dy, 12);    /* Q.20 px, < 2^29 */
    if (act > ACT_MAX) {
        act = ACT_MAX;
        s->sat_activity++;
    }
    s->act[i] = act;
    s->tlast[i] = t;
    /* eq. (3): m + round(a1 (u - m)) with 0 <= a1 <= 1 lies between m and the event u, both
       inside +-FX_POS_LIM: it cannot saturate */
    s->mx[i] += mulsh(dx, s->a1, 30);
    s->my[i] += mulsh(dy, s->a1, 30);
    /* eq. (4)-(5): S <- (1 - a2) S + g e e^T, e = (dx, dy); ex ex is Q.40 px^2 */
    s->sxx[i] = ema(s->sxx[i], smul(ex, ex), s->cov_gm, s->cov_am, s->cov_sh);
    s->sxy[i] = ema(s->sxy[i], smul(ex, ey), s->cov_gm, s->cov_am, s->cov_sh);
    s->syy[i] = ema(s->syy[i], smul(ey, ey), s->cov_gm, s->cov_am, s->cov_sh);
    refresh(s, i);
    check_index(s, i);
}

/* eq. (2) for candidate i: it becomes the best if its d^2 is below the best so far */
static inline __attribute__((always_inline)) void candidate(const fx_state *s, int i, int32_t x,
                                                            int32_t y, uint32_t *best_d2,
                                                            int *best)
{
    uint32_t d2 = qform(s, i, x, y);
    if (d2 < *best_d2) {
        *best_d2 = d2;
        *best = i;
    }
}

/* eq. (2) for one valid event at pixel (x, y): the sensitive trackers indexed in the
   event's cell (mask), in index order, so ties resolve as in the reference's full scan.
   Returns the best tracker within the gate (its d^2 in *best_d2, which holds the gate on
   entry) or FX_NO_TRACKER. */
static inline __attribute__((always_inline)) int search(const fx_state *s, uint64_t mask,
                                                        int32_t x, int32_t y, uint32_t *best_d2)
{
    uint64_t m = s->cells[(y >> FX_CELL_SHIFT) * s->gw + (x >> FX_CELL_SHIFT)] & mask;
    int best = FX_NO_TRACKER;
#if FX_WORD64
    while (m) {                                           /* index order: ties as the reference */
        int i = __builtin_ctzll(m);
        m &= m - 1;
        candidate(s, i, x, y, best_d2, &best);
    }
#else
    /* the mask's 32-bit halves in turn (low bits first: the same order), and a build for
       at most 32 trackers has only the first */
    int half;
    for (half = 0; half < (FX_MAX_TRACKERS > 32 ? 2 : 1); half++) {
        uint32_t w = (uint32_t)(m >> (32 * half));
        while (w) {
            int i = __builtin_ctz(w) + 32 * half;
            w &= w - 1;
            candidate(s, i, x, y, best_d2, &best);
        }
    }
#endif
    return best;
}

/* eqs. (3)-(6) for the winner `best` of eq. (2) (its d^2 given) */
static inline __attribute__((always_inline)) void take(fx_state *s, int best, int64_t t,
                                                      int32_t x, int32_t y, uint32_t d2)
{
    update_tracker(s, best, t, shl64(x, FX_POS_FRAC) - s->mx[best],
                   shl64(y, FX_POS_FRAC) - s->my[best], d2);
}

/* eq. (2) and eqs. (3)-(6) for one valid event at pixel (x, y): the winner is updated.
   Returns the winner or FX_NO_TRACKER. */
static inline __attribute__((always_inline)) int assign(fx_state *s, uint64_t mask, int64_t t,
                                                        int32_t x, int32_t y)
{
    uint32_t best_d2 = s->gate;
    int best = search(s, mask, x, y, &best_d2);
    if (best >= 0)
        take(s, best, t, x, y, best_d2);
    return best;
}

/* One event (Algorithm 1).  Returns the winning tracker, FX_NO_TRACKER or a skip code. */
int fx_step(fx_state *s, int64_t t, int32_t x, int32_t y)
{
    int best;
    if (t < s->last_t) {
        s->n_back++;
        return FX_BACK_IN_TIME;
    }
    s->last_t = t;
    if (x >= s->width || y >= s->height || x < 0 || y < 0) {
        s->n_outside++;
        return FX_OUT_OF_SENSOR;
    }
    s->n_valid++;
    best = assign(s, s->sensitive_mask, t, x, y);
    if (best >= 0)
        s->n_assigned++;
    if (++s->since_spring >= s->period) {
        s->since_spring = 0;
        fx_springs(s);
    }
    return best;
}

/* the batch loop of fx_steps (g NULL: state s) and fx_set_steps (the set g), the event
   counters, the clock and (for s) the sensitive mask kept in registers (the springs are
   the only other writer of the mask); inlined into each, so g's tests vanish */
typedef struct {
    int64_t k, last_t;
    int32_t until, n_assigned, n_skipped, n_back;
} batch;

static inline __attribute__((always_inline)) int set_assign(fx_set *g, int64_t t, int32_t x,
                                                            int32_t y);

static inline __attribute__((always_inline)) batch steps_loop(fx_state *s, fx_set *g,
                                                            const fx_event *ev, int64_t n,
                                                            int64_t t_stop, int64_t last_t,
                                                            int32_t since_spring)
{
    const fx_state *s0 = g ? g->inst[0] : s;
    uint32_t width = (uint32_t)s0->width, height = (uint32_t)s0->height;
    int32_t period = s0->period;
    batch o = {0, last_t, period - since_spring, 0, 0, 0};   /* until >= 1 */
    uint64_t mask = g ? 0 : s->sensitive_mask;
    for (o.k = 0; o.k < n; o.k++) {
        int64_t t = ev[o.k].t;
        uint32_t x = ev[o.k].x, y = ev[o.k].y;
        if (st_sample_due(t, t_stop, o.last_t))
            break;
        if (t < o.last_t) {
            o.n_back++;
            continue;
        }
        o.last_t = t;
        if (x >= width || y >= height) {
            o.n_skipped++;
            continue;
        }
        if (g)
            o.n_assigned += set_assign(g, t, (int32_t)x, (int32_t)y) >= 0;
        else
            o.n_assigned += assign(s, mask, t, (int32_t)x, (int32_t)y) >= 0;
        if (--o.until <= 0) {
            o.until = period;
            if (g) {
                fx_set_springs(g);
            } else {
                fx_springs(s);
                mask = s->sensitive_mask;
            }
        }
    }
    return o;
}

/* fx_step over a batch */
int64_t fx_steps(fx_state *s, const fx_event *ev, int64_t n, int64_t t_stop)
{
    batch o = steps_loop(s, 0, ev, n, t_stop, s->last_t, s->since_spring);
    s->last_t = o.last_t;
    s->since_spring = s->period - o.until;
    s->n_valid += o.k - o.n_back - o.n_skipped;
    s->n_assigned += o.n_assigned;
    s->n_back += o.n_back;
    s->n_outside += o.n_skipped;
    return o.k;
}

/* ---- several model instances (springtrack.instances) ---------------------------------
   One fx_state per instance: its trackers, connections, gains, criteria, springs,
   energies, centre of mass and similarity frame are its own.  The set runs one event
   assignment over all of them, one clock and one spring period. */

/* [ref] step, eq. (2) over the union: each tracking instance's best tracker in turn, one
   starting from the best d^2 so far so that only a strictly smaller one wins (ties: the
   lowest instance, and in it the lowest index, as the reference's scan over all
   trackers); the winner is updated (eqs. 3-6).  Returns its index among all trackers. */
static inline __attribute__((always_inline)) int set_assign(fx_set *g, int64_t t, int32_t x,
                                                            int32_t y)
{
    uint32_t best_d2 = g->inst[0]->gate;                  /* p_threshold: one for all */
    int best = FX_NO_TRACKER, owner = 0, q;
    for (q = 0; q < g->ni; q++) {
        const fx_state *s = g->inst[q];
        uint32_t d2 = best_d2;
        int i;
        if (g->state[q] != FX_TRACKING)
            continue;
        i = search(s, s->sensitive_mask, x, y, &d2);
        if (i >= 0) {
            best = i;
            best_d2 = d2;
            owner = q;
        }
    }
    if (best < 0)
        return FX_NO_TRACKER;
    take(g->inst[owner], best, t, x, y, best_d2);
    return g->t0[owner] + best;
}

/* [ref] springs: every tracking instance's springs and criteria (eqs. 7-22) and its guard */
void fx_set_springs(fx_set *g)
{
    int q;
    g->n_spring_updates++;
    for (q = 0; q < g->ni; q++)
        if (g->state[q] == FX_TRACKING)
            fx_springs(g->inst[q]);
}

/* the set's clock and event counts, copied into every instance (fx_set_params reads them) */
static void set_sync(fx_set *g)
{
    int q;
    for (q = 0; q < g->ni; q++) {
        fx_state *s = g->inst[q];
        s->last_t = g->last_t;
        s->n_valid = g->n_valid;
        s->n_back = g->n_back;
        s->n_outside = g->n_outside;
    }
}

int fx_set_step(fx_set *g, int64_t t, int32_t x, int32_t y)
{
    const fx_state *s0 = g->inst[0];
    int best;
    if (t < g->last_t) {
        g->n_back++;
        set_sync(g);
        return FX_BACK_IN_TIME;
    }
    g->last_t = t;
    if (x >= s0->width || y >= s0->height || x < 0 || y < 0) {
        g->n_outside++;
        set_sync(g);
        return FX_OUT_OF_SENSOR;
    }
    g->n_valid++;
    set_sync(g);
    best = set_assign(g, t, x, y);
    if (best >= 0)
        g->n_assigned++;
    if (++g->since_spring >= s0->period) {
        g->since_spring = 0;
        fx_set_springs(g);
    }
    return best;
}

/* fx_steps for a set: the same loop, the sampling rule's stop included */
int64_t fx_set_steps(fx_set *g, const fx_event *ev, int64_t n, int64_t t_stop)
{
    batch o = steps_loop(0, g, ev, n, t_stop, g->last_t, g->since_spring);
    g->last_t = o.last_t;
    g->since_spring = g->inst[0]->period - o.until;
    g->n_valid += o.k - o.n_back - o.n_skipped;
    g->n_assigned += o.n_assigned;
    g->n_back += o.n_back;
    g->n_outside += o.n_skipped;
    set_sync(g);
    return o.k;
}

/* Instance q's state (springtrack.instances.InstanceState): a tracking instance's
   trackers are all sensitive (the next spring update decides eq. 21 again), the others'
   none, and only tracking instances take events and run their springs. */
void fx_set_state(fx_set *g, int q, int32_t state)
{
    fx_state *s = g->inst[q];
    g->state[q] = state;
    s->sensitive_mask = state != FX_TRACKING ? 0
                        : s->n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << s->n) - 1;
}

/* A set of the ni loaded states inst[0..ni), all tracking, the clock and counts zero. */
int fx_set_init(fx_set *g, fx_state *const *inst, int32_t ni)
{
    int32_t q, t0 = 0, c = 0;
    if (ni < 1 || ni > FX_MAX_INSTANCES)
        return FX_ERR_CAPACITY;
    for (q = 0; q < ni; q++) {
        t0 += inst[q]->n;
        c += inst[q]->nc;
        if (inst[q]->width != inst[0]->width || inst[q]->height != inst[0]->height)
            return FX_ERR_RANGE;
    }
    if (t0 > FX_MAX_SET_TRACKERS || c > FX_MAX_SET_CONNECTIONS)
        return FX_ERR_CAPACITY;
    g->ni = ni;
    g->since_spring = 0;
    g->last_t = -((int64_t)1 << 62);
    g->n_valid = g->n_assigned = g->n_back = g->n_outside = g->n_spring_updates = 0;
    for (q = 0, t0 = 0; q < ni; q++) {
        g->inst[q] = inst[q];
        g->t0[q] = t0;
        t0 += inst[q]->n;
        fx_set_state(g, q, FX_TRACKING);
    }
    return FX_OK;
}

/* eq. (6) evaluated lazily at time t, Q.32 */
int64_t fx_activity(const fx_state *s, int i, int64_t t)
{
    return mulsh(s->act[i], decay(s, t - s->tlast[i]), 30);
}

/* ---- springs and energy criteria (every `period` events) -----------------------------
   The criteria of eqs. (21)-(22) compare each connection's energy with s times their mean:
   a decision taken the other way than by the float64 kernel moves a tracker by up to
   energy_gain times its distance to its target, so the energies are computed to about
   1e-9 px of the exact ones of the kernel's own positions (dl and the Cartesian offsets
   e in Q.32 from the Q.32 spring vectors and rest geometry; energies Q.40), while the
   spring geometry that only sets directions and angles stays Q.16. */
#define OFFSET_LIM ((int32_t)1 << 30)                     /* 16384 px in Q.16 */
#define FINE_LIM ((int64_t)1 << 38)                       /* 64 px in Q.32: Q.24 fits int32 */

static inline int32_t clamp_offset(int64_t v)
{
    return (int32_t)(v >= OFFSET_LIM ? OFFSET_LIM - 1 : (v <= -OFFSET_LIM ? -OFFSET_LIM + 1 : v));
}

/* |v| < 64 px (Q.32): then v is taken in Q.24 (int32) */
static inline int fine(int64_t v)
{
    return v < FINE_LIM && v > -FINE_LIM;
}

static inline void frame_offset(const fx_state *s, int k, int64_t *ox, int64_t *oy);

/* the offsets e = r - d0 of eq. (18) of connection k (Q.32) from its spring vector r
   (Q.32).  The rest offset d0 is (dx0, dy0), or s R (dx0, dy0) (frame_offset) if the
   spring update computing the energies used the similarity frame. */
static inline void offsets(const fx_state *s, int k, int64_t rx, int64_t ry, int64_t *ex,
                           int64_t *ey)
{
    int64_t ox = s->dx0[k], oy = s->dy0[k];
    if (s->car_turned)
        frame_offset(s, k, &ox, &oy);
    *ex = rx - ox;                                        /* |.| < 2^50 */
    *ey = ry - oy;
}

/* an offset beyond 64 px in Q.16, clamped to +-16384 px */
static inline int32_t offset16(int64_t e)
{
    return clamp_offset(rshr(e, 16));
}

/* how many of the offsets (Q.32) offset16 clamps */
static inline int clamped(int64_t ex, int64_t ey)
{
    const int64_t lim = shl64(OFFSET_LIM, 16) - ((int64_t)1 << 15);   /* rshr reaches 2^30 */
    return (ex >= lim || ex < -lim) + (ey >= lim || ey < -lim);
}

/* eq. (10): dl = l - l0 (Q.32) of connection k from its spring vector r (Q.32) and the
   direction c = (cx, cy) (Q.30) of the spring geometry, l~ its length (Q.16).  The tables
   give c within ~2e-7 of unit length (|c| = 1 + eps), in the direction of r's Q.16
   rounding (an angle a < 2^-17 px / l), so l = r.c / |c| = r.c (3 - |c|^2) / 2 to
   O(eps^2 + a^2) (< 1e-11 px for l >= 0.1 px), without a division: r.c from the high 16.16
   halves h of r and the 16-bit rests (r = h 2^16 + e; Q.46, |.| < 2^61), |c|^2 in Q.60,
   the factor (3 - |c|^2) / 2 in Q.30 and one mulsh. */
static inline __attribute__((always_inline)) int64_t spring_dl(const fx_state *s, int k,
                                                               int64_t rx, int64_t ry, int32_t l,
                                                               int32_t cx, int32_t cy)
{
    int32_t hx = (int32_t)(rx >> 16), hy = (int32_t)(ry >> 16);      /* |.| < 2^30 */
    int32_t ex = (int32_t)(rx & 0xffff), ey = (int32_t)(ry & 0xffff);
    int64_t dot, cc;
    uint32_t f;
    if (l <= 0)                                           /* |r| < 2^-16 px */
        return -s->l0[k];
    dot = smul(hx, cx) + smul(hy, cy) + ((smul(ex, cx) + smul(ey, cy)) >> 16);   /* Q.46 */
    cc = smul(cx, cx) + smul(cy, cy);                     /* |c|^2, Q.60 (< 2^61) */
    f = (uint32_t)((((int64_t)3 << 60) - cc) >> 31);      /* (3 - |c|^2) / 2, Q.30 */
    return mulsh(dot, f, 44) - s->l0[k];                  /* Q.46 x Q.30 / 2^44 = Q.32 */
}

/* eq. (11): the Euclidean force a dl r / l (Q.32) of connection k, from dl (Q.32) and the
   direction (cx, cy) (Q.30): a dl in Q.30 when |a dl| < 2 px (single products), else from
   dl in Q.16 */
static inline __attribute__((always_inline)) void euclid_force(const fx_state *s, int k,
                                                               int64_t dl, int32_t cx,
                                                               int32_t cy, int64_t *fx,
                                                               int64_t *fy)
{
    int32_t a = (int32_t)s->stiff[k], d;
    if (fine(dl)) {
        int64_t adl = smul((int32_t)rshr(dl, 8), a);      /* Q.24 x Q.30 = Q.54 */
        if (adl < ((int64_t)1 << 55) && adl > -((int64_t)1 << 55)) {
            int32_t q = (int32_t)rshr(adl, 24);           /* a dl, Q.30 */
            *fx = rshr(smul(q, cx), 28);
            *fy = rshr(smul(q, cy), 28);
            return;
        }
    }
    d = clamp_offset(rshr(dl, 16));                       /* Q.16 (|dl| < 16384 px) */
    *fx = mulsh(rshr(smul(d, cx), 14), (uint32_t)a, 30);  /* dl r / l, Q.32, times a */
    *fy = mulsh(rshr(smul(d, cy), 14), (uint32_t)a, 30);
}

/* a |d|^2 / 2 in Q.40 for the squared length q of d in Q.32 px^2 (offsets beyond 64 px):
   beyond 2^21 px^2 it is E_MAX (the caller counts it) */
static inline int64_t energy_wide(const fx_state *s, int k, int64_t q)
{
    int64_t e = mulsh(q, s->stiff[k], 31);                /* Q.32, < 2^61 */
    return e >= ((int64_t)1 << 53) ? E_MAX + 1 : shl64(e, 8);
}

/* energies of connection k (Q.40): eq. (12) a dl^2 / 2 from dl (Q.32); eq. (17) a dtheta^2
   / 2 from the corrected angle (binary); eq. (20) a |e|^2 / 2 from the offsets (Q.32),
   each from Q.24 values (products < 2^62) below 64 px */
static inline int64_t energy_euclid(const fx_state *s, int k, int64_t dl)
{
    int32_t d;
    if (fine(dl)) {
        d = (int32_t)rshr(dl, 8);                         /* Q.24 */
        return mulsh(smul(d, d), s->stiff[k], 39);        /* Q.48 x Q.30 / 2^39 = Q.40 */
    }
    d = clamp_offset(rshr(dl, 16));
    return energy_wide(s, k, smul(d, d));
}

static inline int64_t energy_torsion(const fx_state *s, int k, int64_t dth)
{
    int32_t dq = (int32_t)mulsh(dth, PI_Q28, 31);         /* radians, Q.28; |.| < 2^31 */
    return mulsh(smul(dq, dq), s->stiff[k], 47);          /* Q.56 x Q.30 / 2^47 = Q.40 */
}

static inline int64_t energy_cart(const fx_state *s, int k, int64_t ex, int64_t ey)
{
    int32_t x, y;
    if (fine(ex) && fine(ey)) {
        x = (int32_t)rshr(ex, 8);                         /* Q.24 */
        y = (int32_t)rshr(ey, 8);
        return mulsh(smul(x, x) + smul(y, y), s->stiff[k], 39);
    }
    x = offset16(ex);
    y = offset16(ey);
    return energy_wide(s, k, smul(x, x) + smul(y, y));
}

/* eq. (19): the Cartesian force a e (Q.32) of connection k */
static inline void cart_force(const fx_state *s, int k, int64_t ex, int64_t ey, int64_t *fx,
                              int64_t *fy)
{
    int32_t a = (int32_t)s->stiff[k];
    if (fine(ex) && fine(ey)) {                           /* Q.24 x Q.30 -> Q.32 */
        *fx = rshr(smul((int32_t)rshr(ex, 8), a), 22);
        *fy = rshr(smul((int32_t)rshr(ey, 8), a), 22);
    } else {                                              /* Q.16 x Q.30 -> Q.32 */
        *fx = rshr(smul(offset16(ex), a), 14);
        *fy = rshr(smul(offset16(ey), a), 14);
    }
}

/* Eq. (14) and the polar form of a spring vector r (Q.16), in two steps so that the spring
   pass can issue all the divisions first (they then overlap).  In the connection's rest
   frame, (u, v) = (c0 . r, c0 x r) rounded to Q.18 (finer than r, so that this rotation
   adds no error of note), with c0 = (cos th0, sin th0) (Q.30): when |v| <= u < 2^31 (r
   within 45 degrees of its rest direction, the usual case) the angle from rest is atan(t),
   t = |v| / u (Q.28, 2 zero bits added), the direction r / |r| is c0 rotated by it, and
   |r| = u cos + |v| sin of it, from the tables of atan and 1 / sqrt(1 + t^2); otherwise the
   polar form of r itself minus th0, wrapped to [-pi, pi).  Both: one division. */
typedef struct {
    uint32_t t;
    int32_t u, v;                                         /* u <= 0: polar form, octant -u */
} spring_ratio;

static inline __attribute__((always_inline)) spring_ratio geom_ratio(const fx_state *s, int k,
                                                                     int32_t rx, int32_t ry)
{
    spring_ratio g;
    int64_t u = rshr(smul(s->c0x[k], rx) + smul(s->c0y[k], ry), 28);   /* Q.18, < 2^33 */
    int64_t v = rshr(smul(s->c0x[k], ry) - smul(s->c0y[k], rx), 28);
    int64_t av = v < 0 ? -v : v;
    int oct;
    if (u > 0 && av <= u && u < ((int64_t)1 << 31)) {
        uint32_t rem;
        g.u = (int32_t)u;
        g.v = (int32_t)v;
        g.t = divlu((uint32_t)av >> 4, (uint32_t)av << 28, (uint32_t)u, &rem) << 2;  /* [0, 2^30] */
        return g;
    }
    g.t = polar_ratio(rx, ry, &g.v, &oct);                /* v = max(|x|, |y|) */
    g.u = -oct;                                           /* <= 0: the octant */
    return g;
}

/* the angle from rest (binary angle, [-pi, pi)), the length (Q.16) and direction (Q.30) */
static inline __attribute__((always_inline)) int32_t geom_finish(const fx_state *s, int k,
                                                                 spring_ratio g, int32_t *l,
                                                                 int32_t *cx, int32_t *cy)
{
    if (g.u > 0) {
        int32_t a = unit_interp(FX_ATAN_TAB, g.t);
        int32_t h = unit_interp(FX_IHYP_TAB, g.t);        /* cos of the angle */
        int32_t sn = (int32_t)rshr((int64_t)umul(g.t, (uint32_t)h), 30);   /* |sin| */
        int32_t sg = g.v >> 31;                           /* -1 if v < 0: a mask, the sign */
        *l = (int32_t)rshr(smul(g.u, h) + smul((g.v ^ sg) - sg, sn), 32);  /* of a spring is */
        a = (a ^ sg) - sg;                                /* data the branch predictor */
        sn = (sn ^ sg) - sg;                              /* cannot learn */
        *cx = (int32_t)rshr(smul(s->c0x[k], h) - smul(s->c0y[k], sn), 30);
        *cy = (int32_t)rshr(smul(s->c0y[k], h) + smul(s->c0x[k], sn), 30);
        return a;
    } else {
        uint32_t th;
        polar_finish(g.t, g.v, -g.u, &th, l, cx, cy);
        return (int32_t)(th - s->th0[k]);                 /* mod 2^32 = mod 2 pi */
    }
}

static inline int32_t spring_angle(const fx_state *s, int k, int32_t rx, int32_t ry, int32_t *l,
                                   int32_t *cx, int32_t *cy)
{
    return geom_finish(s, k, geom_ratio(s, k, rx, ry), l, cx, cy);
}

static inline int64_t sat_energy_of(fx_state *s, int64_t e)
{
    if (e > E_MAX) {
        s->sat_energy++;
        return E_MAX;
    }
    return e;
}

/* r = x_j - x_i of connection k, Q.32, |.| < 2^46 */
static inline void spring_vector(const fx_state *s, int k, int64_t *rx, int64_t *ry)
{
    int i = s->ca[k], j = s->cb[k];
    *rx = s->mx[j] - s->mx[i];
    *ry = s->my[j] - s->my[i];
}

/* a spring vector (Q.32) in the spring geometry's Q.16, |.| < 2^30 */
static inline int32_t geom16(int64_t r)
{
    return (int32_t)rshr(r, 16);
}

/* Eqs. (10)-(20) for every connection: the forces summed per tracker into ddx, ddy (Q.32)
   and the criterion's energy (eq. 13: each and their sum saturating at 2^21 px^2), which
   is returned.  `used` = the kinds whose geometry the model needs (its springs' kinds and
   the criterion's); each instantiation below contains only that geometry.
   Structure of arrays, one short step per pass: the connections are independent, and a
   pass whose iterations are short lets an out-of-order processor overlap many of them (a
   32-bit in-order core does the first two passes as one). */
static inline __attribute__((always_inline)) int64_t spring_passes(fx_state *s, const int used,
                                                                   int64_t *ddx, int64_t *ddy)
{
    int nc = s->nc, ek = s->ekind, k, sat = 0;
    int64_t fx[FX_MAX_CONNECTIONS], fy[FX_MAX_CONNECTIONS];
    int32_t dth[FX_MAX_CONNECTIONS];
    int64_t total = 0, mean_dth = 0;
    int64_t *en = s->energy[ek];
    int64_t *grx = s->grx, *gry = s->gry;
    if (used & 3) {
        int64_t sum = 0;
        spring_ratio g[FX_MAX_CONNECTIONS];
#if FX_WORD64
        /* an out-of-order host: r and all the divisions first, so that they overlap */
        for (k = 0; k < nc; k++) {
            spring_vector(s, k, &grx[k], &gry[k]);
            g[k] = geom_ratio(s, k, geom16(grx[k]), geom16(gry[k]));
        }
#endif
        for (k = 0; k < nc; k++) {
            int32_t l, cx, cy;
#if !FX_WORD64
            /* an in-order core: one pass (the same operations per connection) */
            spring_vector(s, k, &grx[k], &gry[k]);
            g[k] = geom_ratio(s, k, geom16(grx[k]), geom16(gry[k]));
#endif
            dth[k] = geom_finish(s, k, g[k], &l, &cx, &cy);   /* eq. (14) */
            sum += dth[k];
            fx[k] = fy[k] = 0;
            if (used & 1) {
                int64_t dl = spring_dl(s, k, grx[k], gry[k], l, cx, cy);   /* eq. (10) */
                if (s->kinds[k] & 1) {                    /* eq. (11): a dl (r / l) */
                    if (l <= 0) {
                        cx = s->c0x[k];
                        cy = s->c0y[k];
                    }
                    euclid_force(s, k, dl, cx, cy, &fx[k], &fy[k]);
                }
                if (ek == 0) {                            /* eq. (12), the criterion's */
                    en[k] = sat_energy_of(s, energy_euclid(s, k, dl));
                    total = sat_add(s, total, en[k], E_MAX);
                }
            }
        }
        if ((used & 2) && nc > 0)
            mean_dth = div_round(sum, (uint32_t)nc);      /* eq. (15) */
    } else {
        for (k = 0; k < nc; k++) {                        /* r = x_j - x_i, Q.32 */
            spring_vector(s, k, &grx[k], &gry[k]);
            fx[k] = fy[k] = 0;
        }
    }
    for (k = 0; k < nc; k++) {
        int i = s->ca[k], j = s->cb[k], kind = s->kinds[k];
        int64_t d = 0, gx = fx[k], gy = fy[k], ex = 0, ey = 0;
        uint32_t a = s->stiff[k];
        if (used & 2) {
            d = dth[k] - mean_dth;                        /* eq. (15), binary angle */
            if (kind & 2) {                               /* eq. (16): rotate r by a d */
                int32_t c, sn, rx = geom16(grx[k]), ry = geom16(gry[k]);
                rotation(mulsh(d, a, 30), &c, &sn);       /* cos - 1, sin */
                gx += rshr(smul(rx, c) - smul(ry, sn), 14);   /* l (cos(th + a d) - cos th), Q.32 */
                gy += rshr(smul(rx, sn) + smul(ry, c), 14);
            }
        }
        if (used & 4) {
            offsets(s, k, grx[k], gry[k], &ex, &ey);      /* eq. (18) */
            sat += clamped(ex, ey);
            if (kind & 4) {                               /* eq. (19): a e */
                int64_t cxf, cyf;
                cart_force(s, k, ex, ey, &cxf, &cyf);
                gx += cxf;
                gy += cyf;
            }
        }
        ddx[i] += gx;                                     /* onto both ends */
        ddy[i] += gy;
        ddx[j] -= gx;
        ddy[j] -= gy;
        if (ek != 0) {                                    /* the criterion's energy */
            en[k] = sat_energy_of(s, (used & 2) && ek == 1 ? energy_torsion(s, k, d)  /* (17) */
                                                           : energy_cart(s, k, ex, ey));  /* (20) */
            total = sat_add(s, total, en[k], E_MAX);
        }
    }
    s->sat_energy += sat;
    return total;
}

/* one function per set of used kinds (1..7), each compiled with only that geometry */
#define SPRING_PASSES(u)                                                                   \
    static __attribute__((noinline)) int64_t spring_passes_##u(fx_state *s, int64_t *ddx,  \
                                                               int64_t *ddy)               \
    {                                                                                      \
        return spring_passes(s, u, ddx, ddy);                                              \
    }
SPRING_PASSES(1)
SPRING_PASSES(2)
SPRING_PASSES(3)
SPRING_PASSES(4)
SPRING_PASSES(5)
SPRING_PASSES(6)
SPRING_PASSES(7)
static int64_t (*const spring_passes_of[8])(fx_state *, int64_t *, int64_t *) = {
    spring_passes_7, spring_passes_1, spring_passes_2, spring_passes_3,
    spring_passes_4, spring_passes_5, spring_passes_6, spring_passes_7};

/* x0 + sum m_i (x_i - x0) / sum m_i for Q.32 positions, rounded half up: the offsets are
   split into a Q.16 high part and 16 low bits so that every product is 32 x 32 and no sum
   exceeds 2^61, then recombined exactly (msum < 2^31). */
static int64_t centre(const fx_state *s, const int64_t *x, uint32_t msum)
{
    int64_t hi = 0, lo = 0, q;
    uint32_t r;
    int i;
    for (i = 0; i < s->n; i++) {
        int64_t d = x[i] - x[0];                          /* |.| < 2^46 */
        hi += smul((int32_t)s->mq[i], (int32_t)(d >> 16)); /* < 2^55 each */
        lo += (int64_t)umul(s->mq[i], (uint32_t)d & 0xffff);  /* < 2^41 each */
    }
    q = floor_div(hi, msum, &r);
    return x[0] + shl64(q, 16) + div_round(shl64(r, 16) + lo, msum);
}

/* ---- the similarity frame (pull_frame, cartesian_frame = "similarity") --------------
   [ref] fit_frame.  Every product is a 32 x 32 -> 64-bit one (smul), every division an
   int64 by a divisor below 2^31 (div_round).  Formats: the means' offsets from the last
   frame's G and the rest offsets in 29 bits with one shift for the whole fit (Q.(32 -
   sh): Q.23 for a structure within +-128 px), their centroids and the offsets about those
   in the same Q, the fit's sums in that Q doubled less 8, masses in units of the largest;
   s R = [[c, -sn], [sn, c]] Q.28 (|c|, |sn| <= 4 < 8); G Q.32. */
#define FRAME_ONE ((int32_t)1 << 28)                  /* 1.0 in Q.28 */
#define FRAME_SCALE_MIN_Q ((int32_t)1 << 26)          /* [ref] FRAME_SCALE_MIN = 1/4, Q.28 */
#define FRAME_SCALE_MAX_Q ((int32_t)1 << 30)          /* [ref] FRAME_SCALE_MAX = 4, Q.28 */
#define FRAME_SPREAD_SHIFT 20                         /* [ref] FRAME_MIN_SPREAD = 2^-20 */

/* the index of the lowest set bit of m != 0 (two 32-bit halves) */
static inline int lowest_bit(uint64_t m)
{
    uint32_t lo = (uint32_t)m;
    return lo ? __builtin_ctz(lo) : 32 + __builtin_ctz((uint32_t)(m >> 32));
}

/* floor(v / 2^sh) for 0 <= sh < 32 when it fits int32: from v's two words, in 32 bits
   ((hi 2) 2^(31 - sh): no shift by 32) */
static inline int32_t shr32(int64_t v, int sh)
{
    return (int32_t)(((uint32_t)v >> sh) | (((uint32_t)(v >> 32) << 1) << (31 - sh)));
}

/* c v for c in Q.28 and v in Q.32, |v| < 2^46: v = hi 2^16 + lo, two 32 x 32 products,
   rounded to Q.32 (within 1 unit) */
static inline int64_t frame_scale(int32_t c, int64_t v)
{
    return rshr(smul(c, (int32_t)(v >> 16)), 12) + rshr(smul(c, (int32_t)(v & 0xffff)), 28);
}

/* (x, y) scaled to the length len (Q.28): x len / |(x, y)|, |x|, |y| < 2^30, not both 0 */
static inline void frame_to_length(int32_t x, int32_t y, int32_t len, int32_t *c, int32_t *sn)
{
    uint32_t r = (uint32_t)isqrt64((uint64_t)(smul(x, x) + smul(y, y)));   /* < 2^31 */
    *c = (int32_t)div_round(smul(x, len), r);
    *sn = (int32_t)div_round(smul(y, len), r);
}

/* The similarity x -> G + s R (x - G0) that best maps the rest shape onto the means, in
   the mass-weighted least-squares sense, over the trackers of `fit` (all if it holds
   fewer than 2): with p = dG0 - pbar, q = mu - qbar about the set's weighted centroids,
   a = sum m p.q, b = sum m p x q, D = sum m |p|^2, s R = [[a, -b], [b, a]] / D (the scale
   held to [1/4, 4]; s R = I when D <= 2^-20 sum m), G = qbar - s R pbar.  Sets frame_c,
   frame_s (Q.28) and frame_gx, frame_gy (Q.32). */
static __attribute__((noinline)) void fit_frame(fx_state *s, uint64_t fit)
{
    int n = s->n, i, sh;
    uint64_t all = n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << n) - 1, k2, m;
    const int64_t *gdx = s->gdx0, *gdy = s->gdy0, *mx = s->mx, *my = s->my;
    int32_t ux[FX_MAX_TRACKERS], uy[FX_MAX_TRACKERS], vx[FX_MAX_TRACKERS], vy[FX_MAX_TRACKERS];
    int32_t an, bn, dn, c, sn;
    int64_t ox[FX_MAX_TRACKERS], oy[FX_MAX_TRACKERS], W = 0, spx = 0, spy = 0, sqx = 0, sqy = 0;
    int64_t px, py, qx, qy, a = 0, b = 0, d = 0, big = 0, lim;
    fit &= all;
    if ((fit & (fit - 1)) == 0)                       /* fewer than 2: all of them */
        fit = all;
    /* The sums run over the trackers of the fit only (weight mass / largest, Q.24, > 0),
       visited in increasing order.  The means' offsets from the last frame's G (near
       qbar), the rest offsets (from G0), and one shift that puts their largest below
       2^29: their centroids and the offsets about those are then below 2^30 */
    for (m = fit; m; m &= m - 1) {                    /* x ^ (x >> 63): |x| or |x| - 1 */
        i = lowest_bit(m);
        ox[i] = mx[i] - s->frame_gx;
        oy[i] = my[i] - s->frame_gy;
        big |= (gdx[i] ^ (gdx[i] >> 63)) | (gdy[i] ^ (gdy[i] >> 63)) | (ox[i] ^ (ox[i] >> 63))
               | (oy[i] ^ (oy[i] >> 63));
    }
    sh = bitlen64((uint64_t)big) - 29;                /* |.| >> sh <= 2^29; sh < 24 (|G| < 2^51) */
    if (sh < 0)
        sh = 0;
    for (m = fit; m; m &= m - 1) {                    /* weighted centroids, Q.(32 - sh) */
        int32_t w;
        i = lowest_bit(m);
        w = (int32_t)s->mq[i];
        ux[i] = shr32(gdx[i], sh);
        uy[i] = shr32(gdy[i], sh);
        vx[i] = shr32(ox[i], sh);
        vy[i] = shr32(oy[i], sh);
        W += w;                                       /* <= 2^30 */
        spx += smul(w, ux[i]);                        /* < 2^53 each */
        spy += smul(w, uy[i]);
        sqx += smul(w, vx[i]);
        sqy += smul(w, vy[i]);
    }
    px = div_round(spx, (uint32_t)W);                 /* pbar, about G0 */
    py = div_round(spy, (uint32_t)W);
    qx = div_round(sqx, (uint32_t)W);                 /* qbar, about the last G */
    qy = div_round(sqy, (uint32_t)W);
    for (m = fit; m; m &= m - 1) {                    /* p, q: below 2^30 */
        int32_t pux, puy, qvx, qvy, mux, muy;
        i = lowest_bit(m);
        pux = ux[i] - (int32_t)px;
        puy = uy[i] - (int32_t)py;
        qvx = vx[i] - (int32_t)qx;
        qvy = vy[i] - (int32_t)qy;
        mux = pux;                                    /* m p: m = 1 if the masses are equal */
        muy = puy;
        if (!s->equal_mass) {
            mux = (int32_t)rshr(smul((int32_t)s->mq[i], pux), 24);
            muy = (int32_t)rshr(smul((int32_t)s->mq[i], puy), 24);
        }
        /* products < 2^60, pairs < 2^61: a 2^-8 of each keeps 64 of them in int64 */
        a += (smul(mux, qvx) + smul(muy, qvy)) >> 8;  /* a = sum m p.q */
        b += (smul(mux, qvy) - smul(muy, qvx)) >> 8;  /* b = sum m p x q */
        d += (smul(mux, pux) + smul(muy, puy)) >> 8;  /* D = sum m |p|^2 */
    }
    px = shl64(px, sh);                               /* Q.32 */
    py = shl64(py, sh);
    qx = s->frame_gx + shl64(qx, sh);
    qy = s->frame_gy + shl64(qy, sh);
    /* D <= 2^-20 sum m, with D in Q.(56 - 2 sh) px^2 and sum m (W) in Q.24:
       D <= W 2^(56 - 2 sh - 24 - 20) */
    sh = 32 - FRAME_SPREAD_SHIFT - 2 * sh;
    lim = sh >= 0 ? shl64(W, sh) : W >> -sh;
    if (d <= lim) {                                   /* no rotation to tell */
        c = FRAME_ONE;
        sn = 0;
    } else {
        /* a, b, D to 30 bits with one shift: s R = [[a, -b], [b, a]] / D unchanged */
        big = d;
        if ((a < 0 ? -a : a) > big)
            big = a < 0 ? -a : a;
        if ((b < 0 ? -b : b) > big)
            big = b < 0 ? -b : b;
        sh = bitlen64((uint64_t)big) - 30;
        if (sh < 0)
            sh = 0;
        an = (int32_t)(a >> sh);
        bn = (int32_t)(b >> sh);
        dn = (int32_t)(d >> sh);
        k2 = (uint64_t)(smul(an, an) + smul(bn, bn));              /* s^2 D^2, < 2^61 */
        if (dn > 0 && k2 <= (uint64_t)smul(dn, dn) << 4) {         /* s <= 4 */
            if (k2 >= ((uint64_t)1 << 60) || k2 << 4 >= (uint64_t)smul(dn, dn)) {
                c = (int32_t)div_round(smul(an, FRAME_ONE), (uint32_t)dn);   /* s R = [[a, -b], */
                sn = (int32_t)div_round(smul(bn, FRAME_ONE), (uint32_t)dn);  /*     [b, a]] / D */
            } else if (k2 > 0) {                                    /* s < 1/4: held */
                frame_to_length(an, bn, FRAME_SCALE_MIN_Q, &c, &sn);
            } else {                                                /* no rotation to keep */
                c = FRAME_SCALE_MIN_Q;
                sn = 0;
            }
        } else {                                                    /* s > 4: held */
            frame_to_length(an, bn, FRAME_SCALE_MAX_Q, &c, &sn);
        }
    }
    s->frame_c = c;
    s->frame_s = sn;
    s->frame_gx = qx - (frame_scale(c, px) - frame_scale(sn, py));   /* G = qbar - s R pbar */
    s->frame_gy = qy - (frame_scale(sn, px) + frame_scale(c, py));
}

/* eq. (22)'s target of tracker i in the frame: G + s R dG0_i, Q.32 */
static inline void frame_target(const fx_state *s, int i, int64_t *tx, int64_t *ty)
{
    *tx = s->frame_gx + (frame_scale(s->frame_c, s->gdx0[i]) - frame_scale(s->frame_s, s->gdy0[i]));
    *ty = s->frame_gy + (frame_scale(s->frame_s, s->gdx0[i]) + frame_scale(s->frame_c, s->gdy0[i]));
}

/* eq. (18)'s rest offset of connection k in the frame the Cartesian springs use (car_c,
   car_s: the frame fitted at the update before): s R (dx0, dy0), Q.32 */
static inline void frame_offset(const fx_state *s, int k, int64_t *ox, int64_t *oy)
{
    *ox = frame_scale(s->car_c, s->dx0[k]) - frame_scale(s->car_s, s->dy0[k]);
    *oy = frame_scale(s->car_s, s->dx0[k]) + frame_scale(s->car_c, s->dy0[k]);
}

/* [ref] springs: displacements from the same positions, applied together (Jacobi).  The
   forces of eqs. (11), (16), (19) are summed per tracker (Q.32 px, |sum| < 2^55) and
   divided by the mass once: the same sums as the reference's per-connection f / m_i.
   Only the criterion's energy kind is computed here; the spring vectors are kept for
   fx_energies(). */
__attribute__((noinline)) void fx_springs(fx_state *s)
{
    int n = s->n, nc = s->nc, used = s->used_kinds, i, k;
    int64_t ddx[FX_MAX_TRACKERS], ddy[FX_MAX_TRACKERS], total, thr, gx, gy, sx = 0, sy = 0;
    uint64_t pulled = 0, calm = ~(uint64_t)0, bad = 0;
    const int64_t *e = s->energy[s->ekind];
    uint32_t rem;
    s->n_spring_updates++;
    s->car_turned = s->car_sim;                          /* eq. (18) in the last fit's frame */
    s->car_c = s->frame_c;
    s->car_s = s->frame_s;
    for (i = 0; i < n; i++)
        ddx[i] = ddy[i] = 0;
    total = spring_passes_of[used & 7](s, ddx, ddy);
    /* bit 3: no torsional energies at this update (0, as the float kernel) */
    s->energy_stale = (7 & ~(1 << s->ekind)) | (used & 2 ? 0 : 8);
    for (i = 0; i < n; i++) {                             /* the sums of forces / m_i */
        int64_t fx = ddx[i], fy = ddy[i];
        if (!s->unit_mass) {                              /* m_i = 1: f / m_i = f exactly */
            fx = mulsh(fx, s->invm[i], 24);
            fy = mulsh(fy, s->invm[i], 24);
        }
        s->mx[i] = sat_pos(s, s->mx[i] + fx);
        s->my[i] = sat_pos(s, s->my[i] + fy);
        sx += s->mx[i] - s->mx[0];                        /* |sum| < 2^53 */
        sy += s->my[i] - s->my[0];
    }
    /* [ref] _energy_criteria: eqs. (13), (21), (22) */
    if (nc > 0) {
        s->mean_energy = (int64_t)udiv64((uint64_t)total, (uint32_t)nc, &rem);   /* eq. (13) */
        /* e > s mean; with s >= nc no connection can exceed it (e <= total = nc mean) */
        if (s->escale_never)
            thr = E_MAX;
        else                                              /* s mean < nc mean <= E_MAX */
            thr = mulsh(s->mean_energy, s->escale, s->escale_sh);
        if (!s->escale_never) {
            /* the trackers at an over-threshold connection (pulled, eq. 22) and those at
               one under it (calm: eq. 21 keeps them sensitive), as OR-reductions of the
               connections' end masks: no branch, no counting per tracker */
            calm = s->isolated;
            for (k = 0; k < nc; k++) {
                uint64_t o = (uint64_t)0 - (uint64_t)(e[k] > thr);
                pulled |= s->ends[k] & o;
                calm |= s->ends[k] & ~o;
            }
        }
    }
    if (n == 0)
        return;
    if (nc > 0 && (s->pull_sim || s->car_sim))          /* [ref] fit_frame, the calm ones */
        fit_frame(s, ~pulled);
    /* centre of mass G = x0 + sum m_i (x_i - x0) / sum m_i, rounded half up */
    if (s->pull_sim) {
        gx = gy = 0;                                      /* eq. (22) uses the frame's G */
    } else if (s->equal_mass) {                           /* = x0 + round(sum (x_i - x0) / n) */
        gx = s->mx[0] + floor_div(2 * sx + n, 2 * (uint32_t)n, &rem);
        gy = s->my[0] + floor_div(2 * sy + n, 2 * (uint32_t)n, &rem);
    } else {
        uint32_t msum = 0;
        for (i = 0; i < n; i++)
            msum += s->mq[i];
        gx = centre(s, s->mx, msum);
        gy = centre(s, s->my, msum);
    }
    for (uint64_t p = pulled; p; p &= p - 1) {            /* eq. (22) */
        uint32_t lo = (uint32_t)p;
        int64_t tx, ty;                                   /* G + dG0, or G + s R dG0 */
        i = lo ? __builtin_ctz(lo) : 32 + __builtin_ctz((uint32_t)(p >> 32));
        if (s->pull_sim) {
            frame_target(s, i, &tx, &ty);
        } else {
            tx = gx + s->gdx0[i];
            ty = gy + s->gdy0[i];
        }
        s->mx[i] = sat_pos(s, s->mx[i] + mulsh(tx - s->mx[i], s->energy_gain, 30));
        s->my[i] = sat_pos(s, s->my[i] + mulsh(ty - s->my[i], s->energy_gain, 30));
    }
    /* [ref] _guard: a mean outside the position box (a saturated one is) is a state no
       model within springtrack.limits reaches: counted, and the state reset to the model.
       The box is whole px: the integer parts (the high words) tell */
    for (i = 0; i < n; i++) {
        int32_t xi = (int32_t)(s->mx[i] >> FX_POS_FRAC), yi = (int32_t)(s->my[i] >> FX_POS_FRAC);
        bad |= (uint64_t)(xi < s->pos_lo_x || xi >= s->pos_hi_x || yi < s->pos_lo_y
                          || yi >= s->pos_hi_y);
    }
    if (bad) {
        s->n_resets++;
        fx_reset(s);
        return;
    }
    for (i = 0; i < n; i++)
        bad |= (uint64_t)!box_kept(s, i) << i;
    /* eq. (21): insensitive when every connection of the tracker is over */
    s->sensitive_mask = calm & (n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << n) - 1);
    while (bad) {                                         /* re-index who left its box */
        uint32_t lo = (uint32_t)bad;
        fx_reindex(s, lo ? __builtin_ctz(lo) : 32 + __builtin_ctz((uint32_t)(bad >> 32)));
        bad &= bad - 1;
    }
}

/* The energies of all three kinds at the last spring update (eqs. 12, 17, 20), from the
   spring vectors it kept: the kinds the criterion does not use are computed here, when
   they are read, with the same arithmetic as fx_springs (so the values do not depend on
   when they are read).  Offsets are clamped as there, not counted again. */
void fx_energies(fx_state *s)
{
    int nc = s->nc, k, stale = s->energy_stale;
    int32_t l[FX_MAX_CONNECTIONS], dth[FX_MAX_CONNECTIONS], cx[FX_MAX_CONNECTIONS];
    int32_t cy[FX_MAX_CONNECTIONS];
    int64_t mean_dth = 0, sum = 0;
    if (!(stale & 7))
        return;
    if (stale & 3) {
        for (k = 0; k < nc; k++) {
            dth[k] = spring_angle(s, k, geom16(s->grx[k]), geom16(s->gry[k]), &l[k], &cx[k],
                                  &cy[k]);
            sum += dth[k];
        }
        if (nc > 0)
            mean_dth = div_round(sum, (uint32_t)nc);
    }
    for (k = 0; k < nc; k++) {
        int64_t ex, ey, e;
        if (stale & 1) {
            e = energy_euclid(s, k, spring_dl(s, k, s->grx[k], s->gry[k], l[k], cx[k], cy[k]));
            s->energy[0][k] = e > E_MAX ? E_MAX : e;
        }
        if (stale & 2)
            s->energy[1][k] = stale & 8 ? 0 : energy_torsion(s, k, dth[k] - mean_dth);
        if (stale & 4) {
            offsets(s, k, s->grx[k], s->gry[k], &ex, &ey);
            e = energy_cart(s, k, ex, ey);
            s->energy[2][k] = e > E_MAX ? E_MAX : e;
        }
    }
    s->energy_stale &= 8;
}

/* Derived flags, after the model and the parameters are set (and after each change). */
void fx_prepare(fx_state *s)
{
    int i, k;
    s->used_kinds = 1 << s->ekind;
    for (k = 0; k < s->nc; k++)
        s->used_kinds |= s->kinds[k] & 7;
    s->need_torsion = (s->used_kinds >> 1) & 1;
    s->unit_mass = s->equal_mass = 1;
    for (i = 0; i < s->n; i++) {
        if (s->invm[i] != (uint32_t)1 << 24)
            s->unit_mass = 0;
        if (s->mq[i] != s->mq[0])
            s->equal_mass = 0;
    }
    s->decay_span = s->dt_max < ((int64_t)1 << (2 * FX_DECAY_BITS)) ? s->dt_max
                    : ((int64_t)1 << (2 * FX_DECAY_BITS));
}

void fx_reset(fx_state *s)
{
    int i, k, q;
    for (i = 0; i < s->n; i++) {
        s->mx[i] = s->rest_x[i];
        s->my[i] = s->rest_y[i];
        s->sxx[i] = s->rest_sxx[i];
        s->sxy[i] = s->rest_sxy[i];
        s->syy[i] = s->rest_syy[i];
        s->act[i] = 0;
        s->tlast[i] = s->last_t;
    }
    for (q = 0; q < 3; q++)
        for (k = 0; k < s->nc; k++)
            s->energy[q][k] = 0;
    s->mean_energy = 0;
    s->energy_stale = 0;                                  /* the energies are those zeros */
    s->sensitive_mask = s->n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << s->n) - 1;
    s->frame_c = FRAME_ONE;                               /* [ref] the identity frame about */
    s->frame_s = 0;                                       /* G0 until a fit */
    s->car_c = s->car_s = s->car_turned = 0;
    if (s->n > 0) {
        s->frame_gx = s->mx[0] - s->gdx0[0];
        s->frame_gy = s->my[0] - s->gdy0[0];
    }
    for (i = 0; i < s->n; i++) {
        refresh(s, i);
        fx_reindex(s, i);
    }
}

/* Clamp every position into +-FX_POS_LIM (after loading a model), counting saturations. */
void fx_clamp_positions(fx_state *s)
{
    int i;
    for (i = 0; i < s->n; i++) {
        s->mx[i] = sat_pos(s, s->mx[i]);
        s->my[i] = sat_pos(s, s->my[i]);
    }
}

/* ---- loading (the word streams of springtrack/fixed_q.py) ----------------------------- */

static inline int64_t word64(const int32_t *w)           /* low word first */
{
    return (int64_t)(((uint64_t)(uint32_t)w[1] << 32) | (uint32_t)w[0]);
}

/* tracker i's rest geometry from its FX_MODEL_TRACKER words: the mean and covariance the
   state starts from and the guard resets it to, the offset to the rest centre of mass */
static void rest_tracker(fx_state *s, int i, const int32_t *w)
{
    s->rest_x[i] = word64(w);
    s->rest_y[i] = word64(w + 2);
    s->rest_sxx[i] = word64(w + 4);
    s->rest_sxy[i] = word64(w + 6);
    s->rest_syy[i] = word64(w + 8);
    s->gdx0[i] = word64(w + 12);
    s->gdy0[i] = word64(w + 14);
}

/* connection k's rest geometry from its FX_MODEL_CONNECTION words: length, offset, angle */
static void rest_connection(fx_state *s, int k, const int32_t *w)
{
    s->l0[k] = word64(w + 4);
    s->dx0[k] = word64(w + 6);
    s->dy0[k] = word64(w + 8);
    s->th0[k] = (uint32_t)w[10];
    s->c0x[k] = w[11];
    s->c0y[k] = w[12];
}

int32_t fx_cells_needed(int32_t width, int32_t height)
{
    return (((width - 1) >> FX_CELL_SHIFT) + 1) * (((height - 1) >> FX_CELL_SHIFT) + 1);
}

int fx_load_model(fx_state *s, const int32_t *w, int32_t nw, uint64_t *cells, int32_t cell_cap)
{
    int32_t n, nc, width, height, i, k, need;
    uint8_t *z = (uint8_t *)s;
    uint32_t b;
    if (nw < FX_MODEL_HEAD)
        return FX_ERR_WORDS;
    n = w[0];
    nc = w[1];
    width = w[2];
    height = w[3];
    if (n < 0 || nc < 0 || n > FX_MAX_TRACKERS || nc > FX_MAX_CONNECTIONS)
        return FX_ERR_CAPACITY;
    if (nw != FX_MODEL_HEAD + n * FX_MODEL_TRACKER + nc * FX_MODEL_CONNECTION)
        return FX_ERR_WORDS;
    if (width < 1 || height < 1 || width > 8192 || height > 8192)
        return FX_ERR_RANGE;
    /* the position box, whole px: x_lo, x_hi, y_lo, y_hi within +-8191 */
    if (w[4] >= w[5] || w[6] >= w[7] || w[4] < -8191 || w[5] > 8191 || w[6] < -8191
        || w[7] > 8191)
        return FX_ERR_RANGE;
    need = fx_cells_needed(width, height);
    if (need > cell_cap)
        return FX_ERR_CELLS;
    for (b = 0; b < sizeof(fx_state); b++)                /* no libc: memset by hand */
        z[b] = 0;
    for (k = 0; k < need; k++)
        cells[k] = 0;
    s->cells = cells;
    s->n = n;
    s->nc = nc;
    s->width = width;
    s->height = height;
    s->gw = ((width - 1) >> FX_CELL_SHIFT) + 1;
    s->gh = ((height - 1) >> FX_CELL_SHIFT) + 1;
    s->pos_lo_x = w[4];
    s->pos_hi_x = w[5];
    s->pos_lo_y = w[6];
    s->pos_hi_y = w[7];
    w += FX_MODEL_HEAD;
    for (i = 0; i < n; i++, w += FX_MODEL_TRACKER) {
        rest_tracker(s, i, w);
        s->mx[i] = s->rest_x[i];
        s->my[i] = s->rest_y[i];
        s->sxx[i] = s->rest_sxx[i];
        s->sxy[i] = s->rest_sxy[i];
        s->syy[i] = s->rest_syy[i];
        s->mq[i] = (uint32_t)w[10];
        s->invm[i] = (uint32_t)w[11];
        s->box_x0[i] = s->box_y0[i] = 0;                  /* not indexed yet */
        s->box_x1[i] = s->box_y1[i] = -1;
        s->sensitive_mask |= (uint64_t)1 << i;
    }
    s->isolated = s->sensitive_mask;
    for (k = 0; k < nc; k++, w += FX_MODEL_CONNECTION) {
        if (w[0] < 0 || w[0] >= n || w[1] < 0 || w[1] >= n)
            return FX_ERR_RANGE;
        s->ca[k] = w[0];
        s->cb[k] = w[1];
        s->kinds[k] = w[2];
        s->stiff[k] = (uint32_t)w[3];
        rest_connection(s, k, w);
        s->ends[k] = ((uint64_t)1 << s->ca[k]) | ((uint64_t)1 << s->cb[k]);
        s->isolated &= ~s->ends[k];
    }
    fx_clamp_positions(s);
    s->frame_c = FRAME_ONE;                               /* [ref] the identity frame about */
    s->frame_s = 0;                                       /* G0 until a fit */
    if (s->n > 0) {
        s->frame_gx = s->mx[0] - s->gdx0[0];
        s->frame_gy = s->my[0] - s->gdy0[0];
    }
    s->last_t = -((int64_t)1 << 62);
    return FX_OK;
}

int fx_set_params(fx_state *s, const int32_t *w, int32_t nw)
{
    int i;
    if (nw != FX_PARAMS_WORDS)
        return FX_ERR_WORDS;
    if (w[3] < 31 || w[3] > 62 || w[12] < 1 || w[12] > 62 || w[18] < 1 || w[19] < 0
        || w[19] > 2 || (uint32_t)w[22] > 1 || (uint32_t)w[23] > 1)
        return FX_ERR_RANGE;
    /* [ref] eq. (6): a new tau decays from the change on */
    if (s->has_params && s->n_valid > 0
        && ((uint32_t)w[20] != s->tau_bits[0] || (uint32_t)w[21] != s->tau_bits[1])) {
        for (i = 0; i < s->n; i++) {
            s->act[i] = fx_activity(s, i, s->last_t);
            s->tlast[i] = s->last_t;
        }
    }
    s->a1 = (uint32_t)w[0];
    s->cov_gm = (uint32_t)w[1];
    s->cov_am = (uint32_t)w[2];
    s->cov_sh = w[3];
    s->energy_gain = (uint32_t)w[4];
    s->gate = (uint32_t)w[5];
    s->k_tau = (uint32_t)w[6];
    s->dt_max = word64(w + 7);
    s->act_thr = word64(w + 9);
    s->escale = (uint32_t)w[11];
    s->escale_sh = w[12];
    s->escale_never = w[13];
    s->smin2 = word64(w + 14);
    s->smax2 = word64(w + 16);
    s->period = w[18];
    s->ekind = w[19];
    s->tau_bits[0] = (uint32_t)w[20];
    s->tau_bits[1] = (uint32_t)w[21];
    s->pull_sim = w[22];
    s->car_sim = w[23];
    for (i = 0; i < FX_DECAY_N; i++) {
        s->decay_lo[i] = (uint32_t)w[FX_PARAMS_HEAD + i];
        s->decay_hi[i] = (uint32_t)w[FX_PARAMS_HEAD + FX_DECAY_N + i];
    }
    fx_prepare(s);
    for (i = 0; i < s->n; i++) {
        refresh(s, i);
        fx_reindex(s, i);
    }
    if (!s->has_params)
        s->n_reindex = 0;                                 /* the first indexing is no update */
    s->has_params = 1;
    return FX_OK;
}

/* ---- moving an instance rigidly (springtrack.reference.ReferenceTracker.move) --------- */

/* round(c v / 2^28), half up, for c in Q.28 and |v| < 2^62 when it fits int64: v = hi 2^31
   + lo with 0 <= lo < 2^31, so c v / 2^28 = 8 c hi (exact) + c lo / 2^28 (rounded): two
   32 x 32 -> 64-bit products, one rounding.  A move is rare: one copy of the code, not
   fourteen (flash on a microcontroller) */
static __attribute__((noinline)) int64_t mulq28(int32_t c, int64_t v)
{
    return shl64(smul(c, (int32_t)(v >> 31)), 3) + rshr(smul(c, (int32_t)(v & 0x7fffffff)), 28);
}

/* (x, y) <- A (x, y) + t, A = [[a, -b], [b, a]] Q.28, Q.32 in and out */
static inline void sim_point(int32_t a, int32_t b, int64_t tx, int64_t ty, int64_t *x,
                             int64_t *y)
{
    int64_t u = *x, v = *y;
    *x = mulq28(a, u) - mulq28(b, v) + tx;
    *y = mulq28(b, u) + mulq28(a, v) + ty;
}

/* 1 if the model words w (checked for length) describe the loaded instance: the same
   sensor, position box, trackers' masses and connections (ends, kinds, stiffnesses) */
static int same_model(const fx_state *s, const int32_t *w)
{
    int i, k;
    if (w[0] != s->n || w[1] != s->nc || w[2] != s->width || w[3] != s->height
        || w[4] != s->pos_lo_x || w[5] != s->pos_hi_x || w[6] != s->pos_lo_y
        || w[7] != s->pos_hi_y)
        return 0;
    w += FX_MODEL_HEAD;
    for (i = 0; i < s->n; i++, w += FX_MODEL_TRACKER)
        if ((uint32_t)w[10] != s->mq[i] || (uint32_t)w[11] != s->invm[i])
            return 0;
    for (k = 0; k < s->nc; k++, w += FX_MODEL_CONNECTION)
        if (w[0] != s->ca[k] || w[1] != s->cb[k] || w[2] != s->kinds[k]
            || (uint32_t)w[3] != s->stiff[k])
            return 0;
    return 1;
}

int fx_move(fx_state *s, const int32_t *w, int32_t nw)
{
    int32_t a, b;
    int64_t tx, ty;
    int i, k;
    if (nw != FX_MOVE_HEAD + FX_MODEL_HEAD + s->n * FX_MODEL_TRACKER
              + s->nc * FX_MODEL_CONNECTION)
        return FX_ERR_WORDS;
    a = w[0];                                             /* |a|, |b| < 8 (Q.28 in int32) */
    b = w[1];
    tx = word64(w + 2);
    ty = word64(w + 4);
    if (tx <= -FX_SIM_T_LIM || tx >= FX_SIM_T_LIM || ty <= -FX_SIM_T_LIM || ty >= FX_SIM_T_LIM)
        return FX_ERR_RANGE;
    w += FX_MOVE_HEAD;
    if (!same_model(s, w))
        return FX_ERR_MODEL;
    /* the energies of the last spring update stay as they were: the kinds not computed yet
       are computed now, from that update's rest geometry */
    fx_energies(s);
    w += FX_MODEL_HEAD;
    for (i = 0; i < s->n; i++, w += FX_MODEL_TRACKER)
        rest_tracker(s, i, w);
    for (k = 0; k < s->nc; k++, w += FX_MODEL_CONNECTION)
        rest_connection(s, k, w);
    for (i = 0; i < s->n; i++) {
        int64_t sxx = s->sxx[i], sxy = s->sxy[i], syy = s->syy[i];   /* Q.40, <= 2^52 */
        int64_t pxx, pxy, pyx, pyy, x = s->mx[i], y = s->my[i];
        /* mu' = A mu + t (Q.32: |A mu| < 2^49, |t| < 2^52), held inside +-FX_POS_LIM */
        sim_point(a, b, tx, ty, &x, &y);
        s->mx[i] = sat_pos(s, x);
        s->my[i] = sat_pos(s, y);
        /* Sigma' = A Sigma A^T: the rows of A Sigma (< 2^56), then times A^T (< 2^60) */
        pxx = mulq28(a, sxx) - mulq28(b, sxy);
        pxy = mulq28(a, sxy) - mulq28(b, syy);
        pyx = mulq28(b, sxx) + mulq28(a, sxy);
        pyy = mulq28(b, sxy) + mulq28(a, syy);
        s->sxx[i] = mulq28(a, pxx) - mulq28(b, pxy);
        s->sxy[i] = mulq28(b, pxx) + mulq28(a, pxy);
        s->syy[i] = mulq28(b, pyx) + mulq28(a, pyy);
        refresh(s, i);                                    /* clamped as eq. (4)'s, inverted */
        fx_reindex(s, i);
    }
    /* the frame's centre mapped; its s R is kept (2-D similarities commute) */
    sim_point(a, b, tx, ty, &s->frame_gx, &s->frame_gy);
    return FX_OK;
}
