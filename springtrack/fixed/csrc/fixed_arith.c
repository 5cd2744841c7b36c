/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): arithmetic
   building blocks: the 32 x 32 -> 64-bit products, shifts and roundings, divisions, square
   root, and the table-driven exp2, Gaussian, decay, atan2, cos/sin and polar form. */

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

/* acc + a b with a 32 x 32 -> 64-bit product (callers' bounds: no overflow).  On Thumb-2
   one SMLAL, where smul's SMULL and a 64-bit addition are three instructions (the
   compiler cannot merge an asm SMULL into its addition). */
static inline int64_t smla(int64_t acc, int32_t a, int32_t b)
{
#if defined(__thumb2__) && !FX_WORD64
    uint32_t lo = (uint32_t)acc, hi = (uint32_t)((uint64_t)acc >> 32);
    __asm__("smlal %0, %1, %2, %3" : "+r"(lo), "+r"(hi) : "r"(a), "r"(b));
    return (int64_t)(((uint64_t)hi << 32) | lo);
#else
    return acc + (int64_t)a * b;
#endif
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
    int64_t hi = smla(smul((int32_t)(inc >> 32), (int32_t)gm), -(int32_t)(v >> 32), (int32_t)am);
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
