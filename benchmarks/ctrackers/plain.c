/* The plain-C peer tracker (see peer.h): eq. (2) over the index's candidates, the springs
 * as passes over arrays of connections (the compiler vectorises them at -O3 -march=native;
 * peer.h's branch-free atan2 and sincos instead of libm's). */
#include "peer.h"

/* eq. (2) in the log domain: the candidate with the smallest d^2 below the gate, in
 * increasing index (a strict < keeps the lowest index on ties); d^2 is the one eq. (2)'s
 * probability is computed from. */
static inline int scan(const Peer *s, uint64_t cand, double fx, double fy, double *d2_out)
{
    int best = -1;
    double best_d2 = s->gate;
    for (; cand; cand &= cand - 1) {
        int i = __builtin_ctzll(cand);
        double dx = fx - s->mx[i], dy = fy - s->my[i];
        double d2 = s->ia[i] * dx * dx + s->ic[i] * dy * dy + s->ib2[i] * dx * dy;
        int lt = d2 < best_d2;
        best_d2 = lt ? d2 : best_d2;
        best = lt ? i : best;
    }
    *d2_out = best_d2;
    return best;
}

static inline void store_tracker(Peer *s, int i, double x, double y, double ia, double ib2,
                                 double ic)
{
    s->mx[i] = x;
    s->my[i] = y;
    s->ia[i] = ia;
    s->ib2[i] = ib2;
    s->ic[i] = ic;
}

/* eqs. (10)-(20): every displacement from the same positions, then applied. */
static void springs(Peer *s)
{
    int n = s->n, nc = s->nc;
    _Alignas(64) double rxs[PEER_MAX_C], rys[PEER_MAX_C], dth[PEER_MAX_C];
    _Alignas(64) double ux_[PEER_MAX_C], uy_[PEER_MAX_C];
    double ddx[PEER_MAX_T] = {0}, ddy[PEER_MAX_T] = {0};
    const double *mx = s->mx, *my = s->my, *im = s->inv_mass;
    double mean_dth = 0.0;
    for (int k = 0; k < nc; k++) {
        rxs[k] = mx[s->cb[k]] - mx[s->ca[k]];
        rys[k] = my[s->cb[k]] - my[s->ca[k]];
    }
    if (s->need_torsion) {
        for (int k = 0; k < nc; k++) {                            /* eq. (14) */
            dth[k] = wrap_angle(peer_atan2(rys[k], rxs[k]) - s->th0[k]);
            mean_dth += dth[k];
        }
        mean_dth /= nc;                                           /* eq. (15) */
    }
    for (int k = 0; k < nc; k++) {
        double a = s->stiff[k], rx = rxs[k], ry = rys[k];
        double l = sqrt(rx * rx + ry * ry);
        double dl = l - s->l0[k];                                 /* eq. (10) */
        s->energy[0][k] = 0.5 * a * (dl * dl);                    /* eq. (12) */
        double ex = rx - s->rdx0[k], ey = ry - s->rdy0[k];        /* eq. (18) */
        s->energy[2][k] = 0.5 * a * (ex * ex + ey * ey);          /* eq. (20) */
        int pos = l > 0.0;                                        /* eq. (11) */
        double inv_l = 1.0 / (pos ? l : 1.0);
        double cx = pos ? rx * inv_l : s->c0[k], cy = pos ? ry * inv_l : s->s0[k];
        double g = s->a_euc[k] * dl;
        ux_[k] = g * cx + s->a_car[k] * ex;                      /* eqs. (11), (19) */
        uy_[k] = g * cy + s->a_car[k] * ey;
    }
    if (s->need_torsion) {
        for (int k = 0; k < nc; k++) {
            double d = dth[k] - mean_dth;                         /* eq. (15) */
            s->energy[1][k] = 0.5 * s->stiff[k] * (d * d);        /* eq. (17) */
            double se, ce;                                        /* eq. (16) */
            peer_sincos(s->a_tor[k] * d, &se, &ce);
            double cm1 = ce - 1.0;
            ux_[k] += rxs[k] * cm1 - rys[k] * se;
            uy_[k] += rys[k] * cm1 + rxs[k] * se;
        }
    } else {
        for (int k = 0; k < nc; k++)
            s->energy[1][k] = 0.0;
    }
    for (int k = 0; k < nc; k++) {                                /* onto both ends */
        int i = s->ca[k], j = s->cb[k];
        ddx[i] += ux_[k] * im[i];
        ddy[i] += uy_[k] * im[i];
        ddx[j] -= ux_[k] * im[j];
        ddy[j] -= uy_[k] * im[j];
    }
    for (int i = 0; i < n; i++) {
        s->mx[i] += ddx[i];
        s->my[i] += ddy[i];
    }
}

const char *peer_isa(void) { return "scalar C"; }

#define PEER_LOOP
#include "peer.h"
