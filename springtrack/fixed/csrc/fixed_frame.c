/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): the
   similarity frame (pull_frame, cartesian_frame = "similarity"): its fit, its refits
   weighted by how well each tracker agrees with it, and the targets and rest offsets in
   it. */

/* ---- the similarity frame (pull_frame, cartesian_frame = "similarity") --------------
   [ref] fit_frame.  Every product is a 32 x 32 -> 64-bit one (smul), every division an
   int64 by a divisor below 2^31 (div_round).  Formats: the means' offsets from the last
   frame's G and the rest offsets in 29 bits with one shift for the whole fit (Q.(32 -
   sh): Q.23 for a structure within +-128 px), their centroids and the offsets about those
   in the same Q, the fit's sums in that Q doubled less 8, masses in units of the largest;
   s R = [[c, -sn], [sn, c]] Q.28 (|c|, |sn| <= 4 < 8); G Q.32. */
#define FRAME_ONE ((int32_t)1 << 28)                  /* 1.0 in Q.28 */
#define FRAME_SCALE_MIN_Q ((int32_t)1 << 26)          /* [ref] FRAME_SCALE_MIN = 1/4, Q.28 */
#define FRAME_SCALE_MAX_Q ((int32_t)1 << 30)          /* [ref] FRAME_SCALE_MAX = 4, Q.28 */
#define FRAME_SPREAD_SHIFT 20                         /* [ref] FRAME_MIN_SPREAD = 2^-20 */
#define FRAME_REFITS 2                                /* [ref] FRAME_REFITS */
#define FRAME_AGREE_Q ((int64_t)1 << 30)              /* [ref] FRAME_AGREE_PX2 = 2^-4, Q.34 px^2 */
#define FRAME_W_ONE ((uint32_t)1 << 24)              /* a weight of 1, Q.24 */
#define FRAME_RAMP_SHIFT 1                            /* [ref] FRAME_RAMP = 2^-1 */

/* the index of the lowest set bit of m != 0 (on a 32-bit core from two 32-bit halves) */
static inline int lowest_bit(uint64_t m)
{
#if FX_WORD64
    return __builtin_ctzll(m);
#else
    uint32_t lo = (uint32_t)m;
    return lo ? __builtin_ctz(lo) : 32 + __builtin_ctz((uint32_t)(m >> 32));
#endif
}

/* floor(v / 2^sh) for 0 <= sh < 32 when it fits int32: on a 32-bit core from v's two
   words, in 32 bits ((hi 2) 2^(31 - sh): no shift by 32); the same bits as v >> sh */
static inline int32_t shr32(int64_t v, int sh)
{
#if FX_WORD64
    return (int32_t)(v >> sh);
#else
    return (int32_t)(((uint32_t)v >> sh) | (((uint32_t)(v >> 32) << 1) << (31 - sh)));
#endif
}

/* c v for c in Q.28 and v in Q.32, |v| < 2^46: v = hi 2^16 + lo, two 32 x 32 products,
   rounded to Q.32 (within 1 unit) */
static inline int64_t frame_scale(int32_t c, int64_t v)
{
    return rshr(smul(c, (int32_t)(v >> 16)), 12) + rshr(smul(c, (int32_t)(v & 0xffff)), 28);
}

/* (x, y) scaled to the length len (Q.28): x len / |(x, y)|, |x|, |y| < 2^30, not both 0 */
static inline void frame_to_length(int32_t x, int32_t y, int32_t len, int32_t *c, int32_t *sn)
{
    uint32_t r = (uint32_t)isqrt64((uint64_t)(smul(x, x) + smul(y, y)));   /* < 2^31 */
    *c = (int32_t)div_round(smul(x, len), r);
    *sn = (int32_t)div_round(smul(y, len), r);
}

/* The similarity x -> G + s R (x - G0) that best maps the rest shape onto the means, in
   the weighted least-squares sense (weights wq: mass / largest mass, times how well the
   tracker agrees, Q.24), over the trackers of `fit` (all if it holds fewer than 2; each
   with wq > 0): with p = dG0 - pbar, q = mu - qbar about the set's weighted centroids,
   a = sum m p.q, b = sum m p x q, D = sum m |p|^2, s R = [[a, -b], [b, a]] / D (the scale
   held to [1/4, 4]; s R = I when D <= 2^-20 sum m), G = qbar - s R pbar.  Sets frame_c,
   frame_s (Q.28) and frame_gx, frame_gy (Q.32). */
