/* A hand-written C tracker: the yardstick of springtrack's float64 kernel in benchmarks/.
 *
 * Valeiras et al. 2015, Algorithm 1, written from springtrack/reference.py the way a C
 * programmer who wants it fast would write it, independently of springtrack/kernel/
 * (its own spatial index, its own exp, atan2 and sincos):
 *   per event   eq. (2): the sensitive tracker with the smallest Mahalanobis d^2 inside
 *               the gate takes it (ties: lowest index); the d^2 that decides the gate is
 *               the one eq. (2)'s probability exp(-d^2/2) is computed from (one pass);
 *               eqs. (3)-(6): its mean, covariance and activity move;
 *   every `period` valid events   eqs. (10)-(20): the springs, then eqs. (13), (21)-(22):
 *               the energy criteria; with pull_frame / cartesian_frame = similarity, the
 *               similarity that maps the rest shape onto the calm trackers, refitted
 *               weighted by how well each agrees with it (fit_frame),
 *               sets eq. (22)'s targets and the next update's Cartesian rest offsets.
 * State as structure of arrays.  The spatial index: the sensor cut into 8 x 8 px cells,
 * each cell a 64-bit mask of the trackers whose gate box (grown by a slack) covers it;
 * a tracker is re-indexed only when its gate box leaves the box it was indexed with, so
 * the candidates of an event are one load and an AND with the sensitive mask.
 * The two peers differ only in scan() and springs(): plain.c writes them as plain loops
 * (the compiler vectorises what it can at -O3 -march=native), simd.c with AVX-512 or
 * AVX2 intrinsics (chosen at build time by the -march).  Each .c file defines them, then
 * includes this file's second half (PEER_LOOP) for the event loop.
 *
 * Input: the packed event records of expelliarmus / tonic / numpy files (t int64, x and
 * y int16, p uint8: 13 bytes).  Built by benchmarks/_ctrackers.py and called through ctypes.
 */
#ifndef PEER_H
#define PEER_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define PEER_MAX_T 64
#define PEER_MAX_C 128
#define PEER_EUCLIDEAN 1
#define PEER_TORSIONAL 2
#define PEER_CARTESIAN 4
#define PEER_RHO_MAX 0.99
/* the similarity frame's bounds (springtrack/reference.py FRAME_*) */
#define PEER_FRAME_SCALE_MIN 0.25
#define PEER_FRAME_SCALE_MAX 4.0
#define PEER_FRAME_MIN_SPREAD (1.0 / 1048576.0)
#define PEER_FRAME_REFITS 2
#define PEER_FRAME_AGREE_PX2 (1.0 / 16.0)
#define PEER_FRAME_RAMP 0.5
/* the index: 2^3 = 8 px cells; a gate box grown by 1/4 of its half-size plus 3 px */
#define PEER_CELL_SHIFT 3
#define PEER_SLACK_REL 0.25
#define PEER_SLACK_PX 3.0

typedef struct __attribute__((packed)) {
    int64_t t;
    int16_t x, y;
    uint8_t p;
} PeerEvent;

/* Parameters as peer_new() takes them (doubles, in this order). */
enum { P_A1, P_A2, P_GATE, P_TAU, P_COV_GAIN, P_SMIN, P_SMAX, P_ESCALE, P_EGAIN, P_PERIOD,
       P_EKIND, P_PULL_SIM, P_CAR_SIM, N_PARAMS };

