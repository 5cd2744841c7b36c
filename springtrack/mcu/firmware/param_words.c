/* param_words.h: springtrack.params' checks and springtrack.fixed.q.params_words, on the
 * core, in integers (xfloat.h).  The words equal the host's where its libm's exp and log
 * round as xfloat.c does (docs/mcu.md, "PARAM_SET by name"). */
#include "param_words.h"
#include "wire_codes.h"
#include "xfloat.h"

uint64_t param_rd64(const uint8_t *p)
{
    uint64_t v = 0;
    int k;
    for (k = 7; k >= 0; k--)
        v = v << 8 | p[k];
    return v;
}

/* the parameter named p[0..n), or -1 */
int param_lookup(const uint8_t *p, uint32_t n)
{
    int k;
    uint32_t c;
    for (k = 0; k < PARAM_COUNT; k++) {
        const char *s = param_specs[k].name;
        for (c = 0; c < n && s[c] && s[c] == (char)p[c]; c++)
            ;
        if (c == n && !s[c])
            return k;
    }
    return -1;
}

int param_choice(int k, const uint8_t *p, uint32_t n)
{
    int c;
    uint32_t j;
    for (c = 0; c < param_specs[k].nchoices; c++) {
        const char *s = param_specs[k].choices[c];
        for (j = 0; j < n && s[j] && s[j] == (char)p[j]; j++)
            ;
        if (j == n && !s[j])
            return c;
    }
    return -1;
}

/* ---- springtrack.fixed.q.params_q in integers --------------------------------------------- */
static const dbits_t TWO_NEG = D_NEG(D_TWO);

/* springtrack.gate.covariance_gain: alpha_covariance / covariance_bias(alpha_position, gate) */
static dbits_t covariance_gain(const values_t *v, dbits_t gate)
{
    dbits_t a1 = v->f[PARAM_ALPHA_POSITION];
    dbits_t j = d_div(a1, d_sub(D_TWO, a1));            /* J = a1 / (2 - a1) */
    dbits_t onej = d_add(D_ONE, j);
    dbits_t h = d_div(gate, onej);
    dbits_t e = d_exp_neg(d_mul(D_HALF, h));            /* kappa(h), springtrack.gate */
    dbits_t kappa = d_div(d_sub(D_TWO, d_mul(d_add(h, D_TWO), e)),
                           d_mul(D_TWO, d_sub(D_ONE, e)));
    return d_div(v->f[PARAM_ALPHA_COVARIANCE], d_mul(onej, kappa));
}

/* q.mantissa / q.gain_pair's shift: 30 - floor(log2 big) within [lo, 62], then down while
   a value needs 32 bits */
static int32_t shift_for(dbits_t big, dbits_t other, int32_t lo)
{
    int32_t sh = 62;
    if (!d_le(big, D_ZERO)) {
        sh = 30 - d_ilogb(big);
        sh = sh < lo ? lo : sh > 62 ? 62 : sh;
    }
    while (sh > lo && (d_round_scaled(big, sh) >= (int64_t)1 << 31
                       || d_round_scaled(other, sh) >= (int64_t)1 << 31))
        sh--;
    return sh;
}

static int32_t cap31(int64_t v) { return (int32_t)(v < ((int64_t)1 << 31) - 1 ? v : ((int64_t)1 << 31) - 1); }

static void put64(int32_t *w, int64_t v)
{
    w[0] = (int32_t)(uint32_t)(uint64_t)v;
    w[1] = (int32_t)(uint32_t)((uint64_t)v >> 32);
}

/* ceil(n / d) for d > 0 */
static uint64_t ceil_div(uint64_t n, uint64_t d)
{
    uint64_t q = 0, r = 0;
    int b;
    for (b = 63; b >= 0; b--) {
        r = r << 1 | (n >> b & 1);
        if (r >= d) {
            r -= d;
            q |= (uint64_t)1 << b;
        }
    }
    return q + (r != 0);
}

