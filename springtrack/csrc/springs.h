/* The spring update of the tracker kernel (springtrack/kernel/kernel.pyx ksprings) as
 * structure-of-arrays passes over the connections and trackers, branch-free so that GCC
 * vectorises them (clones for SSE2 / AVX2 / AVX-512, picked at load time).
 * springtrack/reference.py springs() and _energy_criteria() are the specification; these
 * passes compute the same quantities in the same order per connection, so the kernel
 * differs from the reference by the rounding of fastmath.h's atan2 / sin / cos only.
 *
 *   st_torsion_angles       eq. (14): angle of each connection from its rest direction
 *   st_torsion_angles_framed  the same, fast, when every connection is near its rest
 *                           direction turned by a common frame angle
 *   st_torsion_rotation     eqs. (15)-(17): deviation from the mean angle, its energy and
 *                           the rotation sin(eps), cos(eps) - 1 of eq. (16)
 *   st_spring_terms_batch   eqs. (10)-(12), (16), (18)-(20): energies and the summed
 *                           displacement of both ends, already divided by their masses
 *   st_over_ends            eqs. (21)-(22) once the threshold is known: the trackers
 *                           at an over-threshold connection, and those at one under it,
 *                           as bit masks (no branch)
 *   st_fit_frame            the similarity frame of eq. (22) and eqs. (18)-(20): the
 *                           mass-weighted Procrustes fit of the rest shape to the means
 *   st_frame_weights        how well each tracker of a fit set agrees with its frame
 *                           (eq. 21's test on the frame's residuals, made continuous):
 *                           st_frame_residuals and st_frame_ramp its vector passes
 *   st_turn_offsets         eq. (18)'s rest offsets in that frame, s R d0
 *   st_pull                 eq. (22): the pull of the former toward G + s R dG0
 *   st_boxes_left           which trackers' gate boxes left their indexed boxes
 *   st_bounds               the smallest and largest of n values (an instance's spring box)
 */
#ifndef SPRINGTRACK_SPRINGS_H
#define SPRINGTRACK_SPRINGS_H

#include <string.h>

#include "fastmath.h"

/* x[0] + ... + x[n-1] in four interleaved partial sums (a chain of n/4 additions, not n:
 * the mean angle and the mean energy gate the rest of the spring update) */
static inline double st_sum(int n, const double *restrict x)
{
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
    int k = 0;
    for (; k + 4 <= n; k += 4) {
        a0 += x[k];
        a1 += x[k + 1];
        a2 += x[k + 2];
        a3 += x[k + 3];
    }
    for (; k < n; k++)
        a0 += x[k];
    return (a0 + a1) + (a2 + a3);
}

/* eqs. (21)-(22), which trackers the over-threshold connections touch: ends[k] has the
 * bits of connection k's two trackers; over = e[k] > thr (thr: energy_scale times the mean
 * energy, eq. 13).  *pulled = the trackers with an over connection (eq. 22 moves them
 * toward G); *calm = the trackers with a connection that is not over (eq. 21 keeps them
 * sensitive).  The reference counts each tracker's over connections and compares the
 * count with its degree; these OR-reductions over the connections give the same answer,
 * four connections per AVX2 instruction. */
ST_CLONES static void st_over_ends(int nc, const double *restrict e, double thr,
                                   const uint64_t *restrict ends, uint64_t *pulled,
                                   uint64_t *calm)
{
    uint64_t p = 0, c = 0;
    for (int k = 0; k < nc; k++) {
        uint64_t over = (uint64_t)0 - (uint64_t)(e[k] > thr);
        p |= ends[k] & over;
        c |= ends[k] & ~over;
    }
    *pulled = p;
    *calm = c;
}

/* eq. (22): the trackers in the mask pulled move toward G + s R dG0 by gain, the others
 * by gain 0 (mx + 0 = mx exactly), without a branch.  s R = [[c, -sn], [sn, c]]: the
 * similarity frame (st_fit_frame), or c = 1, sn = 0 in the image frame, where the target
 * is gx + (1 gdx0 - 0 gdy0) = gx + gdx0 exactly, the reference's G + dG0.  The others by
 * gain dis[i], how much they disagree with the frame (st_frame_weights; 0: not at all). */