typedef struct {
    int n, nc, width, height, period, ekind, need_torsion, since, pull_sim, car_sim;
    int cw, ch;                             /* the index: cells across, down */
    double a1, keep, cov_gain, gate, gate_slack, tau, inv_tau, smin2, smax2, escale, egain, msum;
    uint64_t sens;                          /* bit i: tracker i sensitive */
    uint64_t *cells;                        /* cw * ch masks */
    /* trackers; arrays padded to a multiple of 8 for the vector peer */
    _Alignas(64) double mx[PEER_MAX_T];
    _Alignas(64) double my[PEER_MAX_T];
    _Alignas(64) double sxx[PEER_MAX_T];
    _Alignas(64) double sxy[PEER_MAX_T];
    _Alignas(64) double syy[PEER_MAX_T];
    _Alignas(64) double ia[PEER_MAX_T];     /* inverse covariance [ia ib; ib ic] */
    _Alignas(64) double ib2[PEER_MAX_T];    /* 2 ib, as eq. (2)'s cross term uses it */
    _Alignas(64) double ic[PEER_MAX_T];
    _Alignas(64) double off[PEER_MAX_T];    /* 0 if sensitive, +inf if not (or padding) */
    _Alignas(64) double act[PEER_MAX_T];
    _Alignas(64) double mass[PEER_MAX_T];
    _Alignas(64) double inv_mass[PEER_MAX_T];
    _Alignas(64) double gdx0[PEER_MAX_T];
    _Alignas(64) double gdy0[PEER_MAX_T];
    /* the box each tracker is indexed with: its gate box may move inside [lo, hi] */
    double lox[PEER_MAX_T], hix[PEER_MAX_T], loy[PEER_MAX_T], hiy[PEER_MAX_T];
    int cx0[PEER_MAX_T], cx1[PEER_MAX_T], cy0[PEER_MAX_T], cy1[PEER_MAX_T];
    int64_t tlast[PEER_MAX_T];
    int degree[PEER_MAX_T];
    /* connections */
    _Alignas(64) int ca[PEER_MAX_C];
    _Alignas(64) int cb[PEER_MAX_C];
    int kinds[PEER_MAX_C];
    _Alignas(64) double stiff[PEER_MAX_C];
    _Alignas(64) double l0[PEER_MAX_C];
    _Alignas(64) double th0[PEER_MAX_C];
    _Alignas(64) double dx0[PEER_MAX_C];
    _Alignas(64) double dy0[PEER_MAX_C];
    _Alignas(64) double rdx0[PEER_MAX_C];   /* eq. (18)'s rest offset: s R d0 (or d0) */
    _Alignas(64) double rdy0[PEER_MAX_C];
    _Alignas(64) double c0[PEER_MAX_C];     /* cos th0, sin th0 */
    _Alignas(64) double s0[PEER_MAX_C];
    _Alignas(64) double a_euc[PEER_MAX_C];  /* stiffness where the connection has the kind */
    _Alignas(64) double a_tor[PEER_MAX_C];
    _Alignas(64) double a_car[PEER_MAX_C];
    _Alignas(64) double energy[3][PEER_MAX_C];
    double mean_energy;
    double fc, fs, fgx, fgy;                /* the similarity frame: s R = [[fc, -fs], [fs, fc]] */
    int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_springs, n_reindex;
} Peer;

/* ---- elementary functions, branch-free so loops over them vectorise ---- */

/* min and max as compares (libm's fmin / fmax are calls, which keep loops scalar); a NaN
 * in v stays NaN as in the reference's min(max(v, lo), hi) */
static inline double pmax(double v, double lo) { return lo > v ? lo : v; }
static inline double pmin(double v, double hi) { return hi < v ? hi : v; }

/* 2^(j/64), j = 0..63, filled by peer_new */
static double peer_exp2_table[64];

/* exp(x) for x <= 0 (eq. 2's -d^2/2 and eq. 6's -dt/tau); 0 below -708.  x = (64 m + j)
 * ln2/64 + r, |r| <= ln2/128: exp x = 2^m 2^(j/64) (1 + r + ... + r^5/5!), ~1 ulp. */
static inline double peer_exp(double x)
{
    const double shift = 0x1.8p52, inv = 64.0 / M_LN2;
    const double l_hi = 0x1.62e42fefa0000p-7, l_lo = 0x1.cf79abc9e3b3ap-46;   /* ln2/64 = l_hi + l_lo */
    int under = !(x > -708.0);
    x = under ? -708.0 : x;
    double kd = x * inv + shift;
    int64_t k;
    memcpy(&k, &kd, 8);
    kd = kd - shift;
    double r = (x - kd * l_hi) - kd * l_lo, r2 = r * r;
    double p = (1.0 + r) + r2 * ((0.5 + r * (1.0 / 6.0)) + r2 * ((1.0 / 24.0) + r * (1.0 / 120.0)));
    /* kd's low mantissa bits hold the integer k = 64 m + j (two's complement) */
    uint64_t bits = (uint64_t)((int64_t)((int32_t)k >> 6) + 1023) << 52;
    double scale;
    memcpy(&scale, &bits, 8);
    double v = peer_exp2_table[k & 63] * p * scale;
    return under ? 0.0 : v;
}

/* atan2(y, x) in [-pi, pi], atan2(0, 0) = 0: Cephes' atan after one division (the octant
 * reduction t = min / max, above 0.66 atan t = pi/4 + atan((t - 1) / (t + 1))), ~1 ulp. */