static __attribute__((noinline)) void fit_frame(fx_state *s, uint64_t fit, const uint32_t *wq)
{
    int n = s->n, i, sh;
    uint64_t all = n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << n) - 1, k2, m;
    const int64_t *gdx = s->gdx0, *gdy = s->gdy0, *mx = s->mx, *my = s->my;
    int32_t ux[FX_MAX_TRACKERS], uy[FX_MAX_TRACKERS], vx[FX_MAX_TRACKERS], vy[FX_MAX_TRACKERS];
    int32_t an, bn, dn, c, sn;
    int64_t ox[FX_MAX_TRACKERS], oy[FX_MAX_TRACKERS], W, spx = 0, spy = 0, sqx = 0, sqy = 0;
    uint32_t wsum = 0;
    int64_t px, py, qx, qy, a = 0, b = 0, d = 0, big = 0, lim;
    fit &= all;
    if ((fit & (fit - 1)) == 0)                       /* fewer than 2: all of them */
        fit = all;
    /* The sums run over the trackers of the fit only (weight wq, Q.24, > 0),
       visited in increasing order.  The means' offsets from the last frame's G (near
       qbar), the rest offsets (from G0), and one shift that puts their largest below
       2^29: their centroids and the offsets about those are then below 2^30 */
    for (m = fit; m; m &= m - 1) {                    /* x ^ (x >> 63): |x| or |x| - 1 */
        i = lowest_bit(m);
        ox[i] = mx[i] - s->frame_gx;
        oy[i] = my[i] - s->frame_gy;
        big |= (gdx[i] ^ (gdx[i] >> 63)) | (gdy[i] ^ (gdy[i] >> 63)) | (ox[i] ^ (ox[i] >> 63))
               | (oy[i] ^ (oy[i] >> 63));
    }
    sh = bitlen64((uint64_t)big) - 29;                /* |.| >> sh <= 2^29; sh < 24 (|G| < 2^51) */
    if (sh < 0)
        sh = 0;
    for (m = fit; m; m &= m - 1) {                    /* weighted centroids, Q.(32 - sh) */
        int32_t w;
        i = lowest_bit(m);
        w = (int32_t)wq[i];
        ux[i] = shr32(gdx[i], sh);
        uy[i] = shr32(gdy[i], sh);
        vx[i] = shr32(ox[i], sh);
        vy[i] = shr32(oy[i], sh);
        wsum += (uint32_t)w;                          /* <= 2^30 */
        spx = smla(spx, w, ux[i]);                    /* < 2^53 each */
        spy = smla(spy, w, uy[i]);
        sqx = smla(sqx, w, vx[i]);
        sqy = smla(sqy, w, vy[i]);
    }
    W = wsum;
    px = div_round(spx, (uint32_t)W);                 /* pbar, about G0 */
    py = div_round(spy, (uint32_t)W);
    qx = div_round(sqx, (uint32_t)W);                 /* qbar, about the last G */
    qy = div_round(sqy, (uint32_t)W);
    for (m = fit; m; m &= m - 1) {                    /* p, q: below 2^30 */
        int32_t pux, puy, qvx, qvy, mux, muy;
        i = lowest_bit(m);
        pux = ux[i] - (int32_t)px;
        puy = uy[i] - (int32_t)py;
        qvx = vx[i] - (int32_t)qx;
        qvy = vy[i] - (int32_t)qy;
        mux = pux;                                    /* m p: exactly p for a weight of 1 */
        muy = puy;
        if (wq[i] != FRAME_W_ONE) {
            mux = (int32_t)rshr(smul((int32_t)wq[i], pux), 24);
            muy = (int32_t)rshr(smul((int32_t)wq[i], puy), 24);
        }
        /* products < 2^60, pairs < 2^61: a 2^-8 of each keeps 64 of them in int64 */
        a += smla(smul(mux, qvx), muy, qvy) >> 8;     /* a = sum m p.q */
        b += smla(smul(mux, qvy), -muy, qvx) >> 8;    /* b = sum m p x q */
        d += smla(smul(mux, pux), muy, puy) >> 8;     /* D = sum m |p|^2 */
    }
    px = shl64(px, sh);                               /* Q.32 */
    py = shl64(py, sh);
    qx = s->frame_gx + shl64(qx, sh);
    qy = s->frame_gy + shl64(qy, sh);
    /* D <= 2^-20 sum m, with D in Q.(56 - 2 sh) px^2 and sum m (W) in Q.24:
       D <= W 2^(56 - 2 sh - 24 - 20) */
    sh = 32 - FRAME_SPREAD_SHIFT - 2 * sh;
    lim = sh >= 0 ? shl64(W, sh) : W >> -sh;
    if (d <= lim) {                                   /* no rotation to tell */
        c = FRAME_ONE;
        sn = 0;
    } else {
        /* a, b, D to 30 bits with one shift: s R = [[a, -b], [b, a]] / D unchanged */
        big = d;
        if ((a < 0 ? -a : a) > big)
            big = a < 0 ? -a : a;
        if ((b < 0 ? -b : b) > big)
            big = b < 0 ? -b : b;
        sh = bitlen64((uint64_t)big) - 30;
        if (sh < 0)
            sh = 0;
        an = (int32_t)(a >> sh);
        bn = (int32_t)(b >> sh);
        dn = (int32_t)(d >> sh);
        k2 = (uint64_t)(smul(an, an) + smul(bn, bn));              /* s^2 D^2, < 2^61 */
        if (dn > 0 && k2 <= (uint64_t)smul(dn, dn) << 4) {         /* s <= 4 */
            if (k2 >= ((uint64_t)1 << 60) || k2 << 4 >= (uint64_t)smul(dn, dn)) {
                c = (int32_t)div_round(smul(an, FRAME_ONE), (uint32_t)dn);   /* s R = [[a, -b], */
                sn = (int32_t)div_round(smul(bn, FRAME_ONE), (uint32_t)dn);  /*     [b, a]] / D */
            } else if (k2 > 0) {                                    /* s < 1/4: held */
                frame_to_length(an, bn, FRAME_SCALE_MIN_Q, &c, &sn);
            } else {                                                /* no rotation to keep */
                c = FRAME_SCALE_MIN_Q;
                sn = 0;
            }
        } else {                                                    /* s > 4: held */
            frame_to_length(an, bn, FRAME_SCALE_MAX_Q, &c, &sn);
        }
    }
    s->frame_c = c;
    s->frame_s = sn;
    s->frame_gx = qx - (frame_scale(c, px) - frame_scale(sn, py));   /* G = qbar - s R pbar */
    s->frame_gy = qy - (frame_scale(sn, px) + frame_scale(c, py));
}

