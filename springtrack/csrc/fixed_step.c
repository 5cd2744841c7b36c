/* Integer-only tracker step: the fixed-point translation of springtrack/_kernel.pyx.
 *
 * Equations cite Valeiras et al. 2015; [ref] names the function of
 * springtrack/reference.py a block mirrors.  Q formats are listed in fixed_step.h and
 * justified, with their error bounds, in docs/fixed_point.md.  No floating-point type
 * appears in this file: it compiles with `gcc -mgeneral-regs-only`.
 */
#include "fixed_step.h"

#define ONE_Q30 ((int64_t)1 << 30)
#define RHO_Q30 1063004406u        /* 0.99 (reference.RHO_MAX), Q.30 */
#define RHO2_Q30 1052374362u       /* 0.99^2, Q.30 */
#define HALF_LOG2E_Q30 774541002u  /* log2(e) / 2, Q.30: exp(-d2/2) = 2^(-d2 log2(e)/2) */
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

/* exp(-dt / tau), Q.30, for dt in us (eq. 6) */
static inline uint32_t decay(const fx_state *s, int64_t dt)
{
    if (dt <= 0)
        return (uint32_t)ONE_Q30;
    if (dt >= s->dt_max)
        return 0;
    return exp2neg(s, dt * s->k_tau);                  /* < 41 * 2^40 */
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
            *c = ONE_Q30 - r2 / 2;
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
   octant ratio t = min / max, then tables of atan(t), sqrt(1 + t^2), 1 / sqrt(1 + t^2). */
static inline void polar(const fx_state *s, int64_t x, int64_t y, uint32_t *ang, int64_t *len,
                         int64_t *cx, int64_t *cy)
{
    int64_t ax = x < 0 ? -x : x, ay = y < 0 ? -y : y, big, small, t, a, h, cbig, csmall;
    int swap = ay > ax;
    if (ax == 0 && ay == 0) {
        *ang = 0;
        *len = *cx = *cy = 0;
        return;
    }
    big = swap ? ay : ax;
    small = swap ? ax : ay;
    t = (small << 30) / big;                              /* [0, 2^30] */
    a = unit_interp(s->atan_tab, t);
    *len = rshr(big * unit_interp(s->hyp_tab, t), 30);    /* big sqrt(1 + t^2) */
    h = unit_interp(s->ihyp_tab, t);                      /* cos of the octant angle */
    cbig = h;
    csmall = rshr(t * h, 30);
    if (swap) {
        a = ((int64_t)1 << 30) - a;
        *cx = csmall;
        *cy = cbig;
    } else {
        *cx = cbig;
        *cy = csmall;
    }
    if (x < 0) {
        a = ((int64_t)1 << 31) - a;
        *cx = -*cx;
    }
    if (y < 0) {
        a = -a;
        *cy = -*cy;
    }
    *ang = (uint32_t)((uint64_t)a & 0xffffffffu);
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
static void index_set(fx_state *s, int i, int on)
{
    uint64_t bit = (uint64_t)1 << i;
    int cx, cy;
    for (cy = s->box_y0[i]; cy <= s->box_y1[i]; cy++)
        for (cx = s->box_x0[i]; cx <= s->box_x1[i]; cx++) {
            if (on)
                s->cells[cy * s->gw + cx] |= bit;
            else
                s->cells[cy * s->gw + cx] &= ~bit;
        }
}

static inline int32_t cell_of(int64_t v, int32_t gmax)
{
    int64_t c = v >> (16 + FX_CELL_SHIFT);                /* v Q.16 px; floor */
    return c < 0 ? 0 : (c > gmax ? gmax : (int32_t)c);
}

/* (Re)insert tracker i with its gate box sqrt(gate * sxx) x sqrt(gate * syy), enlarged by
   2^-FX_INDEX_GROW_SHIFT of itself and FX_INDEX_MARGIN, so that a covariance growing a
   little does not re-index at once (the index only selects candidates: any box that
   contains the gate box gives the same results). */
void fx_reindex(fx_state *s, int i)
{
    int64_t hx = (int64_t)isqrt64(s, (uint64_t)s->gsxx[i]) + 1;      /* Q.16 */
    int64_t hy = (int64_t)isqrt64(s, (uint64_t)s->gsyy[i]) + 1;
    hx += (hx >> FX_INDEX_GROW_SHIFT) + FX_INDEX_MARGIN;
    hy += (hy >> FX_INDEX_GROW_SHIFT) + FX_INDEX_MARGIN;
    s->bx_lo[i] = pos16(s->mx[i]) - hx;
    s->bx_hi[i] = pos16(s->mx[i]) + hx;
    s->by_lo[i] = pos16(s->my[i]) - hy;
    s->by_hi[i] = pos16(s->my[i]) + hy;
    index_set(s, i, 0);
    s->box_x0[i] = cell_of(s->bx_lo[i], s->gw - 1);
    s->box_x1[i] = cell_of(s->bx_hi[i], s->gw - 1);
    s->box_y0[i] = cell_of(s->by_lo[i], s->gh - 1);
    s->box_y1[i] = cell_of(s->by_hi[i], s->gh - 1);
    index_set(s, i, 1);
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

static inline int box_ok(const fx_state *s, int i)
{
    /* positions to Q.16 (floor): an error < 2^-16 px, far inside the 3 px index margin;
       both sides of an axis are inside iff the nearer one is (one square per axis) */
    int64_t x = pos16(s->mx[i]), y = pos16(s->my[i]);
    return inside(min64(x - s->bx_lo[i], s->bx_hi[i] - x), s->gsxx[i])
        && inside(min64(y - s->by_lo[i], s->by_hi[i] - y), s->gsyy[i]);
}

/* Re-index tracker i if its exact gate box has left the box it is indexed with. */
static inline void check_index(fx_state *s, int i)
{
    if (!box_ok(s, i))
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
   then the inverse covariance of eq. (2) and the gate box.  One division. */
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
    if (b * b > mulsh(p, RHO2_Q30, 30)) {              /* |rho| > 0.99: clamp */
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
    s->gsxx[i] = mulsh(sxx, s->gate_q24, 32);          /* gate * sxx, Q.32 px^2 */
    s->gsyy[i] = mulsh(syy, s->gate_q24, 32);
}

void fx_refresh(fx_state *s, int i)
{
    refresh(s, i);
}

/* [ref] _update: eqs. (2)-(6) for the winning tracker i; dx, dy Q.32 from the pre-update
   mean (|.| < 2^41 inside the gate), d2 Q.40. */
static inline void update_tracker(fx_state *s, int i, int64_t t, int64_t dx, int64_t dy, int64_t d2)
{
    int64_t p = (int64_t)exp2neg(s, mulsh(d2, HALF_LOG2E_Q30, 30));   /* eq. (2), Q.30 */
    int64_t act = mulsh(s->act[i], decay(s, t - s->tlast[i]), 30) + p * 4;  /* eq. (6) */
    if (act > ACT_MAX) {
        act = ACT_MAX;
        s->sat_activity++;
    }
    s->act[i] = act;
    s->tlast[i] = t;
    int64_t ex = rshr(dx, 12), ey = rshr(dy, 12);         /* Q.20 px, < 2^29 */
    /* eq. (3) */
    s->mx[i] = sat_pos(s, s->mx[i] + mul62(dx, s->a1));
    s->my[i] = sat_pos(s, s->my[i] + mul62(dy, s->a1));
    /* eq. (4)-(5): S <- (1 - a2) S + g e e^T, e = (dx, dy); ex ex is Q.40 px^2 */
    s->sxx[i] += mul62(ex * ex, s->cov_gain) - mul62(s->sxx[i], s->a2);
    s->sxy[i] += mul62(ex * ey, s->cov_gain) - mul62(s->sxy[i], s->a2);
    s->syy[i] += mul62(ey * ey, s->cov_gain) - mul62(s->syy[i], s->a2);
    refresh(s, i);
    check_index(s, i);
}

/* One event (Algorithm 1).  Returns the winning tracker, FX_NO_TRACKER or a skip code. */
static inline int step_one(fx_state *s, int64_t t, int32_t x, int32_t y)
{
    int64_t fx, fy, best_d2, bdx = 0, bdy = 0;
    uint64_t m;
    int best = FX_NO_TRACKER;
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
    fx = (int64_t)x << FX_POS_FRAC;
    fy = (int64_t)y << FX_POS_FRAC;
    best_d2 = s->gate;
    /* eq. (2): the sensitive trackers indexed in this event's cell, in index order, so
       ties resolve as in the reference's full scan */
    m = s->cells[(y >> FX_CELL_SHIFT) * s->gw + (x >> FX_CELL_SHIFT)] & s->sensitive_mask;
    while (m) {
        int i = __builtin_ctzll(m);
        int64_t dx, dy;
        __int128 d2;
        m &= m - 1;
        dx = fx - s->mx[i];                               /* Q.32, |.| < 2^46 */
        dy = fy - s->my[i];
        d2 = qform(s->ia[i], s->ib2[i], s->ic[i], dx, dy);
        if (d2 < best_d2) {
            best_d2 = (int64_t)d2;
            best = i;
            bdx = dx;
            bdy = dy;
        }
    }
    if (best >= 0) {
        update_tracker(s, best, t, bdx, bdy, best_d2 < 0 ? 0 : best_d2);
        s->n_assigned++;
    }
    if (++s->since_spring >= s->period) {
        s->since_spring = 0;
        fx_springs(s);
    }
    return best;
}

int fx_step(fx_state *s, int64_t t, int32_t x, int32_t y)
{
    return step_one(s, t, x, y);
}

int64_t fx_steps(fx_state *s, const fx_event *ev, int64_t n, int64_t t_stop)
{
    for (int64_t k = 0; k < n; k++) {
        if (ev[k].t >= t_stop && ev[k].t >= s->last_t)
            return k;
        step_one(s, ev[k].t, ev[k].x, ev[k].y);
    }
    return n;
}

/* eq. (6) evaluated lazily at time t, Q.32 */
int64_t fx_activity(const fx_state *s, int i, int64_t t)
{
    return mulsh(s->act[i], decay(s, t - s->tlast[i]), 30);
}

/* ---- springs and energy criteria (every `period` events) ----------------------------- */
#define OFFSET_LIM ((int64_t)1 << 30)                     /* 16384 px: ex^2 + ey^2 < 2^61 */

static inline int64_t clamp_offset(fx_state *s, int64_t v)
{
    if (v >= OFFSET_LIM || v <= -OFFSET_LIM) {
        s->sat_energy++;
        return v < 0 ? -OFFSET_LIM + 1 : OFFSET_LIM - 1;
    }
    return v;
}

static void energy_criteria(fx_state *s);

/* [ref] springs: displacements from the same positions, applied together (Jacobi).  The
   forces of eqs. (11), (16), (19) are summed per tracker (Q.32 px, |sum| < 2^55) and
   divided by the mass once: the same sums as the reference's per-connection f / m_i. */
void fx_springs(fx_state *s)
{
    int n = s->n, nc = s->nc, k, i, j;
    int64_t ddx[FX_MAX_TRACKERS], ddy[FX_MAX_TRACKERS];
    int64_t dth_raw[FX_MAX_CONNECTIONS], pl[FX_MAX_CONNECTIONS];
    int64_t pcx[FX_MAX_CONNECTIONS], pcy[FX_MAX_CONNECTIONS];
    int64_t mean_dth = 0;
    s->n_spring_updates++;
    for (i = 0; i < n; i++)
        ddx[i] = ddy[i] = 0;
    if (s->need_torsion && nc > 0) {
        for (k = 0; k < nc; k++) {                        /* eq. (14), wrapped to [-pi, pi) */
            uint32_t th;
            i = s->ca[k];
            j = s->cb[k];
            polar(s, rshr(s->mx[j] - s->mx[i], 16), rshr(s->my[j] - s->my[i], 16), &th,
                  &pl[k], &pcx[k], &pcy[k]);
            th -= s->th0[k];                              /* mod 2^32 = mod 2 pi */
            dth_raw[k] = th >= 0x80000000u ? (int64_t)th - ((int64_t)1 << 32) : (int64_t)th;
            mean_dth += dth_raw[k];
        }
        mean_dth = div_round(mean_dth, nc);
    }
    for (k = 0; k < nc; k++) {
        int64_t rx, ry, l, dl, ex, ey, cx = 0, cy = 0;
        int kind = s->kinds[k];
        i = s->ca[k];
        j = s->cb[k];
        rx = rshr(s->mx[j] - s->mx[i], 16);               /* Q.16, |.| < 2^30 */
        ry = rshr(s->my[j] - s->my[i], 16);
        if (s->need_torsion) {                            /* polar form computed above */
            l = pl[k];
            cx = pcx[k];
            cy = pcy[k];
        } else {
            l = (int64_t)isqrt64(s, (uint64_t)(rx * rx + ry * ry));   /* Q.16 */
            if ((kind & 1) && l > 0) {                    /* r / l in Q.30, one division */
                int64_t inv = ((int64_t)1 << 60) / l;     /* 2^60 / l, >= 2^29 */
                cx = rshr(rx * inv, 30);                  /* rx inv <= 2^60 (|rx| <= l) */
                cy = rshr(ry * inv, 30);
            }
        }
        dl = l - s->l0[k];                                /* eq. (10) */
        s->energy[0][k] = mulsh(dl * dl, s->stiff[k], 31);     /* eq. (12): a dl^2 / 2 */
        ex = clamp_offset(s, rx - s->dx0[k]);             /* eq. (18) */
        ey = clamp_offset(s, ry - s->dy0[k]);
        s->energy[2][k] = mulsh(ex * ex + ey * ey, s->stiff[k], 31);   /* eq. (20) */
        if (kind & 1) {                                   /* eq. (11): a dl (r / l) / m */
            int64_t qx, qy;
            if (l > 0) {                                  /* dl r / l, Q.32 */
                qx = rshr(dl * cx, 14);
                qy = rshr(dl * cy, 14);
            } else {
                qx = rshr(dl * s->c0x[k], 14);
                qy = rshr(dl * s->c0y[k], 14);
            }
            qx = mulsh(qx, s->stiff[k], 30);              /* a dl r / l */
            qy = mulsh(qy, s->stiff[k], 30);
            ddx[i] += qx;
            ddy[i] += qy;
            ddx[j] -= qx;
            ddy[j] -= qy;
        }
        if (s->need_torsion) {
            int64_t dth = dth_raw[k] - mean_dth;          /* eq. (15), binary angle */
            int64_t dq = mul32sh(dth, PI_Q28, 31);       /* radians, Q.28 */
            s->energy[1][k] = mulsh(dq * dq, s->stiff[k], 55);  /* eq. (17) */
            if (kind & 2) {                               /* eq. (16): rotate r by a dth */
                int64_t c, sn, ux, uy;
                cossin(s, mul32sh(dth, s->stiff[k], 30), &c, &sn);
                c -= ONE_Q30;
                ux = rshr(rx * c - ry * sn, 14);          /* l (cos(th + a dth) - cos th), Q.32 */
                uy = rshr(rx * sn + ry * c, 14);
                ddx[i] += ux;
                ddy[i] += uy;
                ddx[j] -= ux;
                ddy[j] -= uy;
            }
        } else {
            s->energy[1][k] = 0;
        }
        if (kind & 4) {                                   /* eq. (19) */
            int64_t fx = mul32sh(ex, s->stiff[k], 14);    /* a e: Q.16 x Q.30 -> Q.32 */
            int64_t fy = mul32sh(ey, s->stiff[k], 14);
            ddx[i] += fx;
            ddy[i] += fy;
            ddx[j] -= fx;
            ddy[j] -= fy;
        }
    }
    for (i = 0; i < n; i++) {                             /* the sums of forces / m_i */
        s->mx[i] = sat_pos(s, s->mx[i] + mulsh(ddx[i], s->invm[i], 24));
        s->my[i] = sat_pos(s, s->my[i] + mulsh(ddy[i], s->invm[i], 24));
    }
    energy_criteria(s);
    for (i = 0; i < n; i++)
        check_index(s, i);
}

/* x0 + sum m_i (x_i - x0) / sum m_i for Q.32 positions: the offsets are split into a
   Q.16 high part and 16 low bits so that no sum exceeds 2^61, then recombined exactly. */
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

/* [ref] _energy_criteria: eqs. (13), (21), (22) */
static void energy_criteria(fx_state *s)
{
    int n = s->n, nc = s->nc, k, i;
    int over[FX_MAX_TRACKERS];
    int64_t total = 0, thr, gx, gy, msum = 0;
    int64_t *e;
    if (nc == 0)
        return;
    e = s->energy[s->ekind];
    for (k = 0; k < nc; k++) {                            /* eq. (13) */
        if (e[k] > E_MAX) {
            e[k] = E_MAX;
            s->sat_energy++;
        }
        total = sat_add(s, total, e[k], E_MAX);
    }
    s->mean_energy = total / nc;
    /* e > s mean; with s >= nc no connection can exceed it (e <= total = nc mean) */
    if (s->escale_never)
        thr = E_MAX;
    else if (s->mean_energy < ((int64_t)1 << 54))          /* escale < nc 2^14 <= 2^21 */
        thr = mulsh(s->mean_energy, s->escale, 14);
    else                                                  /* huge energies: 10 bits less */
        thr = mulsh(s->mean_energy >> 10, s->escale, 4);
    for (i = 0; i < n; i++)
        over[i] = 0;
    if (!s->escale_never)
        for (k = 0; k < nc; k++)
            if (e[k] > thr) {
                over[s->ca[k]]++;
                over[s->cb[k]]++;
            }
    /* centre of mass G = x0 + sum m_i (x_i - x0) / sum m_i */
    for (i = 0; i < n; i++)
        msum += s->mq[i];
    gx = centre(s, s->mx, msum);
    gy = centre(s, s->my, msum);
    s->sensitive_mask = 0;
    for (i = 0; i < n; i++) {
        if (over[i] > 0) {                                /* eq. (22) */
            s->mx[i] = sat_pos(s, s->mx[i] + mul62(gx + s->gdx0[i] - s->mx[i], s->energy_gain));
            s->my[i] = sat_pos(s, s->my[i] + mul62(gy + s->gdy0[i] - s->my[i], s->energy_gain));
        }
        if (!(s->degree[i] > 0 && over[i] == s->degree[i]))   /* eq. (21) */
            s->sensitive_mask |= (uint64_t)1 << i;
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