static inline double peer_atan2(double y, double x)
{
    const double MOREBITS = 6.123233995736765886130e-17;
    double ax = fabs(x), ay = fabs(y);
    double num = ax < ay ? ax : ay, den = ax < ay ? ay : ax;
    int big = num > 0.66 * den;
    double tn = big ? num - den : num, td = big ? num + den : den;
    td = td == 0.0 ? 1.0 : td;
    double t = tn / td, z = t * t;
    double p = -8.750608600031904122785e-1;
    p = p * z + -1.615753718733365076637e1;
    p = p * z + -7.500855792314704667340e1;
    p = p * z + -1.228866684490136173410e2;
    p = p * z + -6.485021904942025371773e1;
    double q = z + 2.485846490142306297962e1;
    q = q * z + 1.650270098316988542046e2;
    q = q * z + 4.328810604912902668951e2;
    q = q * z + 4.853903996359136964868e2;
    q = q * z + 1.945506571482613964425e2;
    double r = t * (z * p / q) + t;
    r = (big ? M_PI_4 : 0.0) + (r + (big ? 0.5 * MOREBITS : 0.0));
    r = ay > ax ? (M_PI_2 - r) + MOREBITS : r;
    r = x < 0.0 ? (M_PI - r) + 2.0 * MOREBITS : r;
    return copysign(r, y);
}

/* sin x and cos x: Cephes' reduction by pi/4 in three parts, degree-6 polynomials. */
static inline void peer_sincos(double x, double *sn, double *cs)
{
    double ax = fabs(x);
    int j = ((int)(ax * 1.27323954473516268615) + 1) & ~1;
    double y = j;
    double z = ((ax - y * 7.85398125648498535156e-1) - y * 3.77489470793079817668e-8)
               - y * 2.69515142907905952645e-15;
    double zz = z * z;
    double ps = 1.58962301576546568060e-10;
    ps = ps * zz + -2.50507477628578072866e-8;
    ps = ps * zz + 2.75573136213857245213e-6;
    ps = ps * zz + -1.98412698295895385996e-4;
    ps = ps * zz + 8.33333333332211858878e-3;
    ps = ps * zz + -1.66666666666666307295e-1;
    ps = z + z * zz * ps;
    double pc = -1.13585365213876817300e-11;
    pc = pc * zz + 2.08757008419747316778e-9;
    pc = pc * zz + -2.75573141792967388112e-7;
    pc = pc * zz + 2.48015872888517045348e-5;
    pc = pc * zz + -1.38888888888730564116e-3;
    pc = pc * zz + 4.16666666666665929218e-2;
    pc = (1.0 - 0.5 * zz) + zz * zz * pc;
    /* octant j (even): j & 2 swaps the polynomials; sin flips for j & 4, cos for j in {2, 4} */
    int swap = j & 2;
    double s = swap ? pc : ps, c = swap ? ps : pc;
    s = ((j & 4) != 0) != (x < 0.0) ? -s : s;
    c = (((j & 4) != 0) != ((j & 2) != 0)) ? -c : c;
    *sn = s;
    *cs = c;
}

static inline double wrap_angle(double a)
{
    a = a >= M_PI ? a - 2.0 * M_PI : a;
    return a < -M_PI ? a + 2.0 * M_PI : a;
}

/* ---- the spatial index ---- */

static inline void set_cells(Peer *s, int i, int on)
{
    uint64_t bit = (uint64_t)1 << i;
    for (int cy = s->cy0[i]; cy <= s->cy1[i]; cy++) {
        uint64_t *row = s->cells + (size_t)cy * s->cw;
        for (int cx = s->cx0[i]; cx <= s->cx1[i]; cx++)
            row[cx] = on ? row[cx] | bit : row[cx] & ~bit;
    }
}

/* one axis of tracker i's indexed box: the cells [c0, c1] (clipped to the sensor) covering
 * its gate box [m - h, m + h] grown by the slack, and [lo, hi], where the gate box may go
 * before an event pixel inside it can fall outside those cells (open at the sensor edges) */