/* the exp(-j / tau) tables of q.decay_tables, Q.30 */
static void decay_tables(dbits_t tau, int32_t *lo, int32_t *hi)
{
    static const dbits_t LIMIT = 0x4044000000000000ull;   /* 40: exp(-40) 2^30 < 1/2 */
    int32_t j;
    for (j = 0; j < (1 << Q_DECAY_BITS); j++) {
        dbits_t x = d_div(d_from_int(j), tau), y = d_div(d_from_int((int64_t)j << Q_DECAY_BITS), tau);
        lo[j] = d_lt(LIMIT, x) ? 0 : (int32_t)d_round_scaled(d_exp_neg(x), 30);
        hi[j] = d_lt(LIMIT, y) ? 0 : (int32_t)d_round_scaled(d_exp_neg(y), 30);
    }
}

/* q.motion_q: ceil(tau_m), 1 / tau_m as a mantissa and shift ((0, 31): off), the horizon
   Q.8, c_h Q.30, max(alpha1, 1e-6) Q.30, alpha1 / (1 - alpha1) Q.32 (capped), sigma_max Q.32 */
static void motion_words(const values_t *v, int32_t *w)
{
    static const dbits_t A1_MIN = 0x3eb0c6f7a0b5ed8dull;              /* 1e-6 */
    dbits_t tau = v->f[PARAM_MOTION_TAU_US], a1 = v->f[PARAM_ALPHA_POSITION], inv;
    int64_t c = d_round_scaled(tau, 0), thr = INT64_MAX;
    int32_t sh = 31;
    if (d_lt(d_from_int(c), tau))        /* math.ceil */
        c++;
    w[0] = (int32_t)c;
    w[1] = 0;
    if (d_lt(D_ZERO, tau)) {
        inv = d_div(D_ONE, tau);
        sh = shift_for(inv, D_ZERO, 24);
        w[1] = (int32_t)d_round_scaled(inv, sh);
    }
    w[2] = sh;
    w[3] = (int32_t)d_round_scaled(v->f[PARAM_PREDICTION_HORIZON_US], Q_LEAD_FRAC);
    w[4] = (int32_t)d_round_scaled(v->f[PARAM_POLARITY_GAIN], Q_GAIN_FRAC);
    if (d_lt(a1, A1_MIN))
        a1 = A1_MIN;
    w[5] = (int32_t)d_round_scaled(a1, Q_GAIN_FRAC);
    if (d_lt(a1, D_ONE))
        thr = d_round_scaled(d_div(a1, d_sub(D_ONE, a1)), Q_KALMAN_FRAC);
    put64(w + 6, thr);
    put64(w + 8, d_round_scaled(v->f[PARAM_SIGMA_MAX_PX], Q_POS_FRAC));
}

/* q.params_words of the values (checked) for nc connections; `tables`: 0 keeps w's decay
   tables (those of the same activity_tau_us) */
