/* A hand-written C tracker: the peer of springtrack's float64 kernel in benchmarks/.
 *
 * Valeiras et al. 2015, Algorithm 1, written from springtrack/reference.py the way a C
 * programmer would write it, independently of springtrack/kernel/kernel.pyx (no spatial index,
 * no activity log, libm where the reference calls math):
 *   per event   eq. (2): the sensitive tracker with the smallest Mahalanobis d^2 inside
 *               the gate takes it (ties: lowest index); eqs. (3)-(6): its mean,
 *               covariance and activity move;
 *   every `period` valid events   eqs. (10)-(20): the springs, then eqs. (13), (21)-(22):
 *               the energy criteria; with pull_frame / cartesian_frame = similarity, the
 *               similarity that maps the rest shape onto the calm trackers (fit_frame)
 *               sets eq. (22)'s targets and the next update's Cartesian rest offsets.
 * The two peers differ only in scan() and springs(): plain.c writes them as plain loops,
 * avx2.c with AVX2 intrinsics.  Each .c file defines them, then includes this file's
 * second half (PEER_LOOP) for the event loop.
 *
 * Input: the packed event records of expelliarmus / tonic / numpy files (t int64, x and
 * y int16, p uint8: 13 bytes).  Built by benchmarks/_ctrackers.py with the kernels' own
 * compiler flags (setup.py COMPILE_ARGS) and called through ctypes.
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
    double a1, keep, cov_gain, gate, tau, smin2, smax2, escale, egain, msum;
    /* trackers; arrays padded to a multiple of 4 for the vector peer */
    _Alignas(32) double mx[PEER_MAX_T];
    _Alignas(32) double my[PEER_MAX_T];
    _Alignas(32) double sxx[PEER_MAX_T];
    _Alignas(32) double sxy[PEER_MAX_T];
    _Alignas(32) double syy[PEER_MAX_T];
    _Alignas(32) double ia[PEER_MAX_T];     /* inverse covariance [ia ib; ib ic] */
    _Alignas(32) double ib[PEER_MAX_T];
    _Alignas(32) double ic[PEER_MAX_T];
    _Alignas(32) double off[PEER_MAX_T];    /* 0 if sensitive, +inf if not (or padding) */
    _Alignas(32) double act[PEER_MAX_T];
    _Alignas(32) double mass[PEER_MAX_T];
    _Alignas(32) double inv_mass[PEER_MAX_T];
    _Alignas(32) double gdx0[PEER_MAX_T];
    _Alignas(32) double gdy0[PEER_MAX_T];
    int64_t tlast[PEER_MAX_T];
    int degree[PEER_MAX_T];
    /* connections */
    _Alignas(32) int ca[PEER_MAX_C];
    _Alignas(32) int cb[PEER_MAX_C];
    int kinds[PEER_MAX_C];
    _Alignas(32) double stiff[PEER_MAX_C];
    _Alignas(32) double l0[PEER_MAX_C];
    _Alignas(32) double th0[PEER_MAX_C];
    _Alignas(32) double dx0[PEER_MAX_C];
    _Alignas(32) double dy0[PEER_MAX_C];
    _Alignas(32) double rdx0[PEER_MAX_C];   /* eq. (18)'s rest offset: s R d0 (or d0) */
    _Alignas(32) double rdy0[PEER_MAX_C];
    _Alignas(32) double c0[PEER_MAX_C];     /* cos th0, sin th0 */
    _Alignas(32) double s0[PEER_MAX_C];
    _Alignas(32) double a_euc[PEER_MAX_C];  /* stiffness where the connection has the kind */
    _Alignas(32) double a_tor[PEER_MAX_C];
    _Alignas(32) double a_car[PEER_MAX_C];
    _Alignas(32) double energy[3][PEER_MAX_C];
    double mean_energy;
    double fc, fs, fgx, fgy;                /* the similarity frame: s R = [[fc, -fs], [fs, fc]] */
    int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_springs;
} Peer;

