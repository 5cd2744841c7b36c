/* Fast float64 elementary functions for the tracker kernel (springtrack/kernel/kernel.pyx).
 *
 * The kernel must equal the float64 reference (springtrack/reference.py, which calls
 * libm through Python's math module) to 1e-9 px, not bit for bit, so these replace the
 * libm calls on the hot paths by branch-free code that is accurate to about one ulp and
 * that GCC vectorises over the connections of a spring update (csrc/springs.h):
 *
 *   st_atan2(y, x)          eq. (14) angle of a connection; |error| <= ~4.5e-16 rad
 *   st_sincos_small(e,...)  eq. (16) rotation sin(eps), cos(eps) - 1 for |eps| <= pi/4;
 *                           |error| <= ~2e-17 relative (the batch falls back to libm above)
 *   st_exp(x)               eqs. (2), (6) kernel value and activity decay; ~1 ulp
 *   st_exp_batch            the same over an array, vectorised (the activity log)
 *
 * Polynomials: Chebyshev fits (mpmath.chebyfit, 60 digits), then rounded to double; the
 * worst error of the rounded polynomial was checked in 60-digit arithmetic on 2001 points
 * and is quoted beside each one.  tests/test_springtrack/kernel/test_fastmath.py measures the functions against
 * libm on millions of arguments, edge cases included.
 *
 * Nothing here relies on -ffast-math or FMA contraction: setup.py builds with
 * -ffp-contract=off, so every clone (default / AVX2 / AVX-512) rounds identically.
 */
#ifndef SPRINGTRACK_FASTMATH_H
#define SPRINGTRACK_FASTMATH_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#define ST_PI_HI 3.141592653589793
#define ST_PI_LO 1.2246467991473532e-16
#define ST_PI2_HI 1.5707963267948966
#define ST_PI2_LO 6.123233995736766e-17
#define ST_PI4_HI 0.7853981633974483
#define ST_PI4_LO 3.061616997868383e-17
#define ST_TAN_PI_8 0.41421356237309503
#define ST_SINCOS_MAX 0.7853981633974483      /* pi/4: domain of st_sincos_small */

/* Batch functions: one build runs on any x86-64 and the loader picks the widest vector
 * unit present.  Each module that includes these headers uses some of them: "unused"
 * keeps the others from warning (an unused static function is still left out). */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(ST_NO_CLONES)
#define ST_CLONES __attribute__((target_clones("default", "avx2", "avx512f"), unused))
#elif defined(__GNUC__)
#define ST_CLONES __attribute__((unused))
#else
#define ST_CLONES
#endif

/* c ? a : b for c in {0, 1}, as a bit blend.  A plain ?: lets GCC move the arithmetic
 * that produced a or b into a branch, and then (with the default -ftrapping-math) it
 * refuses to vectorise the loop; a blend keeps every operation unconditional. */
static inline double st_sel(int64_t c, double a, double b)
{
    uint64_t m = (uint64_t)0 - (uint64_t)c, ua, ub;
    memcpy(&ua, &a, 8);
    memcpy(&ub, &b, 8);
    ua = (ua & m) | (ub & ~m);
    memcpy(&a, &ua, 8);
    return a;
}

/* atan(t) for |t| <= tan(pi/8): t + t^3 P(t^2); P fitted to (atan t - t)/t^3,
 * error of the rounded P times t^2 <= 6.8e-18 (relative to atan t). */
static inline double st_atan_reduced(double t)
{
    /* Estrin's scheme: the same polynomial as Horner's rule in a dependency chain of 7
     * operations instead of 22, so that the batch's few iterations overlap (with Horner's
     * chain the spring update's atan2 batch is bound by its latency, not its operations) */
    double s = t * t, s2 = s * s, s4 = s2 * s2, s8 = s4 * s4, ts = t * s;
    double q0 = -0.3333333333333333 + 0.1999999999999552 * s;
    double q1 = -0.14285714284666542 + 0.11111111015256361 * s;
    double q2 = -0.09090904578123903 + 0.07692183190826087 * s;
    double q3 = -0.06664511447381948 + 0.0585814891280221 * s;
    double q4 = -0.0508544973794026 + 0.03923165829558719 * s;
    double r0 = q0 + q1 * s2;
    double r1 = q2 + q3 * s2;
    double r2 = q4 + -0.01917688711906226 * s2;
    double p = (r0 + r1 * s4) + r2 * s8;
    return t + ts * p;
}