void param_words(const values_t *v, int32_t nc, int32_t *w, int tables)
{
    dbits_t gate = d_mul(TWO_NEG, d_log(v->f[PARAM_P_THRESHOLD]));    /* Params.gate_d2 */
    dbits_t tau = v->f[PARAM_ACTIVITY_TAU_US], g = covariance_gain(v, gate);
    dbits_t a2 = v->f[PARAM_ALPHA_COVARIANCE], es = v->f[PARAM_ENERGY_SCALE];
    dbits_t thr = v->f[PARAM_ACTIVITY_THRESHOLD], smin = v->f[PARAM_SIGMA_MIN_PX];
    dbits_t smax = v->f[PARAM_SIGMA_MAX_PX];
    static const dbits_t ACT_MAX = 0x41c0000000000000ull;            /* 2^29 */
    int64_t k_tau = d_round_scaled(d_div(Q_LOG2E, tau), Q_KTAU_FRAC);
    int never = d_le(d_from_int(nc > 1 ? nc : 1), es);                 /* e <= nc mean */
    int32_t sh = shift_for(d_lt(g, a2) ? a2 : g, d_lt(g, a2) ? g : a2, 31);
    w[W_A1] = (int32_t)d_round_scaled(v->f[PARAM_ALPHA_POSITION], Q_GAIN_FRAC);
    w[W_COV_GM] = cap31(d_round_scaled(g, sh));
    w[W_COV_AM] = cap31(d_round_scaled(a2, sh));
    w[W_COV_SH] = sh;
    w[W_ENERGY_GAIN] = (int32_t)d_round_scaled(v->f[PARAM_ENERGY_GAIN], Q_GAIN_FRAC);
    w[W_GATE] = (int32_t)d_round_scaled(gate, Q_D2_FRAC);
    w[W_K_TAU] = (int32_t)(uint32_t)(k_tau < 0xFFFFFFFFll ? k_tau : 0xFFFFFFFFll);
    put64(w + W_DT_MAX, (int64_t)ceil_div((uint64_t)32 << Q_KTAU_FRAC, (uint64_t)k_tau));
    put64(w + W_ACT_THR, d_round_scaled(d_lt(thr, ACT_MAX) ? thr : ACT_MAX, Q_ACT_FRAC));
    sh = shift_for(never ? D_ZERO : es, D_ZERO, 24);
    w[W_ESCALE] = (int32_t)d_round_scaled(never ? D_ZERO : es, sh);
    w[W_ESCALE + 1] = sh;
    w[W_ESCALE_NEVER] = never;
    put64(w + W_SMIN2, d_round_scaled(d_mul(smin, smin), Q_COV_FRAC));
    put64(w + W_SMAX2, d_round_scaled(d_mul(smax, smax), Q_COV_FRAC));
    w[W_PERIOD] = (int32_t)v->i[PARAM_SPRING_PERIOD];
    w[W_EKIND] = (int32_t)v->i[PARAM_ENERGY_KIND];
    put64(w + W_TAU_BITS, (int64_t)tau);
    w[W_PULL_SIM] = v->i[PARAM_PULL_FRAME] == PARAM_FRAME_SIMILARITY;
    w[W_CAR_SIM] = v->i[PARAM_CARTESIAN_FRAME] == PARAM_FRAME_SIMILARITY;
    if (tables)
        decay_tables(tau, w + W_DECAY_LO, w + W_DECAY_HI);
    motion_words(v, w + W_MOTION);
}

/* ---- the checks of springtrack.params.check, Params and the fixed kernel ------------------ */
static int refuse(buf_t *w, int code, int k, const char *what)
{
    if (k >= 0) {
        b_str(w, param_specs[k].name);
        b_u8(w, ' ');
    }
    b_str(w, what);
    return code;
}