static inline void index_axis(double m, double h, int ncell, int *c0, int *c1, double *lo,
                              double *hi)
{
    double g = PEER_SLACK_REL * h + PEER_SLACK_PX;
    double a = pmin(pmax(m - h - g, -1e6), 1e6), b = pmin(pmax(m + h + g, -1e6), 1e6);
    a = a == a ? a : 0.0;                   /* NaN: anywhere, re-indexed at once */
    b = b == b ? b : 0.0;
    int r0 = (int)floor(a) >> PEER_CELL_SHIFT, r1 = (int)floor(b) >> PEER_CELL_SHIFT;
    *lo = r0 <= 0 ? -INFINITY : (double)(r0 << PEER_CELL_SHIFT);
    *hi = r1 >= ncell - 1 ? INFINITY : (double)((r1 + 1) << PEER_CELL_SHIFT);
    *c0 = r0 < 0 ? 0 : r0;
    *c1 = r1 > ncell - 1 ? ncell - 1 : r1;
}

/* The gate's box: d^2 < gate holds only where |dx| < sqrt(gate sxx), |dy| < sqrt(gate syy)
 * (a hair wider for rounding). */
static inline double gate_half(const Peer *s, double v) { return sqrt(s->gate_slack * v) + 1e-6; }

static void reindex(Peer *s, int i)
{
    set_cells(s, i, 0);
    index_axis(s->mx[i], gate_half(s, s->sxx[i]), s->cw, &s->cx0[i], &s->cx1[i], &s->lox[i],
               &s->hix[i]);
    index_axis(s->my[i], gate_half(s, s->syy[i]), s->ch, &s->cy0[i], &s->cy1[i], &s->loy[i],
               &s->hiy[i]);
    set_cells(s, i, 1);
    s->n_reindex++;
}

/* re-index tracker i if its gate box left its indexed box (NaN: re-index too): with
 * d the distance from the mean to a side, d >= 0 and d^2 >= gate' sigma^2 (gate' a hair
 * above the gate), no square root */
static inline void check_index(Peer *s, int i)
{
    double gx = s->gate_slack * s->sxx[i], gy = s->gate_slack * s->syy[i];
    double l = s->mx[i] - s->lox[i], r = s->hix[i] - s->mx[i];
    double d = s->my[i] - s->loy[i], u = s->hiy[i] - s->my[i];
    int inside = (l >= 0.0) & (l * l >= gx) & (r >= 0.0) & (r * r >= gx)
                 & (d >= 0.0) & (d * d >= gy) & (u >= 0.0) & (u * u >= gy);
    if (__builtin_expect(!inside, 0))
        reindex(s, i);
}

/* ---- per tracker ---- */

/* Bound sigma_x, sigma_y to [sigma_min, sigma_max] and |rho| to RHO_MAX in place; Sigma^-1
 * = [ia ib; ib ic] into ia, ib2 = 2 ib (eq. 2's cross term), ic. */
static inline void clamp_and_invert(const Peer *s, double *sxx_, double *sxy_, double *syy_,
                                    double *ia, double *ib2, double *ic)
{
    double sxx = pmin(pmax(*sxx_, s->smin2), s->smax2);
    double syy = pmin(pmax(*syy_, s->smin2), s->smax2);
    double sxy = *sxy_;
    /* |rho| <= RHO_MAX: the square root only where the bound may bite */
    if (__builtin_expect(!(sxy * sxy < (PEER_RHO_MAX * PEER_RHO_MAX * 0.999999) * (sxx * syy)), 0)) {
        double lim = PEER_RHO_MAX * sqrt(sxx * syy);
        sxy = pmin(pmax(sxy, -lim), lim);
    }
    *sxx_ = sxx;
    *sxy_ = sxy;
    *syy_ = syy;
    double inv_det = 1.0 / (sxx * syy - sxy * sxy);
    *ia = syy * inv_det;
    *ib2 = 2.0 * (-sxy * inv_det);
    *ic = sxx * inv_det;
}

/* The similarity x -> G + s R (x - G0) that best maps the rest shape onto the means with
 * the weights w8 (0: not in the fit), in the weighted least-squares sense (reference.py
 * _fit_similarity): with rest offsets p and current offsets q about the weighted
 * centroids, a = sum m p.q, b = sum m p x q, D = sum m |p|^2, s R = [[a, -b], [b, a]] / D,
 * the scale held to its bounds. */