static inline double wrap_angle(double a)
{
    if (a >= M_PI)
        return a - 2.0 * M_PI;
    if (a < -M_PI)
        return a + 2.0 * M_PI;
    return a;
}

/* Bound sigma_x, sigma_y to [sigma_min, sigma_max] and |rho| to RHO_MAX; keep Sigma^-1. */
static inline void clamp_and_invert(Peer *s, int i)
{
    double sxx = fmin(fmax(s->sxx[i], s->smin2), s->smax2);
    double syy = fmin(fmax(s->syy[i], s->smin2), s->smax2);
    double lim = PEER_RHO_MAX * sqrt(sxx * syy);
    double sxy = fmin(fmax(s->sxy[i], -lim), lim);
    s->sxx[i] = sxx;
    s->sxy[i] = sxy;
    s->syy[i] = syy;
    double inv_det = 1.0 / (sxx * syy - sxy * sxy);
    s->ia[i] = syy * inv_det;
    s->ib[i] = -sxy * inv_det;
    s->ic[i] = sxx * inv_det;
}

/* eqs. (3)-(6): tracker i takes the event (fx, fy) at t with Mahalanobis distance d2. */
static inline void update_tracker(Peer *s, int i, int64_t t, double fx, double fy, double d2)
{
    double p = exp(-0.5 * d2);                                   /* eq. (2) */
    s->act[i] = s->act[i] * exp(-(double)(t - s->tlast[i]) / s->tau) + p;   /* eq. (6) */
    s->tlast[i] = t;
    double dx = fx - s->mx[i], dy = fy - s->my[i];               /* eq. (5) */
    s->mx[i] = s->mx[i] + s->a1 * dx;                            /* eq. (3) */
    s->my[i] = s->my[i] + s->a1 * dy;
    s->sxx[i] = s->keep * s->sxx[i] + s->cov_gain * (dx * dx);   /* eq. (4) */
    s->sxy[i] = s->keep * s->sxy[i] + s->cov_gain * (dx * dy);
    s->syy[i] = s->keep * s->syy[i] + s->cov_gain * (dy * dy);
    clamp_and_invert(s, i);
}

/* The similarity x -> G + s R (x - G0) that best maps the rest shape onto the means of
 * the trackers no over-threshold connection touches (all trackers if fewer than 2), in
 * the mass-weighted least-squares sense (reference.py fit_frame): with rest offsets p and
 * current offsets q about the weighted centroids, a = sum m p.q, b = sum m p x q,
 * D = sum m |p|^2, s R = [[a, -b], [b, a]] / D, the scale held to its bounds. */
