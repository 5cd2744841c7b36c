/* Integer-only tracker step: the fixed-point translation of springtrack/_kernel.pyx.
 *
 * Equations cite Valeiras et al. 2015; [ref] names the function of
 * springtrack/reference.py a block mirrors.  Q formats are listed in fixed_step.h and
 * justified, with their error bounds, in docs/fixed_point.md.  No floating-point type
 * appears in this file: it compiles with `gcc -mgeneral-regs-only`.
 */
#include "fixed_step.h"
#include "sampling.h"

#define ONE_Q30 ((int64_t)1 << 30)
#define RHO_Q30 1063004406u        /* 0.99 (reference.RHO_MAX), Q.30 */
#define RHO2_Q30 1052374362u       /* 0.99^2, Q.30 */
#define PI_Q28 843314857u          /* pi, Q.28 */
#define PI_Q29 1686629713u         /* pi, Q.29: binary angle * PI_Q29 / 2^30 = rad Q.30 */
#define SMALL_ANGLE ((int64_t)42722830)   /* 2^-4 rad as a binary angle */
#define ACT_MAX ((int64_t)1 << 61) /* activity saturates at 2^29 */
#define E_MAX ((int64_t)1 << 61)   /* an energy saturates at 2^29 px^2 */

/* ---- arithmetic building blocks ----------------------------------------------------- */

/* round(v * g / 2^sh), half up, exact for |v| < 2^62, g < 2^31, 1 <= sh <= 62, provided
   the result fits int64 (callers' bounds). */
static inline int64_t mulsh(int64_t v, uint32_t g, int sh)
{
    /* one 64 x 64 -> 128-bit product (integer registers); a core without it would split v
       in two 32-bit halves (hi g 2^32 + lo g), which gives the same exact result */
    return (int64_t)(((__int128)v * g + ((__int128)1 << (sh - 1))) >> sh);
}

/* round(v g / 2^62) for a gain g in [0, 2^62] (Q.62, i.e. [0, 1]); |v| < 2^63 */
static inline int64_t mul62(int64_t v, int64_t g)
{
    return (int64_t)(((__int128)v * g + ((__int128)1 << 61)) >> 62);
}

/* v + round((inc g - v a2) / 2^62), half up: one rounding of eq. (4) (gains Q.62; |inc| <
   2^58, |v| < 2^53, so both products and their difference fit 128 bits) */
static inline int64_t ema62(int64_t v, int64_t inc, int64_t g, int64_t a2)
{
    return v + (int64_t)(((__int128)inc * g - (__int128)v * a2 + ((__int128)1 << 61)) >> 62);
}

int64_t fx_mulsh(int64_t v, uint32_t g, int sh)
{
    return mulsh(v, g, sh);
}

/* round(v / 2^sh) half up; sh >= 1 */
static inline int64_t rshr(int64_t v, int sh)
{
    return (v + ((int64_t)1 << (sh - 1))) >> sh;
}

/* mulsh for |v| < 2^32 (the product v g < 2^63 needs no split) */
static inline int64_t mul32sh(int64_t v, uint32_t g, int sh)
{
    return rshr(v * (int64_t)g, sh);
}

/* n / d rounded half away from zero; d > 0 */
static inline int64_t div_round(int64_t n, int64_t d)
{
    return n >= 0 ? (n + d / 2) / d : -((-n + d / 2) / d);
}

static inline int bitlen64(uint64_t v)
{
    return v ? 64 - __builtin_clzll(v) : 0;
}

/* floor(sqrt(v)): normalise v to m = v 4^k in [2^62, 2^64), seed from the table of
   sqrt(j 2^54) / 2 with linear interpolation (relative error < 5e-7), one Newton step
   (error < 2^-40 relative), then an exact +-1 fix.  One division. */
static inline uint64_t isqrt64(const fx_state *s, uint64_t v)
{
    uint64_t m, x, r, j, f, t0, t1;
    int k;
    if (v < 2)
        return v;
    k = (64 - bitlen64(v)) >> 1;                          /* v << 2k keeps v < 2^64 */
    m = v << (2 * k);
    j = (m >> FX_SQRT_SHIFT) - FX_SQRT_J0;                /* [0, 768) */
    f = (m >> (FX_SQRT_SHIFT - 24)) & 0xffffffu;          /* 24 bits of the fraction */
    t0 = s->sqrt_tab[j];
    t1 = s->sqrt_tab[j + 1];
    x = 2 * (t0 + (((t1 - t0) * f) >> 24)) + 1;           /* ~ sqrt(m), in [2^31, 2^32] */
    x = (x + m / x) >> 1;                                 /* m / x < 2^33 */
    r = x >> k;
    if (r > 0xffffffffu)
        r = 0xffffffffu;
    while (r * r > v)
        r--;
    while (r < 0xffffffffu && (r + 1) * (r + 1) <= v)
        r++;
    return r;
}