static void fit_similarity(Peer *s, const double *w8)
{
    int n = s->n;
    double w = 0.0, px = 0.0, py = 0.0, qx = 0.0, qy = 0.0;
    for (int i = 0; i < n; i++) {                                 /* weighted centroids */
        double m = w8[i];
        w += m;
        px += m * s->gdx0[i];
        py += m * s->gdy0[i];
        qx += m * s->mx[i];
        qy += m * s->my[i];
    }
    px = px / w;
    py = py / w;
    qx = qx / w;
    qy = qy / w;
    double a = 0.0, b = 0.0, d = 0.0, c, sn;
    for (int i = 0; i < n; i++) {
        double m = w8[i];
        double ux = s->gdx0[i] - px, uy = s->gdy0[i] - py;        /* rest offset p */
        double vx = s->mx[i] - qx, vy = s->my[i] - qy;            /* current offset q */
        a += m * (ux * vx + uy * vy);
        b += m * (ux * vy - uy * vx);
        d += m * (ux * ux + uy * uy);
    }
    if (d <= PEER_FRAME_MIN_SPREAD * w) {
        c = 1.0;
        sn = 0.0;
    } else {
        c = a / d;
        sn = b / d;
        double k2 = c * c + sn * sn;                              /* s^2 */
        if (k2 > PEER_FRAME_SCALE_MAX * PEER_FRAME_SCALE_MAX) {
            double f = PEER_FRAME_SCALE_MAX / sqrt(k2);
            c = c * f;
            sn = sn * f;
        } else if (k2 < PEER_FRAME_SCALE_MIN * PEER_FRAME_SCALE_MIN) {
            if (k2 > 0.0) {
                double f = PEER_FRAME_SCALE_MIN / sqrt(k2);
                c = c * f;
                sn = sn * f;
            } else {
                c = PEER_FRAME_SCALE_MIN;
                sn = 0.0;
            }
        }
    }
    s->fc = c;
    s->fs = sn;
    s->fgx = qx - (c * px - sn * py);                             /* G = qbar - s R pbar */
    s->fgy = qy - (sn * px + c * py);
}

/* reference.py fit_frame: the frame fitted to the trackers no over-threshold connection
 * touches (all if fewer than 2), then refitted up to PEER_FRAME_REFITS times with masses
 * m v, v = 1 up to T = max(s mean m v r^2, PEER_FRAME_AGREE_PX2) of the squared
 * residuals r^2, 0 from (1 + PEER_FRAME_RAMP) T, linear between; dis[i] = 1 - v_i (0
 * outside the fit), eq. (22)'s share for a tracker no connection pulls. */
static void fit_frame(Peer *s, uint64_t over, double *dis)
{
    int n = s->n;
    uint64_t all = n == 64 ? ~(uint64_t)0 : (((uint64_t)1 << n) - 1);
    uint64_t fit = all & ~over;
    if (__builtin_popcountll(fit) < 2)
        fit = all;
    _Alignas(64) double w8[PEER_MAX_T];
    double wt[PEER_MAX_T], v[PEER_MAX_T], r2[PEER_MAX_T];
    for (int i = 0; i < n; i++) {                                 /* the fit set's masses */
        wt[i] = 1.0;
        dis[i] = 0.0;
        w8[i] = (fit >> i) & 1 ? s->mass[i] : 0.0;
    }
    fit_similarity(s, w8);
    if (!(s->escale < s->nc))
        return;
    for (int r = 0; r < PEER_FRAME_REFITS; r++) {
        double w = 0.0, total = 0.0, thr;
        int changed = 0, pos = 0;
        for (int i = 0; i < n; i++) {
            if (!((fit >> i) & 1))
                continue;
            double ex = s->mx[i] - (s->fgx + (s->fc * s->gdx0[i] - s->fs * s->gdy0[i]));
            double ey = s->my[i] - (s->fgy + (s->fs * s->gdx0[i] + s->fc * s->gdy0[i]));
            r2[i] = ex * ex + ey * ey;
            w += s->mass[i] * wt[i];
            total += s->mass[i] * wt[i] * r2[i];
        }
        thr = s->escale * (total / w);                            /* eq. (21)'s test on r^2 */
        if (thr < PEER_FRAME_AGREE_PX2)
            thr = PEER_FRAME_AGREE_PX2;
        for (int i = 0; i < n; i++) {
            if (!((fit >> i) & 1))
                continue;
            v[i] = 1.0 - (r2[i] - thr) / (PEER_FRAME_RAMP * thr);
            v[i] = v[i] < 0.0 ? 0.0 : v[i] > 1.0 ? 1.0 : v[i];
            changed |= v[i] != wt[i];
            pos += v[i] > 0.0;
        }
        if (!changed || pos < 2)
            break;
        for (int i = 0; i < n; i++)
            if ((fit >> i) & 1) {
                wt[i] = v[i];
                w8[i] = s->mass[i] * v[i];
            }
        fit_similarity(s, w8);
    }
    for (int i = 0; i < n; i++)
        if ((fit >> i) & 1)
            dis[i] = 1.0 - wt[i];
}