ST_CLONES static void st_pull(int n, uint64_t pulled, double gx, double gy, double c, double sn,
                              double gain, const double *restrict dis,
                              const double *restrict gdx0, const double *restrict gdy0,
                              double *restrict mx, double *restrict my)
{
    for (int i = 0; i < n; i++) {
        uint64_t bit = (pulled >> (uint64_t)i) & 1;   /* a 64-bit shift count vectorises */
        double g = st_sel((int64_t)bit, gain, gain * dis[i]);
        double tx = gx + (c * gdx0[i] - sn * gdy0[i]);
        double ty = gy + (sn * gdx0[i] + c * gdy0[i]);
        mx[i] = mx[i] + g * (tx - mx[i]);
        my[i] = my[i] + g * (ty - my[i]);
    }
}

/* [ref] FRAME_SCALE_MIN, FRAME_SCALE_MAX, FRAME_MIN_SPREAD (kernel/kernel.pyx checks they agree) */
#define ST_FRAME_SCALE_MIN 0.25
#define ST_FRAME_SCALE_MAX 4.0
#define ST_FRAME_MIN_SPREAD 0x1p-20
#define ST_FRAME_AGREE_PX2 0x1p-4                     /* [ref] FRAME_AGREE_PX2 */
#define ST_FRAME_RAMP 0x1p-1                          /* [ref] FRAME_RAMP */
#define ST_MAX_FIT 64                           /* trackers (MAX_TRACKERS of kernel/state.pxd) */

/* [ref] fit_frame: the similarity x -> G + s R (x - G0) that best maps the rest shape onto
 * the means (mx, my), mass-weighted least squares over the trackers of the mask fit (all
 * n trackers if it holds fewer than 2).  With rest offsets p = dG0 - pbar and current
 * offsets q = mu - qbar about the fit set's weighted centroids:
 *     a = sum m p.q,  b = sum m p x q,  D = sum m |p|^2,  s R = [[a, -b], [b, a]] / D
 * returned as *c = a / D, *sn = b / D (s R = [[c, -sn], [sn, c]]), the scale held to
 * [ST_FRAME_SCALE_MIN, ST_FRAME_SCALE_MAX], s R = I when D <= ST_FRAME_MIN_SPREAD sum m;
 * and G = qbar - s R pbar, where the rest centre of mass G0 goes.  The trackers outside
 * the set weigh 0.
 * One pass: the moments about (rx, ry) (the last frame's G, near qbar: little cancels)
 * are summed, then centred, a = sum m p.q' - (sum m p).(sum m q') / sum m with
 * q' = mu - r, and likewise b and D; in ST_FIT_LANES interleaved partial sums (a vector),
 * over n rounded up to ST_FIT_LANES: the arrays must hold that many finite entries
 * (KState pads its per-tracker arrays for it: TRACKER_PAD).  The reference sums the centred terms in index order: the two differ
 * by rounding. */
#define ST_FIT_LANES 4
typedef double st_fit_v __attribute__((vector_size(ST_FIT_LANES * sizeof(double))));
typedef int64_t st_fit_m __attribute__((vector_size(ST_FIT_LANES * sizeof(int64_t))));
#define ST_FIT_LOAD(v, p) memcpy(&(v), (p), sizeof(v))    /* unaligned vector load */
#define ST_FIT_SUM(v) (((v)[0] + (v)[1]) + ((v)[2] + (v)[3]))