uint64_t fx_isqrt64(const fx_state *s, uint64_t v)
{
    return isqrt64(s, v);
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

/* a position (Q.32) in Q.16, floor */
static inline int64_t pos16(int64_t v)
{
    return v >> 16;
}

/* Mahalanobis d^2 = ia dx^2 + ib2 dx dy + ic dy^2 (eq. 2), Q.40, from the inverse
   covariance (Q.32 px^-2: ia, ic < 2^47, |ib2| < 2^48) and the exact offsets (Q.32 px,
   < 2^46).  64 x 64 -> 128-bit products (integer registers only): (ia dx) >> 32 < 2^61,
   (ib2 dx) >> 32 < 2^62, and every term is < 2^109, so the sum needs no bound on the
   offsets and is compared with the gate before it is narrowed. */
static inline __int128 qform(int64_t ia, int64_t ib2, int64_t ic, int64_t dx, int64_t dy)
{
    int64_t tx = (int64_t)(((__int128)ia * dx) >> 32);     /* < 2^61: fits int64 */
    int64_t ty = (int64_t)(((__int128)ic * dy) >> 32);
    int64_t txy = (int64_t)(((__int128)ib2 * dx) >> 32);
    /* ty dy + txy dy = (ty + txy) dy exactly (|ty + txy| < 2^61 + 2^62 < 2^63 fits int64):
       two 128-bit products, not three */
    return ((__int128)tx * dx + (__int128)(ty + txy) * dy) >> 24;
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
static inline uint32_t exp2neg(const fx_state *s, int64_t w)
{
    int64_t ip = w >> 40;
    uint64_t frac = (uint64_t)w & (((uint64_t)1 << 40) - 1);
    uint32_t idx = (uint32_t)(frac >> (40 - FX_EXP2_BITS));
    uint64_t rem = (frac >> (40 - FX_EXP2_BITS - 24)) & 0xffffffu;   /* 24 bits */
    uint64_t v0 = s->exp2_lut[idx], v1 = s->exp2_lut[idx + 1];
    uint64_t v;
    if (w < 0)
        return (uint32_t)ONE_Q30;
    if (ip > 31)
        return 0;
    v = v0 - (((v0 - v1) * rem + ((uint64_t)1 << 23)) >> 24);
    /* rounded shift by ip in [0, 31] without a branch (ip is data): half = 2^(ip-1), or 0 */
    v = (v + (((uint64_t)1 << ip) >> 1)) >> ip;
    return (uint32_t)v;
}

uint32_t fx_exp2neg(const fx_state *s, int64_t w)
{
    return exp2neg(s, w);
}

/* exp(-d2 / 2), Q.30, for 0 <= d2 < 32 (Q.40; the gate is <= 31): d2 = hi 2^-5 + lo 2^-15
   + r, the product of two tables of exact roundings and 1 - r / 2 for the rest r < 2^-15
   (whose next term r^2 / 8 < 2^-33); error <= 2.1 units of Q.30 */
static inline int64_t gauss(const fx_state *s, int64_t d2)
{
    uint64_t q = ((uint64_t)s->gauss_hi[d2 >> 35] * s->gauss_lo[(d2 >> 25) & (FX_GAUSS_N - 1)]
                  + ((uint64_t)1 << 29)) >> 30;
    return (int64_t)(q - ((q * (uint64_t)(d2 & (((int64_t)1 << 25) - 1)) + ((uint64_t)1 << 40)) >> 41));
}

int64_t fx_gauss(const fx_state *s, int64_t d2)
{
    return gauss(s, d2);
}

/* round(act d / 2^30), half up, for an activity 0 <= act < 2^62 (Q.32) and a decay d <=
   2^30 (Q.30): act = h 2^31 + l gives 2 h d + round(l d / 2^30), two 64-bit products */
static inline int64_t decay_mul(int64_t act, uint32_t d)
{
    return (act >> 31) * d * 2 + (((act & 0x7fffffff) * d + (1 << 29)) >> 30);
}

/* exp(-dt / tau), Q.30, for dt in us (eq. 6).  Below decay_span (2^18 us, or dt_max if
   that is less) the product of two tables of exact roundings, exp(-dt_hi 512 / tau) and
   exp(-dt_lo / tau) for dt = 512 dt_hi + dt_lo (error <= 1.5 units of Q.30); beyond it
   the exp2 table (which gives 0 from dt_max on). */
static inline uint32_t decay(const fx_state *s, int64_t dt)
{
    if ((uint64_t)dt < (uint64_t)s->decay_span)
        return (uint32_t)(((uint64_t)s->decay_hi[dt >> FX_DECAY_BITS]
                           * s->decay_lo[dt & (FX_DECAY_N - 1)] + ((uint64_t)1 << 29)) >> 30);
    if (dt <= 0)
        return (uint32_t)ONE_Q30;
    if (dt >= s->dt_max)
        return 0;
    return exp2neg(s, dt * s->k_tau);                  /* < 41 * 2^40 */
}

uint32_t fx_decay(const fx_state *s, int64_t dt)
{
    return decay(s, dt);
}

/* atan(t) for t in [0, 1] Q.30, as a binary angle: table of atan(k / 1024) and linear
   interpolation (error < 8e-8 rad, docs/fixed_point.md) */
static inline int64_t atan_unit(const fx_state *s, int64_t t)
{
    int64_t idx = t >> (30 - FX_ATAN_BITS), rem = t & ((1 << (30 - FX_ATAN_BITS)) - 1);
    int64_t v0 = s->atan_tab[idx], v1 = s->atan_tab[idx + 1];
    return v0 + (((v1 - v0) * rem + (1 << (29 - FX_ATAN_BITS))) >> (30 - FX_ATAN_BITS));
}

/* atan2(y, x) as a binary angle (2^32 = 2 pi), |x|, |y| < 2^32: octant reduction, one
   division, table.  atan2(0, 0) = 0 as in C. */
static inline uint32_t atan2_bam(const fx_state *s, int64_t y, int64_t x)
{
    int64_t ax = x < 0 ? -x : x, ay = y < 0 ? -y : y, a;
    if (ax == 0 && ay == 0)
        return 0;
    if (ay <= ax)
        a = atan_unit(s, (ay << 30) / ax);                /* [0, pi/4] */
    else
        a = ((int64_t)1 << 30) - atan_unit(s, (ax << 30) / ay);   /* pi/2 - atan(x/y) */
    if (x < 0)
        a = ((int64_t)1 << 31) - a;                       /* pi - a */
    if (y < 0)
        a = -a;
    return (uint32_t)((uint64_t)a & 0xffffffffu);
}

/* cos and sin of a binary angle, Q.30, CORDIC in rotation mode (Q.60 inside) */
static inline void cossin(const fx_state *s, int64_t angle, int64_t *c, int64_t *sn)
{
    uint32_t u = (uint32_t)((uint64_t)angle & 0xffffffffu);
    int64_t z = (int64_t)u - ((int64_t)(u >> 31) << 32);  /* [-pi, pi), without a branch */
    int64_t x = s->cordic_x0, y = 0;
    int neg = 0, i;
    if (z < SMALL_ANGLE && z > -SMALL_ANGLE) {            /* |z| < 2^-4 rad: Taylor series */
        int64_t r = mul32sh(z, PI_Q29, 30);               /* radians, Q.30; |z| < 2^26 */
        int64_t r2 = rshr(r * r, 30);
        int64_t r4;
        if (r < ((int64_t)1 << 23) && r > -((int64_t)1 << 23)) {
            /* |r| < 2^-7 rad (the usual torsion step): r2 <= 2^16, r4 <= 4, and every r4
               term below rounds to exactly 0, so this is the same result, shorter */
            *sn = rshr(r * (ONE_Q30 - rshr(r2 * 715827883, 32)), 30);
            *c = ONE_Q30 - (r2 >> 1);                     /* r2 >= 0 */
            return;
        }
        r4 = rshr(r2 * r2, 30);
        /* sin r = r (1 - r2/6 + r4/120), cos r = 1 - r2/2 + r4/24 - r2 r4/720: truncation
           < r^7/5040 < 1e-12 for |r| < 2^-4; constants 2^32/6, 2^32/120, 2^32/24, 2^32/720 */
        *sn = rshr(r * (ONE_Q30 - rshr(r2 * 715827883, 32) + rshr(r4 * 35791394, 32)), 30);
        *c = ONE_Q30 - r2 / 2 + rshr(r4 * 178956971, 32) - rshr(rshr(r2 * r4, 30) * 5965232, 32);
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
            z -= s->atan_lut[i];
        } else {
            xn = x + (y >> i);
            y = y - (x >> i);
            z += s->atan_lut[i];
        }
        x = xn;
    }
    x = rshr(x, 30);
    y = rshr(y, 30);
    *c = neg ? -x : x;
    *sn = neg ? -y : y;
}

/* cos(z) - 1 and sin(z), Q.30, of a binary angle z, |z| < 2^32: the short series of cossin
   for the torsion's small rotation a dtheta (the same integers), cossin otherwise */
static inline void rotation(const fx_state *s, int64_t z, int64_t *cm1, int64_t *sn)
{
    if (z <= 5340353 && z >= -5340353) {                  /* |r| < 2^23 below, 0.0078 rad */
        int64_t r = mul32sh(z, PI_Q29, 30);               /* radians, Q.30 */
        int64_t r2 = rshr(r * r, 30);
        *sn = rshr(r * (ONE_Q30 - rshr(r2 * 715827883, 32)), 30);
        *cm1 = -(r2 >> 1);
        return;
    }
    cossin(s, z, cm1, sn);
    *cm1 -= ONE_Q30;
}

uint32_t fx_atan2(const fx_state *s, int64_t y, int64_t x)
{
    return atan2_bam(s, y, x);
}

/* table look-up with linear interpolation at t in [0, 1] (Q.30), tables of 1024 intervals */
static inline int64_t unit_interp(const uint32_t *tab, int64_t t)
{
    int64_t idx = t >> (30 - FX_ATAN_BITS), rem = t & ((1 << (30 - FX_ATAN_BITS)) - 1);
    int64_t v0 = tab[idx], v1 = tab[idx + 1];
    return v0 + (((v1 - v0) * rem + (1 << (29 - FX_ATAN_BITS))) >> (30 - FX_ATAN_BITS));
}

/* Polar form of r = (x, y), |x|, |y| < 2^31: its angle (binary), its length (unit of x,
   rounded; relative error < 2e-7) and its direction r / |r| (Q.30).  One division, the
   octant ratio t = min / max, then tables of atan(t), sqrt(1 + t^2), 1 / sqrt(1 + t^2).
   In two steps, so that the spring pass can do all the divisions first (they overlap):
   polar_ratio gives t, max(|x|, |y|) and the octant (bit 0: |y| > |x|, bit 1: x < 0,
   bit 2: y < 0); polar_finish the rest. */
static inline int64_t polar_ratio(int64_t x, int64_t y, int64_t *big, int *oct)
{
    int64_t ax = x < 0 ? -x : x, ay = y < 0 ? -y : y;
    int swap = ay > ax;
    *big = swap ? ay : ax;
    *oct = swap | (x < 0) << 1 | (y < 0) << 2;
    if (*big == 0)
        return 0;
    return ((swap ? ax : ay) << 30) / *big;                /* [0, 2^30] */
}

static inline void polar_finish(const fx_state *s, int64_t t, int64_t big, int oct, uint32_t *ang,
                                int64_t *len, int64_t *cx, int64_t *cy)
{
    int64_t a, h, cbig, csmall;
    if (big == 0) {
        *ang = 0;
        *len = *cx = *cy = 0;
        return;
    }
    a = unit_interp(s->atan_tab, t);
    *len = rshr(big * unit_interp(s->hyp_tab, t), 30);    /* big sqrt(1 + t^2) */
    h = unit_interp(s->ihyp_tab, t);                      /* cos of the octant angle */
    cbig = h;
    csmall = rshr(t * h, 30);
    if (oct & 1) {
        a = ((int64_t)1 << 30) - a;
        *cx = csmall;
        *cy = cbig;
    } else {
        *cx = cbig;
        *cy = csmall;
    }
    if (oct & 2) {
        a = ((int64_t)1 << 31) - a;
        *cx = -*cx;
    }
    if (oct & 4) {
        a = -a;
        *cy = -*cy;
    }
    *ang = (uint32_t)((uint64_t)a & 0xffffffffu);
}

static inline void polar(const fx_state *s, int64_t x, int64_t y, uint32_t *ang, int64_t *len,
                         int64_t *cx, int64_t *cy)
{
    int64_t big, t;
    int oct;
    t = polar_ratio(x, y, &big, &oct);
    polar_finish(s, t, big, oct, ang, len, cx, cy);
}

void fx_polar(const fx_state *s, int64_t x, int64_t y, uint32_t *ang, int64_t *len, int64_t *cx,
              int64_t *cy)
{
    polar(s, x, y, ang, len, cx, cy);
}


void fx_cossin(const fx_state *s, int64_t angle, int64_t *c, int64_t *sn)
{
    cossin(s, angle, c, sn);
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
        uint64_t *row = s->cells + (int64_t)y * s->gw;
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

static inline int32_t cell_of(int64_t v, int32_t gmax)
{
    int64_t c = v >> (16 + FX_CELL_SHIFT);                /* v Q.16 px; floor */
    return c < 0 ? 0 : (c > gmax ? gmax : (int32_t)c);
}

/* An upper bound of gate v (Q.32 px^2) for a variance v (Q.40, < 2^53): the square of the
   gate box's half-width, for the spatial index (which needs a box that contains the gate
   box, not an exact one).  One 64-bit product: (v / 2^16 + 1) ceil(gate 2^20) < 2^61,
   rounded up; relative excess < 2^-22 for v >= 0.25 px^2. */
static inline int64_t gate_box2(const fx_state *s, int64_t v)
{
    return (((v >> 16) + 1) * s->gate_q20 + 4095) >> 12;
}

/* half-width of the gate box for a variance v (Q.40), Q.16, rounded up */
static inline int64_t gate_half(const fx_state *s, int64_t v)
{
    return (int64_t)isqrt64(s, (uint64_t)gate_box2(s, v)) + 1;
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
    int64_t hx = gate_half(s, s->sxx[i]), hy = gate_half(s, s->syy[i]);     /* Q.16 */
    int64_t cx = pos16(s->mx[i]), cy = pos16(s->my[i]);
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
    s->devx[i] = hx - gate_half(s, s->sxx_lim[i]);
    s->devy[i] = hy - gate_half(s, s->syy_lim[i]);
    if (s->devx[i] < 0)
        s->devx[i] = 0;
    if (s->devy[i] < 0)
        s->devy[i] = 0;
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

/* d >= h  <=>  d >= 0 and d^2 >= h^2 (h^2 = g2, Q.32); d is Q.16, |d| < 2^31 */
static inline int inside(int64_t d, int64_t g2)
{
    return d >= 0 && d * d >= g2;
}

static inline int64_t min64(int64_t a, int64_t b)
{
    return a < b ? a : b;
}

/* 1 if tracker i's gate box lies inside its indexed box (the exact test, for
   fx_check_index) */
static inline int box_ok(const fx_state *s, int i)
{
    /* positions to Q.16 (floor): an error < 2^-16 px, far inside the 3 px index margin;
       both sides of an axis are inside iff the nearer one is (one square per axis) */
    int64_t x = pos16(s->mx[i]), y = pos16(s->my[i]);
    return inside(min64(x - s->bx_lo[i], s->bx_hi[i] - x), gate_box2(s, s->sxx[i]))
        && inside(min64(y - s->by_lo[i], s->by_hi[i] - y), gate_box2(s, s->syy[i]));
}

/* 1 if tracker i's mean and variances are still within the slack fx_reindex noted: a
   sufficient test for box_ok, four comparisons (the exact one needs the gate box of the
   current variances, two products and two squares) */
static inline int box_kept(const fx_state *s, int i)
{
    int64_t dx = pos16(s->mx[i]) - s->bcx[i], dy = pos16(s->my[i]) - s->bcy[i];
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

/* round(v * 2^k): left shift with saturation (counted), or rounded right shift */
static inline int64_t scale2(fx_state *s, int64_t v, int k)
{
    if (k <= 0)
        return k == 0 ? v : rshr(v, -k);
    if (v >= ((int64_t)1 << (62 - k)) || v <= -((int64_t)1 << (62 - k))) {
        s->sat_inverse++;
        return v < 0 ? -((int64_t)1 << 62) : ((int64_t)1 << 62);
    }
    return v * ((int64_t)1 << k);
}

/* [ref] _clamp_and_invert: sigma_x, sigma_y in [sigma_min, sigma_max], |rho| <= 0.99,
   then the inverse covariance of eq. (2).  One division. */
static inline void refresh(fx_state *s, int i)
{
    int64_t sxx = s->sxx[i], syy = s->syy[i], sxy = s->sxy[i];
    int64_t a, b, c, p, det, m, r, big;
    int sh, e, k;
    sxx = sxx < s->smin2 ? s->smin2 : (sxx > s->smax2 ? s->smax2 : sxx);
    syy = syy < s->smin2 ? s->smin2 : (syy > s->smax2 ? s->smax2 : syy);
    /* block scaling: a, c < 2^31 so that every product below fits int64 */
    big = sxx > syy ? sxx : syy;
    sh = bitlen64((uint64_t)big) - 31;
    if (sh < 0)
        sh = 0;
    a = sxx >> sh;
    c = syy >> sh;
    if (sxy > big)                                        /* |sxy| <= max keeps b^2 < 2^62 */
        sxy = big;
    if (sxy < -big)
        sxy = -big;
    b = sxy >> sh;
    p = a * c;
    /* |rho| > 0.99: clamp (b^2 <= p - p / 32 < 0.99^2 p: certainly not, without the product) */
    if (b * b > p - (p >> 5) && b * b > mulsh(p, RHO2_Q30, 30)) {
        /* 0.99 sqrt(sxx syy) = 0.99 sqrt(a c) 2^sh, Q.40, 31 significant bits */
        int64_t lim = mulsh((int64_t)isqrt64(s, (uint64_t)p) * ((int64_t)1 << sh), RHO_Q30, 30);
        sxy = sxy < 0 ? -lim : lim;
        b = sxy >> sh;
    }
    s->sxx[i] = sxx;
    s->sxy[i] = sxy;
    s->syy[i] = syy;
    det = p - b * b;                                      /* > 0.0199 p */
    if (det <= 0)
        det = 1;
    /* det = m 2^e with m in [2^30, 2^31); r = 2^61 / m in (2^30, 2^31] */
    e = bitlen64((uint64_t)det) - 31;
    m = e >= 0 ? det >> e : det * ((int64_t)1 << -e);
    r = ((int64_t)1 << 61) / m;
    /* ia = syy / det in Q.32 = c r 2^(11 - sh - e) for covariances in Q.40
       (docs/fixed_point.md) */
    k = 11 - sh - e;
    s->ia[i] = scale2(s, c * r, k);
    s->ic[i] = scale2(s, a * r, k);
    s->ib2[i] = 2 * scale2(s, -b * r, k);
}

void fx_refresh(fx_state *s, int i)
{
    refresh(s, i);
}

/* [ref] _update: eqs. (2)-(6) for the winning tracker i; dx, dy Q.32 from the pre-update
   mean (|.| < 2^41 inside the gate), d2 Q.40. */
static __attribute__((noinline)) void update_tracker(fx_state *s, int i, int64_t t, int64_t dx, int64_t dy,
                                                   int64_t d2)
{
    int64_t p = gauss(s, d2);                             /* eq. (2), Q.30 */
    int64_t act = decay_mul(s->act[i], decay(s, t - s->tlast[i])) + p * 4;  /* eq. (6) */
    if (act > ACT_MAX) {
        act = ACT_MAX;
        s->sat_activity++;
    }
    s->act[i] = act;
    s->tlast[i] = t;
    int64_t ex = rshr(dx, 12), ey = rshr(dy, 12);         /* Q.20 px, < 2^29 */
    /* eq. (3): m + round(a1 (u - m)) with 0 <= a1 <= 1 lies between m and the event u, both
       inside +-FX_POS_LIM: it cannot saturate */
    s->mx[i] += mul62(dx, s->a1);
    s->my[i] += mul62(dy, s->a1);
    /* eq. (4)-(5): S <- (1 - a2) S + g e e^T, e = (dx, dy); ex ex is Q.40 px^2 */
    s->sxx[i] = ema62(s->sxx[i], ex * ex, s->cov_gain, s->a2);
    s->sxy[i] = ema62(s->sxy[i], ex * ey, s->cov_gain, s->a2);
    s->syy[i] = ema62(s->syy[i], ey * ey, s->cov_gain, s->a2);
    refresh(s, i);
    check_index(s, i);
}

/* eq. (2) and eqs. (3)-(6) for one valid event at pixel (x, y): the sensitive trackers
   indexed in the event's cell (mask), in index order, so ties resolve as in the reference's
   full scan; the winner is updated.  Returns the winner or FX_NO_TRACKER. */
static inline __attribute__((always_inline)) int assign(fx_state *s, uint64_t mask, int64_t t,
                                                        int32_t x, int32_t y)
{
    int64_t fx = (int64_t)x << FX_POS_FRAC, fy = (int64_t)y << FX_POS_FRAC;
    int64_t best_d2 = s->gate;
    uint64_t m = s->cells[(y >> FX_CELL_SHIFT) * s->gw + (x >> FX_CELL_SHIFT)] & mask;
    int best = FX_NO_TRACKER;
    while (m) {
        int i = __builtin_ctzll(m);
        __int128 d2;
        m &= m - 1;
        /* offsets Q.32, |.| < 2^46 */
        d2 = qform(s->ia[i], s->ib2[i], s->ic[i], fx - s->mx[i], fy - s->my[i]);
        if (d2 < best_d2) {
            best_d2 = (int64_t)d2;
            best = i;
        }
    }
    if (best >= 0)
        update_tracker(s, best, t, fx - s->mx[best], fy - s->my[best], best_d2 < 0 ? 0 : best_d2);
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

/* fx_step over a batch, with the event counters, the clock and the sensitive mask kept in
   registers (the springs are the only other writer of the mask) */
int64_t fx_steps(fx_state *s, const fx_event *ev, int64_t n, int64_t t_stop)
{
    int64_t k, last_t = s->last_t, n_assigned = 0, n_skipped = 0, n_back = 0;
    uint32_t width = (uint32_t)s->width, height = (uint32_t)s->height;
    int32_t until = s->period - s->since_spring;          /* >= 1 */
    uint64_t mask = s->sensitive_mask;
    for (k = 0; k < n; k++) {
        int64_t t = ev[k].t;
        uint32_t x = ev[k].x, y = ev[k].y;
        if (st_sample_due(t, t_stop, last_t))
            break;
        if (t < last_t) {
            n_back++;
            continue;
        }
        last_t = t;
        if (x >= width || y >= height) {
            n_skipped++;
            continue;
        }
        n_assigned += assign(s, mask, t, (int32_t)x, (int32_t)y) >= 0;
        if (--until <= 0) {
            until = s->period;
            fx_springs(s);
            mask = s->sensitive_mask;
        }
    }
    s->last_t = last_t;
    s->since_spring = s->period - until;
    s->n_valid += k - n_back - n_skipped;
    s->n_assigned += n_assigned;
    s->n_back += n_back;
    s->n_outside += n_skipped;
    return k;
}

/* eq. (6) evaluated lazily at time t, Q.32 */
int64_t fx_activity(const fx_state *s, int i, int64_t t)
{
    return decay_mul(s->act[i], decay(s, t - s->tlast[i]));
}

/* ---- springs and energy criteria (every `period` events) ----------------------------- */
#define OFFSET_LIM ((int64_t)1 << 30)                     /* 16384 px: ex^2 + ey^2 < 2^61 */

static inline int64_t clamp_offset(int64_t v)
{
    return v >= OFFSET_LIM ? OFFSET_LIM - 1 : (v <= -OFFSET_LIM ? -OFFSET_LIM + 1 : v);
}

/* the offsets of eq. (18) of connection k, each clamped to +-16384 px; returns how many
   were */
static inline int offsets(const fx_state *s, int k, int64_t rx, int64_t ry, int64_t *ex, int64_t *ey)
{
    int64_t x = rx - s->dx0[k], y = ry - s->dy0[k];      /* |.| < 2^31 */
    *ex = clamp_offset(x);
    *ey = clamp_offset(y);
    return ((uint64_t)(x + OFFSET_LIM - 1) > (uint64_t)(2 * OFFSET_LIM - 2))
        + ((uint64_t)(y + OFFSET_LIM - 1) > (uint64_t)(2 * OFFSET_LIM - 2));
}

/* a dl (Q.16 x Q.30 = Q.46, exact) rounded to Q.30 when |a dl| < 2 px (the usual case:
   then the products of the Euclidean force and energy fit 64 bits), else ADL_WIDE */
#define ADL_WIDE INT64_MIN
static inline int64_t adl30(const fx_state *s, int k, int64_t dl)
{
    int64_t adl = dl * (int64_t)s->stiff[k];              /* |dl| < 2^31, a <= 2^30 */
    return adl < ((int64_t)1 << 47) && adl > -((int64_t)1 << 47) ? rshr(adl, 16) : ADL_WIDE;
}

/* energies of connection k (Q.32): eq. (12) a dl^2 / 2 from dl (Q.16) and a dl, or from the
   length l (Q.16); eq. (17) a dtheta^2 / 2 from the corrected angle (binary); eq. (20)
   a |e|^2 / 2 from the offsets */
static inline int64_t energy_euclid_dl(const fx_state *s, int k, int64_t dl, int64_t adl)
{
    if (adl != ADL_WIDE)
        return rshr(adl * dl, 15);                        /* Q.30 x Q.16 / 2 -> Q.32 */
    return mulsh(dl * dl, s->stiff[k], 31);
}

static inline int64_t energy_euclid(const fx_state *s, int k, int64_t l)
{
    int64_t dl = l - s->l0[k];                            /* eq. (10) */
    return energy_euclid_dl(s, k, dl, adl30(s, k, dl));
}

static inline int64_t energy_torsion(const fx_state *s, int k, int64_t dth)
{
    int64_t dq = mul32sh(dth, PI_Q28, 31);                /* radians, Q.28 */
    return mulsh(dq * dq, s->stiff[k], 55);
}

static inline int64_t energy_cart(const fx_state *s, int k, int64_t ex, int64_t ey)
{
    return mulsh(ex * ex + ey * ey, s->stiff[k], 31);
}

/* Eq. (14) and the polar form of a spring vector r (Q.16), in two steps so that the spring
   pass can issue all the divisions first (they then overlap).  In the connection's rest
   frame, (u, v) = (c0 . r, c0 x r) rounded to Q.18 (finer than r, so that this rotation
   adds no error of note), with c0 = (cos th0, sin th0) (Q.30): when |v| <= u (r within 45
   degrees of its rest direction, the usual case) the angle from rest is atan(t), t =
   |v| / u (Q.28, 2 zero bits added), the direction r / |r| is c0 rotated by it, and |r| =
   u cos + |v| sin of it, from the tables of atan and 1 / sqrt(1 + t^2); otherwise the
   polar form of r itself minus th0, wrapped to [-pi, pi).  Both: one division. */
typedef struct {
    int64_t t, u, v;                                      /* u = 0: the polar form of r */
} spring_ratio;

static inline spring_ratio geom_ratio(const fx_state *s, int k, int64_t rx, int64_t ry)
{
    spring_ratio g;
    int64_t av;
    int oct;
    g.u = rshr(s->c0x[k] * rx + s->c0y[k] * ry, 28);     /* Q.18, |.| < 2^33 */
    g.v = rshr(s->c0x[k] * ry - s->c0y[k] * rx, 28);
    av = g.v < 0 ? -g.v : g.v;
    if (g.u > 0 && av <= g.u) {
        g.t = ((av << 28) / g.u) << 2;                    /* [0, 2^30] */
        return g;
    }
    g.u = 0;
    g.t = polar_ratio(rx, ry, &g.v, &oct);                /* v = max(|x|, |y|) */
    g.u = -oct - 1;                                       /* < 0: the octant */
    return g;
}

/* the angle from rest (binary angle, [-pi, pi)), the length (Q.16) and direction (Q.30) */
static inline int64_t geom_finish(const fx_state *s, int k, spring_ratio g, int64_t *l,
                                  int64_t *cx, int64_t *cy)
{
    if (g.u > 0) {
        int64_t a = unit_interp(s->atan_tab, g.t);
        int64_t h = unit_interp(s->ihyp_tab, g.t);        /* cos of the angle */
        int64_t sn = rshr(g.t * h, 30);                   /* |sin| */
        int64_t sg = g.v >> 63;                           /* -1 if v < 0: a mask, the sign */
        *l = rshr(g.u * h + ((g.v ^ sg) - sg) * sn, 32);  /* of a spring is data the branch */
        a = (a ^ sg) - sg;                                /* predictor cannot learn */
        sn = (sn ^ sg) - sg;
        *cx = rshr(s->c0x[k] * h - s->c0y[k] * sn, 30);
        *cy = rshr(s->c0y[k] * h + s->c0x[k] * sn, 30);
        return a;
    } else {
        uint32_t th;
        polar_finish(s, g.t, g.v, (int)(-g.u - 1), &th, l, cx, cy);
        th -= s->th0[k];                                  /* mod 2^32 = mod 2 pi */
        return (int64_t)th - ((int64_t)(th >> 31) << 32);
    }
}

static inline int64_t spring_angle(const fx_state *s, int k, int64_t rx, int64_t ry, int64_t *l,
                                   int64_t *cx, int64_t *cy)
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

/* Eqs. (10)-(20) for every connection: the forces summed per tracker into ddx, ddy (Q.32)
   and the criterion's energy (eq. 13: each and their sum saturating at 2^29), which is
   returned.  `used` = the kinds whose geometry the model needs (its springs' kinds and the
   criterion's); each instantiation below contains only that geometry.
   Structure of arrays, one short step per pass: the connections are independent, and a
   pass whose iterations are short lets the processor overlap many of them (one pass doing
   everything per connection is bound by its dependency chain: division, table look-ups,
   products, ~100 cycles). */
static inline __attribute__((always_inline)) int64_t spring_passes(fx_state *s, const int used,
                                                                   int64_t *ddx, int64_t *ddy)
{
    int nc = s->nc, ek = s->ekind, k, sat = 0;
    int64_t fx[FX_MAX_CONNECTIONS], fy[FX_MAX_CONNECTIONS], dth[FX_MAX_CONNECTIONS];
    int64_t total = 0, mean_dth = 0;
    int64_t *en = s->energy[ek];
    int32_t *grx = s->grx, *gry = s->gry;
    if (used & 3) {
        int64_t sum = 0;
        spring_ratio g[FX_MAX_CONNECTIONS];
        for (k = 0; k < nc; k++) {                        /* r, and the divisions */
            int i = s->ca[k], j = s->cb[k];
            int64_t rx = rshr(s->mx[j] - s->mx[i], 16);  /* Q.16, |.| < 2^30 */
            int64_t ry = rshr(s->my[j] - s->my[i], 16);
            grx[k] = (int32_t)rx;
            gry[k] = (int32_t)ry;
            g[k] = geom_ratio(s, k, rx, ry);
        }
        for (k = 0; k < nc; k++) {
            int64_t l, cx, cy;
            dth[k] = geom_finish(s, k, g[k], &l, &cx, &cy);   /* eq. (14) */
            sum += dth[k];
            fx[k] = fy[k] = 0;
            if (used & 1) {
                int64_t dl = l - s->l0[k];                /* eq. (10) */
                int64_t adl = adl30(s, k, dl);
                if (s->kinds[k] & 1) {                    /* eq. (11): a dl (r / l) */
                    if (l <= 0) {
                        cx = s->c0x[k];
                        cy = s->c0y[k];
                    }
                    if (adl != ADL_WIDE) {                /* Q.30 x Q.30 -> Q.32 */
                        fx[k] = rshr(adl * cx, 28);
                        fy[k] = rshr(adl * cy, 28);
                    } else {                              /* dl r / l, Q.32, times a */
                        fx[k] = mulsh(rshr(dl * cx, 14), s->stiff[k], 30);
                        fy[k] = mulsh(rshr(dl * cy, 14), s->stiff[k], 30);
                    }
                }
                if (ek == 0) {                            /* eq. (12), the criterion's */
                    en[k] = sat_energy_of(s, energy_euclid_dl(s, k, dl, adl));
                    total = sat_add(s, total, en[k], E_MAX);
                }
            }
        }
        if ((used & 2) && nc > 0)
            mean_dth = div_round(sum, nc);                /* eq. (15) */
    } else {
        for (k = 0; k < nc; k++) {                        /* r = x_j - x_i, Q.16 */
            int i = s->ca[k], j = s->cb[k];
            grx[k] = (int32_t)rshr(s->mx[j] - s->mx[i], 16);
            gry[k] = (int32_t)rshr(s->my[j] - s->my[i], 16);
            fx[k] = fy[k] = 0;
        }
    }
    for (k = 0; k < nc; k++) {
        int i = s->ca[k], j = s->cb[k], kind = s->kinds[k];
        int64_t rx = grx[k], ry = gry[k], d = 0, ex = 0, ey = 0, gx = fx[k], gy = fy[k];
        uint32_t a = s->stiff[k];
        if (used & 2) {
            d = dth[k] - mean_dth;                        /* eq. (15), binary angle */
            if (kind & 2) {                               /* eq. (16): rotate r by a d */
                int64_t c, sn;
                rotation(s, mul32sh(d, a, 30), &c, &sn);  /* cos - 1, sin */
                gx += rshr(rx * c - ry * sn, 14);         /* l (cos(th + a d) - cos th), Q.32 */
                gy += rshr(rx * sn + ry * c, 14);
            }
        }
        if (used & 4) {
            sat += offsets(s, k, rx, ry, &ex, &ey);       /* eq. (18) */
            if (kind & 4) {                               /* eq. (19): a e, Q.16 x Q.30 -> Q.32 */
                gx += mul32sh(ex, a, 14);
                gy += mul32sh(ey, a, 14);
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
   split into a Q.16 high part and 16 low bits so that no sum exceeds 2^61, then
   recombined exactly. */
static int64_t centre(const fx_state *s, const int64_t *x, int64_t msum)
{
    int64_t hi = 0, lo = 0, q, r;
    int i;
    for (i = 0; i < s->n; i++) {
        int64_t d = x[i] - x[0];                          /* |.| < 2^46 */
        hi += (int64_t)s->mq[i] * (d >> 16);              /* < 2^54 each */
        lo += (int64_t)s->mq[i] * (d & 0xffff);           /* < 2^40 each */
    }
    q = hi / msum;                                        /* floor division */
    r = hi % msum;
    if (r < 0) {
        q -= 1;
        r += msum;
    }
    return x[0] + q * 65536 + div_round(r * 65536 + lo, msum);
}

/* floor(a / b), b > 0 */
static inline int64_t floor_div(int64_t a, int64_t b)
{
    int64_t q = a / b;
    return q - (a % b < 0);
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
    s->n_spring_updates++;
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
        sx += s->mx[i];                                   /* |sum| < 2^51 */
        sy += s->my[i];
    }
    /* [ref] _energy_criteria: eqs. (13), (21), (22) */
    if (nc > 0) {
        s->mean_energy = total / nc;                      /* eq. (13) */
        /* e > s mean; with s >= nc no connection can exceed it (e <= total = nc mean) */
        if (s->escale_never)
            thr = E_MAX;
        else if (s->mean_energy < ((int64_t)1 << 54))      /* escale < nc 2^14 <= 2^21 */
            thr = mulsh(s->mean_energy, s->escale, 14);
        else                                              /* huge energies: 10 bits less */
            thr = mulsh(s->mean_energy >> 10, s->escale, 4);
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
    /* centre of mass G = x0 + sum m_i (x_i - x0) / sum m_i, rounded half up */
    if (n == 0)
        return;
    if (s->equal_mass) {                                  /* = x0 + round(sum (x_i - x0) / n) */
        gx = s->mx[0] + floor_div(2 * (sx - n * s->mx[0]) + n, 2 * (int64_t)n);
        gy = s->my[0] + floor_div(2 * (sy - n * s->my[0]) + n, 2 * (int64_t)n);
    } else {
        int64_t msum = 0;
        for (i = 0; i < n; i++)
            msum += s->mq[i];
        gx = centre(s, s->mx, msum);
        gy = centre(s, s->my, msum);
    }
    for (uint64_t p = pulled; p; p &= p - 1) {            /* eq. (22) */
        i = __builtin_ctzll(p);
        s->mx[i] = sat_pos(s, s->mx[i] + mul62(gx + s->gdx0[i] - s->mx[i], s->energy_gain));
        s->my[i] = sat_pos(s, s->my[i] + mul62(gy + s->gdy0[i] - s->my[i], s->energy_gain));
    }
    for (i = 0; i < n; i++)
        bad |= (uint64_t)!box_kept(s, i) << i;
    /* eq. (21): insensitive when every connection of the tracker is over */
    s->sensitive_mask = calm & (n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << n) - 1);
    while (bad) {                                         /* re-index who left its box */
        fx_reindex(s, __builtin_ctzll(bad));
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
    int64_t l[FX_MAX_CONNECTIONS], dth[FX_MAX_CONNECTIONS], mean_dth = 0, sum = 0, cx, cy;
    if (!(stale & 7))
        return;
    if (stale & 3) {
        for (k = 0; k < nc; k++) {
            dth[k] = spring_angle(s, k, s->grx[k], s->gry[k], &l[k], &cx, &cy);
            sum += dth[k];
        }
        if (nc > 0)
            mean_dth = div_round(sum, nc);
    }
    for (k = 0; k < nc; k++) {
        int64_t ex, ey;
        if (stale & 1)
            s->energy[0][k] = energy_euclid(s, k, l[k]);
        if (stale & 2)
            s->energy[1][k] = stale & 8 ? 0 : energy_torsion(s, k, dth[k] - mean_dth);
        if (stale & 4) {
            offsets(s, k, s->grx[k], s->gry[k], &ex, &ey);
            s->energy[2][k] = energy_cart(s, k, ex, ey);
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
    s->gate_q20 = (s->gate + ((int64_t)1 << 20) - 1) >> 20;   /* the gate is Q.40 */
    s->decay_span = s->dt_max < ((int64_t)1 << (2 * FX_DECAY_BITS)) ? s->dt_max
                    : ((int64_t)1 << (2 * FX_DECAY_BITS));
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
