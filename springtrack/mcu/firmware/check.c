/* check.h: springtrack/limits.py's check_model and check_params on the kernel's words
 * (layouts: springtrack/fixed/q.py model_words / params_words, fixed_step.h). */
#include "check.h"
#include "fixed_step.h"
#include "wire_codes.h"

#define POS_FRAC 32
#define COV_FRAC 40
#define MASS_FRAC 24
#define GAIN_ONE (1u << 30)          /* stiffness Q2.30: at most 1 (STIFFNESS_MAX) */
#define LOAD_MAX (1u << 29)          /* SPRING_LOAD_MAX 1/2 in Q.30 */
#define VAR_MAX ((int64_t)1 << 60)   /* MODEL_SIGMA_MAX_PX^2 = 2^20 px^2 in Q.40 */
#define POS_LIMIT_PX 8192

static int64_t w64(const int32_t *w) { return (int64_t)((uint64_t)(uint32_t)w[0] | (uint64_t)(uint32_t)w[1] << 32); }

/* a * b as 128 bits (hi, lo) for a, b >= 0 */
static void mul64(uint64_t a, uint64_t b, uint64_t *hi, uint64_t *lo)
{
    uint64_t al = (uint32_t)a, ah = a >> 32, bl = (uint32_t)b, bh = b >> 32;
    uint64_t ll = al * bl, lh = al * bh, hl = ah * bl, hh = ah * bh;
    uint64_t mid = (ll >> 32) + (uint32_t)lh + (uint32_t)hl;
    *lo = (mid << 32) | (uint32_t)ll;
    *hi = hh + (lh >> 32) + (hl >> 32) + (mid >> 32);
}

static int fail(buf_t *why, int code, const char *what, int32_t i, const char *rest)
{
    b_str(why, what);
    if (i >= 0) {
        b_u8(why, '[');
        b_int(why, i);
        b_u8(why, ']');
    }
    b_str(why, rest);
    return code;
}

static int32_t lim_of(int32_t v) { return v < POS_LIMIT_PX - 1 ? v : POS_LIMIT_PX - 1; }