ST_CLONES static void st_fit_frame(int n, uint64_t fit, const double *restrict mass,
                                   const double *restrict gdx0, const double *restrict gdy0,
                                   const double *restrict mx, const double *restrict my,
                                   double rx, double ry, double *c, double *sn, double *gx,
                                   double *gy)
{
    const st_fit_m lane = {1, 2, 4, 8};
    const st_fit_v vrx = {rx, rx, rx, rx}, vry = {ry, ry, ry, ry};
    st_fit_v w = {0}, spx = {0}, spy = {0}, sqx = {0}, sqy = {0}, sa = {0}, sb = {0}, sd = {0};
    st_fit_v m, ux, uy, vx, vy;
    st_fit_m mb;
    double W, px, py, qx, qy, a, b, d, cc, ss, k2, f;
    uint64_t all = n >= 64 ? ~(uint64_t)0 : ((uint64_t)1 << n) - 1;
    int i, nv = (n + ST_FIT_LANES - 1) / ST_FIT_LANES;
    fit &= all;
    if (__builtin_popcountll(fit) < 2)
        fit = all;
    for (i = 0; i < nv; i++) {
        st_fit_m in = (((st_fit_m){0, 0, 0, 0} + (int64_t)(fit >> (ST_FIT_LANES * i))) & lane)
                      != 0;                         /* -1 in the set, else 0 */
        ST_FIT_LOAD(m, mass + ST_FIT_LANES * i);
        memcpy(&mb, &m, sizeof mb);
        mb &= in;
        memcpy(&m, &mb, sizeof m);                  /* the mass, or +0.0 outside the set */
        ST_FIT_LOAD(ux, gdx0 + ST_FIT_LANES * i);   /* rest offset about G0 */
        ST_FIT_LOAD(uy, gdy0 + ST_FIT_LANES * i);
        ST_FIT_LOAD(vx, mx + ST_FIT_LANES * i);
        ST_FIT_LOAD(vy, my + ST_FIT_LANES * i);
        vx -= vrx;                                  /* mean about r */
        vy -= vry;
        st_fit_v mux = m * ux, muy = m * uy;
        w += m;
        spx += mux;
        spy += muy;
        sqx += m * vx;
        sqy += m * vy;
        sa += mux * vx + muy * vy;                  /* sum m p.q' */
        sb += mux * vy - muy * vx;                  /* sum m p x q' */
        sd += mux * ux + muy * uy;                  /* sum m |p|^2 */
    }
    W = ST_FIT_SUM(w);
    px = ST_FIT_SUM(spx);
    py = ST_FIT_SUM(spy);
    qx = ST_FIT_SUM(sqx);
    qy = ST_FIT_SUM(sqy);
    a = ST_FIT_SUM(sa) - (px * qx + py * qy) / W;   /* a = sum m p.q, centred */
    b = ST_FIT_SUM(sb) - (px * qy - py * qx) / W;   /* b = sum m p x q */
    d = ST_FIT_SUM(sd) - (px * px + py * py) / W;   /* D = sum m |p|^2 */
    px = px / W;                                    /* pbar, about G0 */
    py = py / W;
    qx = rx + qx / W;                               /* qbar */
    qy = ry + qy / W;
    if (d <= ST_FRAME_MIN_SPREAD * W) {
        cc = 1.0;
        ss = 0.0;
    } else {
        cc = a / d;                                      /* s R = [[a, -b], [b, a]] / D */
        ss = b / d;
        k2 = cc * cc + ss * ss;                          /* s^2 */
        if (k2 > ST_FRAME_SCALE_MAX * ST_FRAME_SCALE_MAX) {
            f = ST_FRAME_SCALE_MAX / sqrt(k2);
            cc = cc * f;
            ss = ss * f;
        } else if (k2 < ST_FRAME_SCALE_MIN * ST_FRAME_SCALE_MIN) {
            if (k2 > 0.0) {
                f = ST_FRAME_SCALE_MIN / sqrt(k2);
                cc = cc * f;
                ss = ss * f;
            } else {                                     /* no rotation to keep */
                cc = ST_FRAME_SCALE_MIN;
                ss = 0.0;
            }
        }
    }
    *c = cc;
    *sn = ss;
    *gx = qx - (cc * px - ss * py);                      /* G = qbar - s R pbar */
    *gy = qy - (ss * px + cc * py);
}

/* [ref] fit_frame's residuals: r2[i] = |mu - (G + s R dG0)|^2 in the frame (c, sn, gx,
 * gy) for every i < n (the arrays padded as for st_fit_frame), so that the pass
 * vectorises; st_frame_weights reads those of its fit set. */
ST_CLONES static void st_frame_residuals(int n, double c, double sn, double gx, double gy,
                                         const double *restrict gdx0,
                                         const double *restrict gdy0,
                                         const double *restrict mx, const double *restrict my,
                                         double *restrict r2)
{
    for (int i = 0; i < n; i++) {
        double ex = mx[i] - (gx + (c * gdx0[i] - sn * gdy0[i]));  /* mu - (G + s R dG0) */
        double ey = my[i] - (gy + (sn * gdx0[i] + c * gdy0[i]));
        r2[i] = ex * ex + ey * ey;
    }
}