/* eq. (22)'s target of tracker i in the frame: G + s R dG0_i, Q.32 */
static inline void frame_target(const fx_state *s, int i, int64_t *tx, int64_t *ty)
{
    *tx = s->frame_gx + (frame_scale(s->frame_c, s->gdx0[i]) - frame_scale(s->frame_s, s->gdy0[i]));
    *ty = s->frame_gy + (frame_scale(s->frame_s, s->gdx0[i]) + frame_scale(s->frame_c, s->gdy0[i]));
}

/* [ref] fit_frame's weights: for the trackers of `fit`, the squared residual r^2 =
   |mu - (G + s R dG0)|^2 in the last fitted frame, T = max(energy_scale times the mean r^2
   weighted by wq, FRAME_AGREE_PX2), and v = 1 up to T, 0 from (1 + FRAME_RAMP) T, linear
   between (Q.24).
   Residuals in Q.20 px (the kernels' means agree to ~1e-6 px, so a weight near the ends
   of its ramp comes out as the float kernel's), held to +-2^30 (1024 px: such a tracker
   disagrees either way), r^2 in Q.40 px^2 (< 2^61) and 2^-6 of it (Q.34) summed (64 of
   them in int64), each weighted by wq (Q.24); the mean = sum 2^24 / sum wq.  If some v
   differs from the last and at least 2 weights are positive: v and wq = mq v updated and
   the mask of the positive weights returned; else 0 (both unchanged). */