/* atan2(y, x) in [-pi, pi] like libm for finite arguments, branch-free.
 * Reduction: z = min(|x|,|y|) / max(|x|,|y|) in [0, 1]; above tan(pi/8) use
 * atan z = pi/4 + atan((z - 1)/(z + 1)) (one division either way).  The octant then
 * gives the result as c + sigma atan(t) with c a multiple k pi/4 (k = 0..4, as two
 * doubles hi + lo) and sigma = +-1: pi/4 if big, k -> 2 - k if |y| > |x| (swap),
 * k -> 4 - k if x < 0, sigma flipping with each of the last two.  c and sigma come from
 * the comparisons alone, beside the division and the polynomial, so that only two
 * additions follow them (the batch is bound by the length of this chain: few
 * iterations, each too long for the CPU to overlap many).  atan2(+-0, +0) = +-0 and
 * atan2(+-0, x < 0) = +-pi as in libm (the kernel never produces -0 differences). */
#define ST_3PI4_HI 2.356194490192345
#define ST_3PI4_LO 9.184850993605148e-17
static inline double st_atan2(double y, double x)
{
    /* every candidate is computed, then blended (st_sel): no branch in the batch loop */
    double ax = fabs(x), ay = fabs(y);
    int64_t swap = ay > ax;
    double lo = ay < ax ? ay : ax;                    /* min and max (vminpd, vmaxpd) */
    double hi = ay > ax ? ay : ax;
    int64_t big = lo > ST_TAN_PI_8 * hi;
    int64_t neg = copysign(1.0, x) < 0.0;             /* x < 0 or x = -0 */
    double num = st_sel(big, lo - hi, lo);
    double den = st_sel(big, lo + hi, st_sel(hi > 0.0, hi, 1.0));   /* x = y = 0: t = 0 */
    /* c = k pi/4: big ? (neg ? 3 : 1) : (swap ? 2 : (neg ? 4 : 0)) */
    double c_hi = st_sel(big, st_sel(neg, ST_3PI4_HI, ST_PI4_HI),
                         st_sel(swap, ST_PI2_HI, st_sel(neg, ST_PI_HI, 0.0)));
    double c_lo = st_sel(big, st_sel(neg, ST_3PI4_LO, ST_PI4_LO),
                         st_sel(swap, ST_PI2_LO, st_sel(neg, ST_PI_LO, 0.0)));
    uint64_t flip = (uint64_t)(swap ^ neg) << 63, ua;
    double a = st_atan_reduced(num / den);
    memcpy(&ua, &a, 8);
    ua ^= flip;                                       /* sigma atan(t) */
    memcpy(&a, &ua, 8);
    return copysign((c_lo + a) + c_hi, y);
}

/* sin(e) and cos(e) - 1 for |e| <= pi/4 (eq. 16 needs cos(eps) - 1: computed directly,
 * without the cancellation of cos(eps) - 1.0).  sin: e + e^3 S(e^2), error <= 1.9e-17
 * relative; cos - 1: e^2 C(e^2), error <= 1.4e-18 relative. */
static inline void st_sincos_small(double e, double *sn, double *cm1)
{
    /* Estrin's scheme, as st_atan_reduced */
    double s = e * e, s2 = s * s, s4 = s2 * s2;
    double a0 = -0.16666666666666666 + 0.008333333333330948 * s;
    double a1 = -0.00019841269836758574 + 2.755731610255244e-06 * s;
    double a2 = -2.5051131845003624e-08 + 1.5918129294866608e-10 * s;
    double ps = (a0 + a1 * s2) + a2 * s4;
    double b0 = -0.5 + 0.04166666666666664 * s;
    double b1 = -0.0013888888888880775 + 2.480158729369346e-05 * s;
    double b2 = -2.7557315566341895e-07 + 2.0875886738047052e-09 * s;
    double pc = (b0 + b1 * s2) + (b2 + -1.1367998654022494e-11 * s2) * s4;
    *sn = e + e * (s * ps);
    *cm1 = s * pc;
}

/* out[k] = atan2(y[k], x[k]) for k < n. */
ST_CLONES static void st_atan2_batch(const double *restrict y, const double *restrict x,
                                     double *restrict out, int n)
{
    for (int k = 0; k < n; k++)
        out[k] = st_atan2(y[k], x[k]);
}