/* the value of parameter k with wire type tag and bytes val, into v; 0 or a NACK code */
int param_check_value(int k, uint8_t tag, const uint8_t *val, values_t *v, buf_t *w)
{
    const param_spec_t *s = &param_specs[k];
    dbits_t x;
    int64_t i;
    if (s->kind == PARAM_STR) {
        if (tag != 's')
            return refuse(w, NACK_WRONG_TYPE, k, "must be one of its choices (a string)");
        if ((v->i[k] = param_choice(k, val + 1, val[0])) < 0)
            return refuse(w, NACK_OUT_OF_RANGE, k, "must be one of its choices");
        return 0;
    }
    if (tag != 'i' && tag != 'f')
        return refuse(w, NACK_WRONG_TYPE, k, "must be a number");
    if (tag == 'f') {
        x = param_rd64(val);
        if (!d_finite(x))
            return refuse(w, NACK_OUT_OF_RANGE, k, "must be finite and in range");
        if (s->kind == PARAM_INT) {      /* a whole number (else WRONG_TYPE), then in range */
            if ((x << 1) && d_ilogb(x) < 52 && d_from_int(d_round_scaled(x, 0)) != x)
                return refuse(w, NACK_WRONG_TYPE, k, "must be a whole number");
            if (d_lt(x, d_from_int(s->ilo)) || d_lt(d_from_int(s->ihi), x))
                return refuse(w, NACK_OUT_OF_RANGE, k, "out of range");
            v->i[k] = d_round_scaled(x, 0);
            return 0;
        }
    } else {
        i = (int64_t)param_rd64(val);
        x = d_from_int(i);               /* float(value) */
        if (s->kind == PARAM_INT) {      /* float(value) != int(value): WRONG_TYPE */
            uint64_t u = i < 0 ? (uint64_t)0 - (uint64_t)i : (uint64_t)i;
            while (u && !(u & 1))
                u >>= 1;
            if (u >> 53)
                return refuse(w, NACK_WRONG_TYPE, k, "must be a whole number");
            if (i < s->ilo || i > s->ihi)
                return refuse(w, NACK_OUT_OF_RANGE, k, "out of range");
            v->i[k] = i;
            return 0;
        }
    }
    if (d_lt(x, s->lo) || d_lt(s->hi, x))
        return refuse(w, NACK_OUT_OF_RANGE, k, "out of range");
    v->f[k] = x;
    return 0;
}

/* Params.__post_init__, springtrack.limits.check_params and the fixed kernel's params_q */
int param_check_set(const values_t *v, int32_t nc, buf_t *w)
{
    dbits_t gate, g;
    if (!d_lt(v->f[PARAM_SIGMA_MIN_PX], v->f[PARAM_SIGMA_MAX_PX]))
        return refuse(w, NACK_OUT_OF_RANGE, -1, "sigma_min_px must be below sigma_max_px");
    if (d_lt(LIMIT_SIGMA_MAX_PX, v->f[PARAM_SIGMA_MAX_PX]))
        return refuse(w, NACK_OUT_OF_RANGE, PARAM_SIGMA_MAX_PX, "exceeds the limit");
    gate = d_mul(TWO_NEG, d_log(v->f[PARAM_P_THRESHOLD]));
    g = covariance_gain(v, gate);
    if (!d_le(g, LIMIT_COV_GAIN_MAX))
        return refuse(w, NACK_OUT_OF_RANGE, PARAM_ALPHA_COVARIANCE, "is too large for "
                      "alpha_position and p_threshold: eq. (4) would weigh one event's "
                      "bias-corrected sample more than once");
    if (d_lt(D_ZERO, v->f[PARAM_MOTION_TAU_US]) && d_lt(v->f[PARAM_MOTION_TAU_US], D_ONE))
        return refuse(w, NACK_OUT_OF_RANGE, PARAM_MOTION_TAU_US, "must be 0 (off) or at "
                      "least 1 us in the fixed kernel's motion model (event times are whole us)");
    if (d_lt(D_ZERO, v->f[PARAM_MOTION_TAU_US])
        && d_lt(v->f[PARAM_ALPHA_POSITION], Q_MOTION_ALPHA_MIN))
        return refuse(w, NACK_OUT_OF_RANGE, PARAM_ALPHA_POSITION, "is below the fixed "
                      "kernel's Kalman filter's bound with the motion model on");
    if (d_lt(0x403f000000000000ull, gate))                         /* q(gate, ..., 0, 31) */
        return refuse(w, NACK_OUT_OF_RANGE, PARAM_P_THRESHOLD, "gives a gate beyond the "
                      "fixed kernel's range");
    if (d_lt(v->f[PARAM_ENERGY_SCALE], d_from_int(nc > 1 ? nc : 1))
        && d_lt(0x4060000000000000ull, v->f[PARAM_ENERGY_SCALE]))    /* q.mantissa: <= 128 */
        return refuse(w, NACK_OUT_OF_RANGE, PARAM_ENERGY_SCALE, "beyond the fixed kernel's range");
    return 0;
}