static __attribute__((noinline)) uint64_t frame_weights(fx_state *s, uint64_t fit, uint32_t *v,
                                                        uint32_t *wq)
{
    uint64_t m, pos = 0;
    int64_t r2[FX_MAX_TRACKERS], total = 0, mean, thr, ramp;
    uint32_t W = 0, rem, nv[FX_MAX_TRACKERS], nw[FX_MAX_TRACKERS];
    const int64_t lim = (int64_t)1 << 30;
    int i, k, changed = 0;
    for (m = fit; m; m &= m - 1) {
        int64_t tx, ty, ex, ey;
        i = lowest_bit(m);
        frame_target(s, i, &tx, &ty);
        ex = rshr(s->mx[i] - tx, 12);                 /* mu - (G + s R dG0), Q.20 */
        ey = rshr(s->my[i] - ty, 12);
        ex = ex > lim ? lim : ex < -lim ? -lim : ex;
        ey = ey > lim ? lim : ey < -lim ? -lim : ey;
        r2[i] = smla(smul((int32_t)ex, (int32_t)ex), (int32_t)ey, (int32_t)ey) >> 6;
        total += wq[i] == FRAME_W_ONE ? r2[i] : mulsh(r2[i], wq[i], 24);   /* r^2 wq / 2^24 */
        W += wq[i];                                   /* <= 2^30 */
    }
    /* the weighted mean r^2 (Q.34 px^2): sum 2^24 / sum wq in two steps */
    mean = (int64_t)udiv64((uint64_t)total, W, &rem);
    mean = shl64(mean, 24) + (int64_t)udiv64((uint64_t)rem << 24, W, &rem);
    thr = mulsh(mean, s->escale, s->escale_sh);       /* eq. (21)'s test on r^2 */
    if (thr < FRAME_AGREE_Q)
        thr = FRAME_AGREE_Q;
    ramp = thr >> FRAME_RAMP_SHIFT;                   /* FRAME_RAMP T, >= 2^29 */
    k = bitlen64((uint64_t)ramp) - 31;                /* ramp >> k in [2^29, 2^31) */
    if (k < 0)
        k = 0;
    for (m = fit; m; m &= m - 1) {
        int64_t e;
        i = lowest_bit(m);
        e = r2[i] - thr;
        if (e <= 0)                                   /* 1 up to T */
            nv[i] = FRAME_W_ONE;
        else if (e >= ramp)                           /* 0 from (1 + ramp) T */
            nv[i] = 0;
        else                                          /* 1 - (r^2 - T) / (ramp T) */
            nv[i] = FRAME_W_ONE - (uint32_t)div_round(shl64(e >> k, 24), (uint32_t)(ramp >> k));
        nw[i] = nv[i] == FRAME_W_ONE ? s->mq[i]                       /* mq v / 2^24 */
                                     : (uint32_t)rshr((int64_t)umul(s->mq[i], nv[i]), 24);
        changed |= nv[i] != v[i];
        pos |= (uint64_t)(nw[i] > 0) << i;
    }
    if (!changed || (pos & (pos - 1)) == 0)           /* unchanged, or fewer than 2 left */
        return 0;
    for (m = fit; m; m &= m - 1) {
        i = lowest_bit(m);
        v[i] = nv[i];
        wq[i] = nw[i];
    }
    return pos;
}

/* [ref] fit_frame: the frame fitted to `fit` (all if it holds fewer than 2), then refitted
   up to FRAME_REFITS times weighted by how well each tracker agrees with it
   (frame_weights); dis[i] = how much tracker i disagrees (1 - v, Q.24), 0 outside the
   fit.  No refit when energy_scale >= nc (escale_never: the reference tests no tracker
   then). */
static void fit_frame_agreeing(fx_state *s, uint64_t fit, uint32_t *dis)
{
    uint64_t all = s->n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << s->n) - 1, pos;
    uint32_t v[FX_MAX_TRACKERS], wq[FX_MAX_TRACKERS];
    int i;
    fit &= all;
    if ((fit & (fit - 1)) == 0)
        fit = all;
    for (i = 0; i < s->n; i++) {
        v[i] = FRAME_W_ONE;
        wq[i] = s->mq[i];
        dis[i] = 0;
    }
    fit_frame(s, fit, wq);
    if (s->escale_never)
        return;
    for (int r = 0; r < FRAME_REFITS; r++) {
        pos = frame_weights(s, fit, v, wq);
        if (pos == 0)
            break;
        fit_frame(s, pos, wq);
    }
    for (uint64_t m = fit; m; m &= m - 1) {
        i = lowest_bit(m);
        dis[i] = FRAME_W_ONE - v[i];
    }
}

/* eq. (18)'s rest offset of connection k in the frame the Cartesian springs use (car_c,
   car_s: the frame fitted at the update before): s R (dx0, dy0), Q.32 */
static inline void frame_offset(const fx_state *s, int k, int64_t *ox, int64_t *oy)
{
    *ox = frame_scale(s->car_c, s->dx0[k]) - frame_scale(s->car_s, s->dy0[k]);
    *oy = frame_scale(s->car_s, s->dx0[k]) + frame_scale(s->car_c, s->dy0[k]);
}