/* sn[k] = sin(e[k]), cm1[k] = cos(e[k]) - 1 for k < n; libm where |e| > pi/4 (rare:
 * stiffness * |angle deviation| above pi/4). */
ST_CLONES static void st_sincos_batch(const double *restrict e, double *restrict sn,
                                      double *restrict cm1, int n)
{
    int wide = 0;
    for (int k = 0; k < n; k++) {
        st_sincos_small(e[k], &sn[k], &cm1[k]);
        wide |= !(fabs(e[k]) <= ST_SINCOS_MAX);
    }
    if (wide) {
        for (int k = 0; k < n; k++) {
            if (!(fabs(e[k]) <= ST_SINCOS_MAX)) {
                sn[k] = sin(e[k]);
                cm1[k] = cos(e[k]) - 1.0;
            }
        }
    }
}

/* exp(x), about 1 ulp, for the kernel's arguments x <= 0 (any double works).
 * x = (k + j/32) ln 2 + r, |r| <= ln2/64; exp(x) = 2^(k) 2^(j/32) (1 + r + ... r^6/720)
 * (truncation r^7/7! < 3.5e-18).  The table holds 2^(j/32) correctly rounded; ln2/32 is
 * split so that kd * ST_EXP_LN2_HI is exact.  Outside |x| < 700 (result near the
 * under/overflow range, or NaN) libm takes over. */
static const double st_exp2_table[32] = {
    1.0, 1.0218971486541166, 1.0442737824274138, 1.0671404006768237,
    1.0905077326652577, 1.1143867425958924, 1.1387886347566916, 1.1637248587775775,
    1.189207115002721, 1.215247359980469, 1.241857812073484, 1.2690509571917332,
    1.2968395546510096, 1.3252366431597413, 1.3542555469368927, 1.383909881963832,
    1.4142135623730951, 1.4451808069770467, 1.4768261459394993, 1.5091644275934228,
    1.5422108254079407, 1.5759808451078865, 1.6104903319492543, 1.645755478153965,
    1.681792830507429, 1.718619298122478, 1.7562521603732995, 1.7947090750031072,
    1.8340080864093424, 1.8741676341103, 1.9152065613971474, 1.9571441241754002,
};
#define ST_EXP_INV_LN2_32 46.16624130844683      /* 32 / ln 2 */
#define ST_EXP_LN2_HI 0.02166084938653512         /* ln2/32, 21 trailing zero bits */
#define ST_EXP_LN2_LO 5.9631716539705866e-12
#define ST_EXP_SHIFT 6755399441055744.0           /* 1.5 * 2^52: round to integer */

/* st_exp for |x| < 700 (no range check) */
static inline double st_exp_core(double x)
{
    double kd = x * ST_EXP_INV_LN2_32 + ST_EXP_SHIFT;
    uint64_t kb;
    memcpy(&kb, &kd, 8);
    kd -= ST_EXP_SHIFT;                           /* nearest integer to 32 x / ln 2 */
    int64_t ki = (int64_t)(int32_t)(uint32_t)kb;  /* low bits of the shifted value */
    double r = (x - kd * ST_EXP_LN2_HI) - kd * ST_EXP_LN2_LO;
    double scale = st_exp2_table[ki & 31];
    uint64_t sb;
    memcpy(&sb, &scale, 8);
    sb += (uint64_t)(ki >> 5) << 52;              /* times 2^floor(ki / 32) */
    memcpy(&scale, &sb, 8);
    double r2 = r * r;
    double p = r + r2 * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0)))));
    return scale + scale * p;
}

static inline double st_exp(double x)
{
    if (!(fabs(x) < 700.0))
        return exp(x);
    return st_exp_core(x);
}

/* out[k] = st_exp(x[k]) for k < n, the same values, vectorised (the table read as
 * scalar loads; libm where |x| >= 700, rare) */
ST_CLONES static void st_exp_batch(const double *restrict x, double *restrict out, int n)
{
    int64_t wide = 0;
    for (int k = 0; k < n; k++) {
        out[k] = st_exp_core(x[k]);
        wide |= !(fabs(x[k]) < 700.0);
    }
    if (wide)
        for (int k = 0; k < n; k++)
            if (!(fabs(x[k]) < 700.0))
                out[k] = exp(x[k]);
}

#endif /* SPRINGTRACK_FASTMATH_H */
