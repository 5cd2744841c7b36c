/* The plain-C peer tracker (see peer.h): eq. (2) as a loop over every tracker, the springs
 * as springtrack/reference.py writes them, libm's atan2, sin and cos. */
#include "peer.h"

/* eq. (2) in the log domain: the sensitive tracker with the smallest d^2 below the gate. */
static inline int scan(const Peer *s, double fx, double fy, double *d2_out)
{
    int best = -1;
    double best_d2 = s->gate;
    for (int i = 0; i < s->n; i++) {
        if (s->off[i] != 0.0)
            continue;
        double dx = fx - s->mx[i], dy = fy - s->my[i];
        double d2 = s->ia[i] * dx * dx + s->ic[i] * dy * dy + 2.0 * s->ib[i] * dx * dy;
        if (d2 < best_d2) {
            best_d2 = d2;
            best = i;
        }
    }
    *d2_out = best_d2;
    return best;
}

/* eqs. (10)-(20): every displacement from the same positions, then applied. */
static void springs(Peer *s)
{
    int n = s->n, nc = s->nc;
    double ddx[PEER_MAX_T] = {0}, ddy[PEER_MAX_T] = {0}, dth_raw[PEER_MAX_C];
    double mean_dth = 0.0;
    const double *mx = s->mx, *my = s->my, *im = s->inv_mass;
    if (s->need_torsion) {
        for (int k = 0; k < nc; k++) {                            /* eq. (14) */
            int i = s->ca[k], j = s->cb[k];
            double th = atan2(my[j] - my[i], mx[j] - mx[i]);
            dth_raw[k] = wrap_angle(th - s->th0[k]);
            mean_dth += dth_raw[k];
        }
        mean_dth /= nc;                                           /* eq. (15) */
    }
    for (int k = 0; k < nc; k++) {
        int i = s->ca[k], j = s->cb[k], kind = s->kinds[k];
        double a = s->stiff[k];
        double rx = mx[j] - mx[i], ry = my[j] - my[i];
        double l = sqrt(rx * rx + ry * ry);
        double dl = l - s->l0[k];                                 /* eq. (10) */
        s->energy[0][k] = 0.5 * a * (dl * dl);                    /* eq. (12) */
        double ex = rx - s->rdx0[k], ey = ry - s->rdy0[k];        /* eq. (18) */
        s->energy[2][k] = 0.5 * a * (ex * ex + ey * ey);          /* eq. (20) */
        if (kind & PEER_EUCLIDEAN) {                              /* eq. (11) */
            double cx, cy;
            if (l > 0.0) {
                double inv_l = 1.0 / l;
                cx = rx * inv_l;
                cy = ry * inv_l;
            } else {
                cx = s->c0[k];
                cy = s->s0[k];
            }
            double fx = a * dl * cx, fy = a * dl * cy;
            ddx[i] += fx * im[i];
            ddy[i] += fy * im[i];
            ddx[j] -= fx * im[j];
            ddy[j] -= fy * im[j];
        }
        if (s->need_torsion) {
            double dth = dth_raw[k] - mean_dth;                   /* eq. (15) */
            s->energy[1][k] = 0.5 * a * (dth * dth);              /* eq. (17) */
            if (kind & PEER_TORSIONAL) {                          /* eq. (16) */
                double eps = a * dth, cm1 = cos(eps) - 1.0, se = sin(eps);
                double ux = rx * cm1 - ry * se, uy = ry * cm1 + rx * se;
                ddx[i] += ux * im[i];
                ddy[i] += uy * im[i];
                ddx[j] -= ux * im[j];
                ddy[j] -= uy * im[j];
            }
        } else {
            s->energy[1][k] = 0.0;
        }
        if (kind & PEER_CARTESIAN) {                              /* eq. (19) */
            ddx[i] += a * ex * im[i];
            ddy[i] += a * ey * im[i];
            ddx[j] -= a * ex * im[j];
            ddy[j] -= a * ey * im[j];
        }
    }
    for (int i = 0; i < n; i++) {
        s->mx[i] += ddx[i];
        s->my[i] += ddy[i];
    }
}

#define PEER_LOOP
#include "peer.h"