/* eqs. (13), (21)-(22) on the energies of the last spring update; then the index follows
 * the moved trackers. */
static void energy_criteria(Peer *s)
{
    int n = s->n, nc = s->nc;
    if (nc == 0) {
        for (int i = 0; i < n; i++)
            check_index(s, i);
        return;
    }
    const double *e = s->energy[s->ekind];
    double total = 0.0, gx = 0.0, gy = 0.0;
    for (int k = 0; k < nc; k++)                                  /* eq. (13) */
        total += e[k];
    s->mean_energy = total / nc;
    double thr = s->escale * s->mean_energy;
    /* the trackers with any / all of their connections over the threshold */
    uint64_t over = 0, calm_end = 0;
    for (int k = 0; k < nc; k++) {
        uint64_t ends = ((uint64_t)1 << s->ca[k]) | ((uint64_t)1 << s->cb[k]);
        uint64_t hot = -(uint64_t)(e[k] > thr);
        over |= ends & hot;
        calm_end |= ends & ~hot;
    }
    double dis[PEER_MAX_T];
    uint64_t soft = 0;
    for (int i = 0; i < n; i++)
        dis[i] = 0.0;
    if (s->pull_sim || s->car_sim)
        fit_frame(s, over, dis);
    for (int i = 0; i < n; i++)                     /* pulled by the share they disagree */
        soft |= (uint64_t)(dis[i] > 0.0 && !((over >> i) & 1)) << i;
    if (s->car_sim)                                 /* the next update's eq. (18): s R d0 */
        for (int k = 0; k < nc; k++) {
            s->rdx0[k] = s->fc * s->dx0[k] - s->fs * s->dy0[k];
            s->rdy0[k] = s->fs * s->dx0[k] + s->fc * s->dy0[k];
        }
    if (!s->pull_sim) {                             /* G, the centre of mass */
        for (int i = 0; i < n; i++) {
            gx += s->mass[i] * s->mx[i];
            gy += s->mass[i] * s->my[i];
        }
        gx /= s->msum;
        gy /= s->msum;
    }
    for (uint64_t m = over | soft; m; m &= m - 1) {               /* eq. (22) */
        int i = __builtin_ctzll(m);
        double g = (over >> i) & 1 ? s->egain : s->egain * dis[i];
        if (s->pull_sim) {                          /* toward G + s R dG0 in the frame */
            double tx = s->fgx + (s->fc * s->gdx0[i] - s->fs * s->gdy0[i]);
            double ty = s->fgy + (s->fs * s->gdx0[i] + s->fc * s->gdy0[i]);
            s->mx[i] = s->mx[i] + g * (tx - s->mx[i]);
            s->my[i] = s->my[i] + g * (ty - s->my[i]);
        } else {                                    /* toward G + dG0 */
            s->mx[i] = s->mx[i] + g * (gx + s->gdx0[i] - s->mx[i]);
            s->my[i] = s->my[i] + g * (gy + s->gdy0[i] - s->my[i]);
        }
    }
    /* eq. (21): insensitive while all of its connections are over (it has some, none calm) */
    uint64_t all = n == 64 ? ~(uint64_t)0 : (((uint64_t)1 << n) - 1);
    s->sens = all & ~(over & ~calm_end);
    for (int i = 0; i < n; i++) {
        s->off[i] = (s->sens >> i) & 1 ? 0.0 : INFINITY;
        check_index(s, i);
    }
}

/* A tracker from the model's arrays: tr[i*8 + ...] = x, y, sxx, sxy, syy, mass, gdx0, gdy0;
 * conn_i[k*3 + ...] = a, b, kinds; conn_d[k*5 + ...] = stiffness, l0, th0, dx0, dy0. */
