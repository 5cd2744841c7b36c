/* TELEMETRY tracker records from the fixed-point state: see fixed_telemetry.h. */
#include "fixed_telemetry.h"

/* ceil(2^((k + 0.5) / 16) 2^30), k = 0..15: m (Q.30, in [1, 2)) rounds 16 log2(m) up past k
   iff m >= entry k (the thresholds are irrational, so no tie) */
static const uint32_t LOG2_HALF_STEPS[FX_TELE_ACT_STEPS] = {
    1097253709u, 1145833281u, 1196563654u, 1249540053u, 1304861917u, 1362633090u,
    1422962011u, 1485961921u, 1551751076u, 1620452966u, 1692196548u, 1767116489u,
    1845353420u, 1927054196u, 2012372174u, 2101467502u};

static inline int bitlen_u64(uint64_t v)              /* v > 0 */
{
    return 64 - __builtin_clzll(v);
}

/* x, y: round to 1/16 px, clamp to the 15 bits the wire has */
static inline uint16_t tele_pos(int64_t q32, int flag)
{
    int64_t v = (q32 + ((int64_t)1 << (FX_TELE_POS_SHIFT - 1))) >> FX_TELE_POS_SHIFT;
    if (v < 0)
        v = 0;
    if (v > 0x7FFF)
        v = 0x7FFF;
    return (uint16_t)(v | (flag ? 0x8000 : 0));
}

/* sigma in Q.20 px from a Q.40 px^2 variance (0 if it is not positive) */
static inline uint64_t tele_sigma_q20(int64_t var_q40)
{
    return var_q40 > 0 ? fx_isqrt64((uint64_t)var_q40) : 0;
}

static inline uint8_t tele_sigma(uint64_t sigma_q20)
{
    uint64_t v = (sigma_q20 + ((uint64_t)1 << (FX_TELE_SIGMA_SHIFT - 1))) >> FX_TELE_SIGMA_SHIFT;
    return (uint8_t)(v > 255 ? 255 : v);
}

/* round(127 sxy / (sx sy)), clamped to [-127, 127]; 0 if a deviation is 0.  32-bit
   arithmetic: den = sx sy (Q.40, one 32 x 32 product; sigma Q.20 <= 2^26) and |sxy| are
   scaled right together until den < 2^23, then (254 |sxy| + den) / (2 den) is one 32-bit
   division (|sxy| <= den, as |rho| <= 0.99; a larger one is clamped first) */
static inline int8_t tele_rho(int64_t sxy_q40, uint64_t sx_q20, uint64_t sy_q20)
{
    uint64_t den = (uint64_t)(uint32_t)sx_q20 * (uint32_t)sy_q20;
    uint64_t a = (uint64_t)(sxy_q40 < 0 ? -sxy_q40 : sxy_q40);
    uint32_t d, n, r;
    int k;
    if (den == 0)
        return 0;
    k = bitlen_u64(den) > 23 ? bitlen_u64(den) - 23 : 0;
    d = (uint32_t)(den >> k);
    if (a > den || d == 0)
        r = FX_TELE_RHO_SCALE;
    else {
        n = (uint32_t)(a >> k);
        r = (2 * FX_TELE_RHO_SCALE * n + d) / (2 * d);   /* round half up on |rho| */
        if (r > FX_TELE_RHO_SCALE)
            r = FX_TELE_RHO_SCALE;
    }
    return (int8_t)(sxy_q40 < 0 ? -(int32_t)r : (int32_t)r);
}

/* round(16 log2(1 + A)) for an activity A in Q.32, saturated at 255 */
static inline uint8_t tele_activity(int64_t act_q32)
{
    uint64_t v = (uint64_t)(act_q32 > 0 ? act_q32 : 0) + ((uint64_t)1 << 32);   /* 1 + A */
    int e = bitlen_u64(v) - 1;                            /* floor(log2 v) >= 32 */
    uint64_t m = e >= 30 ? v >> (e - 30) : v << (30 - e); /* mantissa in [2^30, 2^31) */
    int64_t code = (int64_t)FX_TELE_ACT_STEPS * (e - 32);
    int k = 0;
    while (k < FX_TELE_ACT_STEPS && m >= LOG2_HALF_STEPS[k])
        k++;
    code += k;
    return (uint8_t)(code > 255 ? 255 : code);
}

void fx_tele_records(const fx_state *s, int64_t t, uint8_t *out)
{
    int i;
    for (i = 0; i < s->n; i++) {
        int64_t a = fx_activity(s, i, t), mx, my;
        uint64_t sx = tele_sigma_q20(s->sxx[i]), sy = tele_sigma_q20(s->syy[i]);
        uint16_t x, y;
        fx_predicted(s, i, t, &mx, &my);                  /* eq. (M1): the means at t */
        x = tele_pos(mx, a > s->act_thr);
        y = tele_pos(my, (int)((s->sensitive_mask >> i) & 1));
        uint8_t *r = out + (int64_t)i * FX_TELE_RECORD;
        r[0] = (uint8_t)(x & 0xFF);
        r[1] = (uint8_t)(x >> 8);
        r[2] = (uint8_t)(y & 0xFF);
        r[3] = (uint8_t)(y >> 8);
        r[4] = tele_sigma(sx);
        r[5] = tele_sigma(sy);
        r[6] = (uint8_t)tele_rho(s->sxy[i], sx, sy);
        r[7] = tele_activity(a);
    }
}