static void fit_frame(Peer *s, const int *over)
{
    int n = s->n, fit[PEER_MAX_T], nf = 0;
    for (int i = 0; i < n; i++)
        if (over[i] == 0)
            fit[nf++] = i;
    if (nf < 2) {
        nf = n;
        for (int i = 0; i < n; i++)
            fit[i] = i;
    }
    double w = 0.0, px = 0.0, py = 0.0, qx = 0.0, qy = 0.0;
    for (int f = 0; f < nf; f++) {                                /* weighted centroids */
        int i = fit[f];
        double m = s->mass[i];
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
    for (int f = 0; f < nf; f++) {
        int i = fit[f];
        double m = s->mass[i];
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

/* eqs. (13), (21)-(22) on the energies of the last spring update. */
static void energy_criteria(Peer *s)
{
    int n = s->n, nc = s->nc, over[PEER_MAX_T] = {0};
    if (nc == 0)
        return;
    const double *e = s->energy[s->ekind];
    double total = 0.0, gx = 0.0, gy = 0.0;
    for (int k = 0; k < nc; k++)                                  /* eq. (13) */
        total += e[k];
    s->mean_energy = total / nc;
    double thr = s->escale * s->mean_energy;
    for (int k = 0; k < nc; k++)
        if (e[k] > thr) {
            over[s->ca[k]]++;
            over[s->cb[k]]++;
        }
    if (s->pull_sim || s->car_sim)
        fit_frame(s, over);
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
    for (int i = 0; i < n; i++) {
        if (over[i] > 0) {                                        /* eq. (22) */
            if (s->pull_sim) {                      /* toward G + s R dG0 in the frame */
                double tx = s->fgx + (s->fc * s->gdx0[i] - s->fs * s->gdy0[i]);
                double ty = s->fgy + (s->fs * s->gdx0[i] + s->fc * s->gdy0[i]);
                s->mx[i] = s->mx[i] + s->egain * (tx - s->mx[i]);
                s->my[i] = s->my[i] + s->egain * (ty - s->my[i]);
            } else {                                /* toward G + dG0 */
                s->mx[i] = s->mx[i] + s->egain * (gx + s->gdx0[i] - s->mx[i]);
                s->my[i] = s->my[i] + s->egain * (gy + s->gdy0[i] - s->my[i]);
            }
        }
        /* eq. (21): insensitive while all of its connections are over */
        s->off[i] = (s->degree[i] > 0 && over[i] == s->degree[i]) ? INFINITY : 0.0;
    }
}

/* A tracker from the model's arrays: tr[i*8 + ...] = x, y, sxx, sxy, syy, mass, gdx0, gdy0;
 * conn_i[k*3 + ...] = a, b, kinds; conn_d[k*5 + ...] = stiffness, l0, th0, dx0, dy0. */
Peer *peer_new(int n, int nc, int width, int height, const double *par, const double *tr,
               const int *conn_i, const double *conn_d)
{
    if (n < 1 || n > PEER_MAX_T || nc < 0 || nc > PEER_MAX_C)
        return NULL;
    Peer *s = aligned_alloc(64, (sizeof(Peer) + 63) / 64 * 64);
    if (!s)
        return NULL;
    memset(s, 0, sizeof(Peer));
    s->n = n;
    s->nc = nc;
    s->width = width;
    s->height = height;
    s->a1 = par[P_A1];
    s->keep = 1.0 - par[P_A2];
    s->gate = par[P_GATE];
    s->tau = par[P_TAU];
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
    for (int i = 0; i < PEER_MAX_T; i++)
        s->off[i] = INFINITY;
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
        clamp_and_invert(s, i);
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

void peer_free(Peer *s) { free(s); }

/* out[i*6 + ...] = x, y, sxx, sxy, syy, activity at t (eq. 6) of tracker i;
 * counters = valid, assigned, back in time, outside, spring updates. */
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
}

#endif /* PEER_H */

#ifdef PEER_LOOP
/* Algorithm 1 over n packed events; the .c file including this defines
 *   int scan(const Peer *s, double fx, double fy, double *d2)   eq. (2): winner or -1
 *   void springs(Peer *s)                                       eqs. (10)-(22)          */
int64_t peer_run(Peer *s, const PeerEvent *ev, int64_t n)
{
    for (int64_t k = 0; k < n; k++) {
        int64_t t;
        int16_t x, y;
        memcpy(&t, &ev[k].t, 8);
        memcpy(&x, &ev[k].x, 2);
        memcpy(&y, &ev[k].y, 2);
        if (t < s->last_t) {
            s->n_back++;
            continue;
        }
        s->last_t = t;
        if (x < 0 || y < 0 || x >= s->width || y >= s->height) {
            s->n_outside++;
            continue;
        }
        s->n_valid++;
        double fx = x, fy = y, d2;
        int best = scan(s, fx, fy, &d2);
        if (best >= 0) {
            update_tracker(s, best, t, fx, fy, d2);
            s->n_assigned++;
        }
        if (++s->since >= s->period) {
            s->since = 0;
            s->n_springs++;
            springs(s);
            energy_criteria(s);
        }
    }
    return n;
}
#endif