/* [ref] fit_frame's ramp: v[i] = 1 up to thr, 0 from (1 + ST_FRAME_RAMP) thr, linear
 * between, for every i < n; *changed = 1 if some v of the mask fit differs from wt;
 * returns the mask of fit's positive v.  Branch-free, so that it vectorises. */
ST_CLONES static uint64_t st_frame_ramp(int n, uint64_t fit, double thr,
                                        const double *restrict r2, const double *restrict wt,
                                        double *restrict v, int64_t *changed)
{
    uint64_t pos = 0;
    int64_t ch = 0;
    for (int i = 0; i < n; i++) {
        uint64_t in = (fit >> (uint64_t)i) & 1;       /* a 64-bit shift count vectorises */
        double x = 1.0 - (r2[i] - thr) / (ST_FRAME_RAMP * thr);   /* 1 to T, 0 from (1 + ramp) T */
        x = st_sel(x < 0.0, 0.0, x);
        x = st_sel(x > 1.0, 1.0, x);
        v[i] = x;
        ch |= (int64_t)(in & (uint64_t)(x != wt[i]));
        pos |= (in & (uint64_t)(x > 0.0)) << (uint64_t)i;
    }
    *changed = ch;
    return pos;
}

/* [ref] fit_frame's weights: for the trackers of the mask fit, their squared residuals
 * r^2 = |mu - (G + s R dG0)|^2 in the frame (c, sn, gx, gy), T = max(scale sum m wt r^2 /
 * sum m wt, ST_FRAME_AGREE_PX2) and v = 1 up to T, 0 from (1 + ST_FRAME_RAMP) T, linear
 * between; the sums in index order as the reference (a chain: only the residuals and the
 * ramp are vector passes).  If some v differs from wt and at least 2 are positive:
 * wt = v, wm = mass v (the masses of the refit) and the mask of the positive ones is
 * returned; else 0 (wt, wm unchanged).  wt and wm hold n entries: those outside fit are
 * written too (with the ramp's value) but weigh nothing. */
static inline uint64_t st_frame_weights(int n, uint64_t fit, double scale,
                                  const double *restrict mass, double *restrict wt,
                                  double *restrict wm, const double *restrict gdx0,
                                  const double *restrict gdy0, const double *restrict mx,
                                  const double *restrict my, double c, double sn, double gx,
                                  double gy)
{
    double r2[ST_MAX_FIT], v[ST_MAX_FIT], w = 0.0, total = 0.0, m, thr;
    uint64_t pos, f;
    int64_t changed;
    int i;
    st_frame_residuals(n, c, sn, gx, gy, gdx0, gdy0, mx, my, r2);
    for (f = fit; f; f &= f - 1) {
        i = __builtin_ctzll(f);
        m = mass[i] * wt[i];
        w += m;
        total += m * r2[i];
    }
    thr = scale * (total / w);                                /* eq. (21)'s test on r^2 */
    if (thr < ST_FRAME_AGREE_PX2)
        thr = ST_FRAME_AGREE_PX2;
    pos = st_frame_ramp(n, fit, thr, r2, wt, v, &changed);
    if (!changed || (pos & (pos - 1)) == 0)                   /* or fewer than 2 left */
        return 0;
    for (i = 0; i < n; i++) {                     /* all n: those outside fit are not read */
        wt[i] = v[i];
        wm[i] = mass[i] * v[i];
    }
    return pos;
}

/* eq. (18)'s rest offsets in the similarity frame: (odx, ody) = s R (dx0, dy0) */
ST_CLONES static void st_turn_offsets(int n, double c, double sn, const double *restrict dx0,
                                      const double *restrict dy0, double *restrict odx,
                                      double *restrict ody)
{
    for (int k = 0; k < n; k++) {
        odx[k] = c * dx0[k] - sn * dy0[k];
        ody[k] = sn * dx0[k] + c * dy0[k];
    }
}

/* eq. (14): th[k] = th - th0 as the angle from the rest direction (rdx, rdy) to
 * r = (rx, ry), atan2(rest x r, rest . r), in [-pi, pi) as the reference's wrap_angle;
 * exactly 0 when r is the rest offset.  When both ends coincide (r = 0) the reference's
 * atan2(0, 0) - th0 gives dth_zero. */