Peer *peer_new(int n, int nc, int width, int height, const double *par, const double *tr,
               const int *conn_i, const double *conn_d)
{
    if (n < 1 || n > PEER_MAX_T || nc < 0 || nc > PEER_MAX_C || width < 1 || height < 1
        || width > 1 << 15 || height > 1 << 15)
        return NULL;
    Peer *s = aligned_alloc(64, (sizeof(Peer) + 63) / 64 * 64);
    if (!s)
        return NULL;
    memset(s, 0, sizeof(Peer));
    s->cw = (width + (1 << PEER_CELL_SHIFT) - 1) >> PEER_CELL_SHIFT;
    s->ch = (height + (1 << PEER_CELL_SHIFT) - 1) >> PEER_CELL_SHIFT;
    s->cells = calloc((size_t)s->cw * s->ch, sizeof(uint64_t));
    if (!s->cells) {
        free(s);
        return NULL;
    }
    for (int j = 0; j < 64; j++)
        peer_exp2_table[j] = exp2(j / 64.0);
    s->n = n;
    s->nc = nc;
    s->width = width;
    s->height = height;
    s->a1 = par[P_A1];
    s->keep = 1.0 - par[P_A2];
    s->gate = par[P_GATE];
    s->gate_slack = par[P_GATE] * (1.0 + 1e-9);
    s->tau = par[P_TAU];
    s->inv_tau = 1.0 / par[P_TAU];
    s->cov_gain = par[P_COV_GAIN];
    s->smin2 = par[P_SMIN] * par[P_SMIN];
    s->smax2 = par[P_SMAX] * par[P_SMAX];
    s->escale = par[P_ESCALE];
    s->egain = par[P_EGAIN];
    s->period = (int)par[P_PERIOD];
    s->ekind = (int)par[P_EKIND];
    s->pull_sim = par[P_PULL_SIM] != 0.0;
    s->car_sim = par[P_CAR_SIM] != 0.0;
    s->fc = 1.0;                            /* the frame until the first fit: identity at G0 */
    s->fs = 0.0;
    s->fgx = tr[0] - tr[6];
    s->fgy = tr[1] - tr[7];
    s->sens = n == 64 ? ~(uint64_t)0 : (((uint64_t)1 << n) - 1);
    for (int i = 0; i < PEER_MAX_T; i++) {
        s->off[i] = INFINITY;
        s->mx[i] = s->my[i] = 1e30;         /* padding: far away, never a candidate */
        s->ia[i] = s->ic[i] = 1.0;
    }
    for (int i = 0; i < n; i++) {
        s->mx[i] = tr[8 * i];
        s->my[i] = tr[8 * i + 1];
        s->sxx[i] = tr[8 * i + 2];
        s->sxy[i] = tr[8 * i + 3];
        s->syy[i] = tr[8 * i + 4];
        s->mass[i] = tr[8 * i + 5];
        s->inv_mass[i] = 1.0 / s->mass[i];
        s->gdx0[i] = tr[8 * i + 6];
        s->gdy0[i] = tr[8 * i + 7];
        s->off[i] = 0.0;
        s->msum += s->mass[i];
        clamp_and_invert(s, &s->sxx[i], &s->sxy[i], &s->syy[i], &s->ia[i], &s->ib2[i], &s->ic[i]);
        s->cx0[i] = s->cy0[i] = 0;
        s->cx1[i] = s->cy1[i] = -1;         /* no cells yet */
        reindex(s, i);
    }
    s->need_torsion = nc > 0 && s->ekind == 1;
    for (int k = 0; k < nc; k++) {
        s->ca[k] = conn_i[3 * k];
        s->cb[k] = conn_i[3 * k + 1];
        s->kinds[k] = conn_i[3 * k + 2];
        s->stiff[k] = conn_d[5 * k];
        s->l0[k] = conn_d[5 * k + 1];
        s->th0[k] = conn_d[5 * k + 2];
        s->dx0[k] = conn_d[5 * k + 3];
        s->dy0[k] = conn_d[5 * k + 4];
        s->rdx0[k] = s->dx0[k];
        s->rdy0[k] = s->dy0[k];
        s->c0[k] = cos(s->th0[k]);
        s->s0[k] = sin(s->th0[k]);
        s->a_euc[k] = s->kinds[k] & PEER_EUCLIDEAN ? s->stiff[k] : 0.0;
        s->a_tor[k] = s->kinds[k] & PEER_TORSIONAL ? s->stiff[k] : 0.0;
        s->a_car[k] = s->kinds[k] & PEER_CARTESIAN ? s->stiff[k] : 0.0;
        s->degree[s->ca[k]]++;
        s->degree[s->cb[k]]++;
        if (s->kinds[k] & PEER_TORSIONAL)
            s->need_torsion = 1;
    }
    s->last_t = -((int64_t)1 << 62);
    return s;
}