int check_model(const int32_t *w, uint32_t nw, uint32_t width, uint32_t height, buf_t *why)
{
    int32_t n, nc, i, k;
    uint64_t load[FX_MAX_TRACKERS];
    if (nw < FX_MODEL_HEAD)
        return fail(why, NACK_INVALID_MODEL, "model words", -1, ": shorter than their head");
    n = w[0];
    nc = w[1];
    if (n < 1 || n > FX_MAX_TRACKERS || nc < 0 || nc > FX_MAX_CONNECTIONS) {
        b_int(why, n);
        b_str(why, " trackers / ");
        b_int(why, nc);
        b_str(why, " connections: this firmware holds 1..");
        b_int(why, FX_MAX_TRACKERS);
        b_str(why, " / 0..");
        b_int(why, FX_MAX_CONNECTIONS);
        b_str(why, " (springtrack mcu build --model sizes it)");
        return NACK_INVALID_MODEL;
    }
    if (nw != (uint32_t)(FX_MODEL_HEAD + n * FX_MODEL_TRACKER + nc * FX_MODEL_CONNECTION))
        return fail(why, NACK_INVALID_MODEL, "model words", -1, ": count does not match the "
                    "trackers and connections");
    if ((uint32_t)w[2] != width || (uint32_t)w[3] != height) {
        b_str(why, "the model's sensor is ");
        b_int(why, w[2]);
        b_u8(why, 'x');
        b_int(why, w[3]);
        b_str(why, " px, the camera's ");
        b_int(why, width);
        b_u8(why, 'x');
        b_int(why, height);
        b_str(why, " px");
        return NACK_SENSOR_MISMATCH;
    }
    /* limits.position_box: one sensor size beyond each border, within +-(8192 - 1) */
    if (w[4] != -lim_of((int32_t)width) || w[5] != lim_of(2 * (int32_t)width)
        || w[6] != -lim_of((int32_t)height) || w[7] != lim_of(2 * (int32_t)height))
        return fail(why, NACK_INVALID_MODEL, "model words", -1, ": the position box is not "
                    "the sensor's (springtrack.limits.position_box)");
    for (i = 0; i < n; i++) {
        const int32_t *t = w + FX_MODEL_HEAD + i * FX_MODEL_TRACKER;
        int64_t x = w64(t), y = w64(t + 2), sxx = w64(t + 4), sxy = w64(t + 6), syy = w64(t + 8);
        uint64_t ah, al, bh, bl, axy = (uint64_t)(sxy < 0 ? -sxy : sxy);
        if (x < (int64_t)w[4] << POS_FRAC || x >= (int64_t)w[5] << POS_FRAC
            || y < (int64_t)w[6] << POS_FRAC || y >= (int64_t)w[7] << POS_FRAC)
            return fail(why, NACK_INVALID_MODEL, "trackers", i, ": position outside the box "
                        "one sensor size around the sensor");
        if (sxx <= 0 || syy <= 0 || sxx > VAR_MAX || syy > VAR_MAX)
            return fail(why, NACK_INVALID_MODEL, "trackers", i, ": variance outside (0, "
                        "1048576] px^2 (sigma 1024 px)");
        mul64((uint64_t)sxx, (uint64_t)syy, &ah, &al);
        mul64(axy, axy, &bh, &bl);
        if (ah < bh || (ah == bh && al <= bl))
            return fail(why, NACK_INVALID_MODEL, "trackers", i, ": sigma is not positive "
                        "definite");
        /* mass in [2^-6, 2^14]: 1/mass Q.24 in [2^10, 2^30]; weight Q.24 in [1, 2^24] */
        if ((uint32_t)t[11] < (1u << (MASS_FRAC - 14)) || (uint32_t)t[11] > (1u << (MASS_FRAC + 6))
            || t[10] < 1 || t[10] > (1 << MASS_FRAC))
            return fail(why, NACK_INVALID_MODEL, "trackers", i, ": mass outside [0.015625, "
                        "16384]");
        load[i] = 0;
    }
    for (k = 0; k < nc; k++) {
        const int32_t *c = w + FX_MODEL_HEAD + n * FX_MODEL_TRACKER + k * FX_MODEL_CONNECTION;
        uint64_t a;
        if (c[0] < 0 || c[0] >= n || c[1] < 0 || c[1] >= n || c[0] == c[1])
            return fail(why, NACK_INVALID_MODEL, "connections", k, ": its trackers are not two "
                        "of the model's");
        if (c[2] < 0 || c[2] > 7)
            return fail(why, NACK_INVALID_MODEL, "connections", k, ": unknown spring kinds");
        if ((uint32_t)c[3] > GAIN_ONE)
            return fail(why, NACK_INVALID_MODEL, "connections", k, ": stiffness outside [0, 1]");
        /* limits.spring_kappa: 1 for Euclidean and/or torsional, plus 1 for Cartesian */
        a = (uint64_t)(uint32_t)c[3] * (uint64_t)(((c[2] & 3) != 0) + ((c[2] & 4) != 0));
        load[c[0]] += a;
        load[c[1]] += a;
    }
    for (i = 0; i < n; i++) {
        /* limits.spring_loads: (1 / m_i) sum kappa_k a_k <= 1/2, Q.30 x Q.24 >> 24 */
        uint32_t invm = (uint32_t)w[FX_MODEL_HEAD + i * FX_MODEL_TRACKER + 11];
        uint64_t hi, lo;
        mul64(load[i], invm, &hi, &lo);
        if (hi || (lo >> MASS_FRAC) > LOAD_MAX)
            return fail(why, NACK_INVALID_MODEL, "trackers", i, ": spring load exceeds 0.5 "
                        "(docs/algorithm.md, Limits): lower the stiffnesses or raise the mass");
    }
    return 0;
}

int check_params(const int32_t *w, uint32_t nw, buf_t *why)
{
    /* fx_set_params' own checks, so that it cannot refuse words accepted here */
    if (nw != FX_PARAMS_WORDS)
        return fail(why, NACK_OUT_OF_RANGE, "parameter words", -1, ": wrong count");
    if (w[3] < 31 || w[3] > 62 || w[12] < 1 || w[12] > 62 || w[18] < 1 || w[19] < 0
        || w[19] > 2 || (uint32_t)w[22] > 1 || (uint32_t)w[23] > 1)
        return fail(why, NACK_OUT_OF_RANGE, "parameter words", -1, ": a value outside the "
                    "kernel's range (springtrack.fixed.q.params_q)");
    /* alpha_position, energy_gain: Q2.30 gains <= 1; the activity threshold positive */
    if ((uint32_t)w[0] > GAIN_ONE || (uint32_t)w[4] > GAIN_ONE || w64(w + 9) < 0
        || w64(w + 14) <= 0 || w64(w + 16) <= w64(w + 14)
        || w64(w + 16) > ((int64_t)64 * 64) << COV_FRAC)
        return fail(why, NACK_OUT_OF_RANGE, "parameter words", -1, ": a gain above 1, or "
                    "sigma_min_px / sigma_max_px outside 0 < min < max <= 64 px");
    return 0;
}