ST_CLONES static void st_torsion_angles(int n, const double *restrict rx,
                                        const double *restrict ry,
                                        const double *restrict rdx,
                                        const double *restrict rdy,
                                        const double *restrict dth_zero, double *restrict th)
{
    for (int k = 0; k < n; k++) {
        double x = rx[k], y = ry[k];
        double d = st_atan2(rdx[k] * y - rdy[k] * x, rdx[k] * x + rdy[k] * y);
        d = st_sel(d >= ST_PI_HI, d - 2.0 * ST_PI_HI, d);        /* [ref] wrap_angle */
        th[k] = st_sel(x == 0.0 && y == 0.0, dth_zero[k], d);
    }
}

/* eq. (14) the fast way, measured in a frame: (qdx, qdy) is each rest direction turned by
 * the frame angle phi (the mean angle of a recent update), so that
 *     th[k] = wrap(phi + atan2(q x r, q . r))
 * and the angle from q to r stays well inside +-3 pi/8 while the structure moves and
 * turns as a whole.  Within that range (q . r > 0, |q x r| < tan(3 pi/8) q . r) the angle
 * is atan t of t = (q x r) / (q . r), reduced as in st_atan2 only for |t| > tan(pi/8) and
 * with the sign of t: no swap, no octant, about half the work of st_atan2 and a shorter
 * chain.  Returns 1 if any connection is outside that range (r = 0 included): th is then
 * not filled right and the caller runs st_torsion_angles instead.  th equals
 * st_torsion_angles' value up to rounding (~1e-15 rad), as both equal the reference's. */
#define ST_TAN_3PI_8 2.414213562373095
ST_CLONES static int64_t st_torsion_angles_framed(int n, const double *restrict rx,
                                                  const double *restrict ry,
                                                  const double *restrict qdx,
                                                  const double *restrict qdy, double phi,
                                                  double *restrict th)
{
    int64_t far = 0;
    for (int k = 0; k < n; k++) {
        double x = rx[k], y = ry[k];
        double c = qdx[k] * y - qdy[k] * x, d = qdx[k] * x + qdy[k] * y, ac = fabs(c);
        far |= !(ac < ST_TAN_3PI_8 * d);
        int64_t big = ac > ST_TAN_PI_8 * d;           /* atan t = pi/4 + atan((t-1)/(t+1)) */
        double a = st_atan_reduced(st_sel(big, ac - d, c) / st_sel(big, ac + d, d));
        a = st_sel(big, copysign((ST_PI4_LO + a) + ST_PI4_HI, c), a);
        a = a + phi;
        a = st_sel(a >= ST_PI_HI, a - 2.0 * ST_PI_HI, a);        /* [ref] wrap_angle */
        th[k] = st_sel(a < -ST_PI_HI, a + 2.0 * ST_PI_HI, a);
    }
    return far;
}

/* eqs. (15)-(17): d = th - mean (eq. 15), e_tor = a/2 d^2 (eq. 17), eps = a_tor d
 * (eq. 16, a_tor = 0 without a torsional spring), then sn, cm1 = sin eps, cos eps - 1 by
 * fastmath.h's st_sincos_batch. */
ST_CLONES static void st_torsion_rotation(int n, const double *restrict th, double mean,
                                          const double *restrict half_a,
                                          const double *restrict a_tor,
                                          double *restrict e_tor, double *restrict eps,
                                          double *restrict sn, double *restrict cm1)
{
    for (int k = 0; k < n; k++) {
        double d = th[k] - mean;
        e_tor[k] = half_a[k] * (d * d);
        eps[k] = a_tor[k] * d;
    }
    st_sincos_batch(eps, sn, cm1, n);
}

/* Spring terms per connection k.  Inputs: r = (rx, ry) = end b - end a; sn, cm1 = sin,
 * cos - 1 of the torsional rotation eps (0 without torsion); rest length l0, rest offset
 * (dx0, dy0), a/2 = half_a, the kind-masked stiffnesses a_euc, a_car (0 where the spring
 * lacks that kind), the rest direction (c0, s0), and 1/mass of end a (wa) and end b (wb).
 * Outputs: the Euclidean and Cartesian energies, and the displacement u of the connection
 * (the three kinds summed) divided by each end's mass: end a moves by (uax, uay), end b
 * by -(ubx, uby). */