void peer_free(Peer *s)
{
    free(s->cells);
    free(s);
}

/* out[i*6 + ...] = x, y, sxx, sxy, syy, activity at t (eq. 6) of tracker i;
 * counters = valid, assigned, back in time, outside, spring updates, re-indexings. */
void peer_state(const Peer *s, int64_t t, double *out, int64_t *counters)
{
    for (int i = 0; i < s->n; i++) {
        out[6 * i] = s->mx[i];
        out[6 * i + 1] = s->my[i];
        out[6 * i + 2] = s->sxx[i];
        out[6 * i + 3] = s->sxy[i];
        out[6 * i + 4] = s->syy[i];
        out[6 * i + 5] = s->act[i] * exp(-(double)(t - s->tlast[i]) / s->tau);
    }
    counters[0] = s->n_valid;
    counters[1] = s->n_assigned;
    counters[2] = s->n_back;
    counters[3] = s->n_outside;
    counters[4] = s->n_springs;
    counters[5] = s->n_reindex;
}

#endif /* PEER_H */

#ifdef PEER_LOOP
/* Algorithm 1 over n packed events; the .c file including this defines
 *   int scan(const Peer *s, uint64_t cand, double fx, double fy, double *d2)
 *       eq. (2) over the candidate trackers `cand`: the winner or -1
 *   void store_tracker(Peer *s, int i, double x, double y, double ia, double ib2, double ic)
 *       what scan() reads of tracker i, written as scan() reads it
 *   void springs(Peer *s)                                       eqs. (10)-(20)          */

/* eqs. (3)-(6): tracker i takes the event (fx, fy) at t with Mahalanobis distance d2. */
static inline void update_tracker(Peer *s, int i, int64_t t, double fx, double fy, double d2)
{
    double p = peer_exp(-0.5 * d2);                                          /* eq. (2) */
    s->act[i] = s->act[i] * peer_exp(-(double)(t - s->tlast[i]) * s->inv_tau) + p;  /* (6) */
    s->tlast[i] = t;
    double dx = fx - s->mx[i], dy = fy - s->my[i];               /* eq. (5) */
    double x = s->mx[i] + s->a1 * dx;                            /* eq. (3) */
    double y = s->my[i] + s->a1 * dy;
    double sxx = s->keep * s->sxx[i] + s->cov_gain * (dx * dx);  /* eq. (4) */
    double sxy = s->keep * s->sxy[i] + s->cov_gain * (dx * dy);
    double syy = s->keep * s->syy[i] + s->cov_gain * (dy * dy);
    double ia, ib2, ic;
    clamp_and_invert(s, &sxx, &sxy, &syy, &ia, &ib2, &ic);
    s->sxx[i] = sxx;
    s->sxy[i] = sxy;
    s->syy[i] = syy;
    store_tracker(s, i, x, y, ia, ib2, ic);
    check_index(s, i);
}

int64_t peer_run(Peer *s, const PeerEvent *ev, int64_t n)
{
    int64_t last_t = s->last_t, n_valid = 0, n_assigned = 0;
    const int w = s->width, h = s->height, cw = s->cw;
    for (int64_t k = 0; k < n; k++) {
        int64_t t;
        int16_t x, y;
        memcpy(&t, &ev[k].t, 8);
        memcpy(&x, &ev[k].x, 2);
        memcpy(&y, &ev[k].y, 2);
        if (__builtin_expect(t < last_t, 0)) {
            s->n_back++;
            continue;
        }
        last_t = t;
        if (__builtin_expect((unsigned)x >= (unsigned)w || (unsigned)y >= (unsigned)h, 0)) {
            s->n_outside++;
            continue;
        }
        n_valid++;
        uint64_t cand = s->cells[(y >> PEER_CELL_SHIFT) * cw + (x >> PEER_CELL_SHIFT)] & s->sens;
        double fx = x, fy = y, d2;
        int best = scan(s, cand, fx, fy, &d2);
        if (best >= 0) {
            update_tracker(s, best, t, fx, fy, d2);
            n_assigned++;
        }
        if (__builtin_expect(++s->since >= s->period, 0)) {
            s->since = 0;
            s->n_springs++;
            springs(s);
            energy_criteria(s);
        }
    }
    s->last_t = last_t;
    s->n_valid += n_valid;
    s->n_assigned += n_assigned;
    return n;
}
#endif