ST_CLONES static void st_spring_terms_batch(
    int n, const double *restrict rx, const double *restrict ry,
    const double *restrict sn, const double *restrict cm1,
    const double *restrict l0, const double *restrict half_a,
    const double *restrict dx0, const double *restrict dy0,
    const double *restrict c0, const double *restrict s0,
    const double *restrict a_euc, const double *restrict a_car,
    const double *restrict wa, const double *restrict wb,
    double *restrict e_euc, double *restrict e_car,
    double *restrict uax, double *restrict uay, double *restrict ubx, double *restrict uby)
{
    for (int k = 0; k < n; k++) {
        double x = rx[k], y = ry[k];
        double l = sqrt(x * x + y * y);
        double dl = l - l0[k];                               /* eq. (10) */
        e_euc[k] = half_a[k] * (dl * dl);                    /* eq. (12) */
        double ex = x - dx0[k];                              /* eq. (18) */
        double ey = y - dy0[k];
        e_car[k] = half_a[k] * (ex * ex + ey * ey);          /* eq. (20) */
        /* eq. (11) direction r / l, or the rest direction when both ends coincide */
        int64_t pos = l > 0.0;
        double inv_l = 1.0 / st_sel(pos, l, 1.0);
        double cx = st_sel(pos, x * inv_l, c0[k]);
        double cy = st_sel(pos, y * inv_l, s0[k]);
        double g = a_euc[k] * dl;                            /* eq. (11) */
        /* eq. (16): l (cos(th + eps) - cos th) = rx (cos eps - 1) - ry sin eps, and for y;
         * eq. (19): a (r - r0) */
        double ux = (g * cx + (x * cm1[k] - y * sn[k])) + a_car[k] * ex;
        double uy = (g * cy + (y * cm1[k] + x * sn[k])) + a_car[k] * ey;
        uax[k] = ux * wa[k];
        uay[k] = uy * wa[k];
        ubx[k] = ux * wb[k];
        uby[k] = uy * wb[k];
    }
}

/* 1 where a tracker's exact gate box (half-widths sqrt(gate sxx), sqrt(gate syy) about its
 * mean (mx, my)) may no longer lie inside the box it is indexed with, else 0.  The test is
 * sufficient, not exact, and cheap: reindex() left slack for the mean to move by
 * (dev_x, dev_y) from the box centre (bcx, bcy) while the variances stay below
 * (sxx_lim, syy_lim); within both the gate box stays inside.  The kernel re-indexes a
 * tracker when this returns 1. */
static inline int64_t st_box_left(double mx, double my, double sxx, double syy, double bcx,
                                  double bcy, double dev_x, double dev_y, double sxx_lim,
                                  double syy_lim)
{
    return (fabs(mx - bcx) > dev_x) | (fabs(my - bcy) > dev_y) | (sxx > sxx_lim)
           | (syy > syy_lim);
}

/* out[i] = st_box_left(tracker i) for i < n (after a spring update moved them all) */
ST_CLONES static void st_boxes_left(int n, const double *restrict mx, const double *restrict my,
                                    const double *restrict sxx, const double *restrict syy,
                                    const double *restrict bcx, const double *restrict bcy,
                                    const double *restrict dev_x, const double *restrict dev_y,
                                    const double *restrict sxx_lim,
                                    const double *restrict syy_lim, int64_t *restrict out)
{
    for (int i = 0; i < n; i++)
        out[i] = st_box_left(mx[i], my[i], sxx[i], syy[i], bcx[i], bcy[i], dev_x[i], dev_y[i],
                             sxx_lim[i], syy_lim[i]);
}

/* lo = min, hi = max of x[0..n), n >= 1 (x < lo ? x : lo: the vector min's own rule) */
ST_CLONES static void st_bounds(int n, const double *restrict x, double *lo, double *hi)
{
    double a = x[0], b = x[0];
    for (int i = 1; i < n; i++) {
        a = x[i] < a ? x[i] : a;
        b = x[i] > b ? x[i] : b;
    }
    *lo = a;
    *hi = b;
}

#endif /* SPRINGTRACK_SPRINGS_H */
