/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): the springs
   of one connection: lengths, angles, offsets, forces and energies of the three kinds
   (eqs. 7-20), and the batched passes over the connections. */

/* ---- springs and energy criteria (every `period` events) -----------------------------
   The criteria of eqs. (21)-(22) compare each connection's energy with s times their mean:
   a decision taken the other way than by the float64 kernel moves a tracker by up to
   energy_gain times its distance to its target, so the energies are computed to about
   1e-9 px of the exact ones of the kernel's own positions (dl and the Cartesian offsets
   e in Q.32 from the Q.32 spring vectors and rest geometry; energies Q.40), while the
   spring geometry that only sets directions and angles stays Q.16. */
#define OFFSET_LIM ((int32_t)1 << 30)                     /* 16384 px in Q.16 */
#define FINE_LIM ((int64_t)1 << 38)                       /* 64 px in Q.32: Q.24 fits int32 */

static inline int32_t clamp_offset(int64_t v)
{
    return (int32_t)(v >= OFFSET_LIM ? OFFSET_LIM - 1 : (v <= -OFFSET_LIM ? -OFFSET_LIM + 1 : v));
}

/* |v| < 64 px (Q.32): then v is taken in Q.24 (int32) */
static inline int fine(int64_t v)
{
    return v < FINE_LIM && v > -FINE_LIM;
}

static inline void frame_offset(const fx_state *s, int k, int64_t *ox, int64_t *oy);

/* the offsets e = r - d0 of eq. (18) of connection k (Q.32) from its spring vector r
   (Q.32).  The rest offset d0 is (dx0, dy0), or s R (dx0, dy0) (frame_offset) if the
   spring update computing the energies used the similarity frame. */
static inline void offsets(const fx_state *s, int k, int64_t rx, int64_t ry, int64_t *ex,
                           int64_t *ey)
{
    int64_t ox = s->dx0[k], oy = s->dy0[k];
    if (s->car_turned)
        frame_offset(s, k, &ox, &oy);
    *ex = rx - ox;                                        /* |.| < 2^50 */
    *ey = ry - oy;
}

/* an offset beyond 64 px in Q.16, clamped to +-16384 px */
static inline int32_t offset16(int64_t e)
{
    return clamp_offset(rshr(e, 16));
}

/* how many of the offsets (Q.32) offset16 clamps */
static inline int clamped(int64_t ex, int64_t ey)
{
    const int64_t lim = shl64(OFFSET_LIM, 16) - ((int64_t)1 << 15);   /* rshr reaches 2^30 */
    return (ex >= lim || ex < -lim) + (ey >= lim || ey < -lim);
}

/* eq. (10): dl = l - l0 (Q.32) of connection k from its spring vector r (Q.32) and the
   direction c = (cx, cy) (Q.30) of the spring geometry, l~ its length (Q.16).  The tables
   give c within ~2e-7 of unit length (|c| = 1 + eps), in the direction of r's Q.16
   rounding (an angle a < 2^-17 px / l), so l = r.c / |c| = r.c (3 - |c|^2) / 2 to
   O(eps^2 + a^2) (< 1e-11 px for l >= 0.1 px), without a division: r.c from the high 16.16
   halves h of r and the 16-bit rests (r = h 2^16 + e; Q.46, |.| < 2^61), |c|^2 in Q.60,
   the factor (3 - |c|^2) / 2 in Q.30 and one mulsh. */
static inline __attribute__((always_inline)) int64_t spring_dl(const fx_state *s, int k,
                                                               int64_t rx, int64_t ry, int32_t l,
                                                               int32_t cx, int32_t cy)
{
    int32_t hx = (int32_t)(rx >> 16), hy = (int32_t)(ry >> 16);      /* |.| < 2^30 */
    int32_t ex = (int32_t)(rx & 0xffff), ey = (int32_t)(ry & 0xffff);
    int64_t dot, cc;
    uint32_t f;
    if (l <= 0)                                           /* |r| < 2^-16 px */
        return -s->l0[k];
    dot = smla(smla(smla(smul(ex, cx), ey, cy) >> 16, hx, cx), hy, cy);   /* Q.46 */
    cc = smla(smul(cx, cx), cy, cy);                      /* |c|^2, Q.60 (< 2^61) */
    f = (uint32_t)((((int64_t)3 << 60) - cc) >> 31);      /* (3 - |c|^2) / 2, Q.30 */
    return mulsh(dot, f, 44) - s->l0[k];                  /* Q.46 x Q.30 / 2^44 = Q.32 */
}

/* eq. (11): the Euclidean force a dl r / l (Q.32) of connection k, from dl (Q.32) and the
   direction (cx, cy) (Q.30): a dl in Q.30 when |a dl| < 2 px (single products), else from
   dl in Q.16 */
static inline __attribute__((always_inline)) void euclid_force(const fx_state *s, int k,
                                                               int64_t dl, int32_t cx,
                                                               int32_t cy, int64_t *fx,
                                                               int64_t *fy)
{
    int32_t a = (int32_t)s->stiff[k], d;
    if (fine(dl)) {
        int64_t adl = smul((int32_t)rshr(dl, 8), a);      /* Q.24 x Q.30 = Q.54 */
        if (adl < ((int64_t)1 << 55) && adl > -((int64_t)1 << 55)) {
            int32_t q = (int32_t)rshr(adl, 24);           /* a dl, Q.30 */
            *fx = rshr(smul(q, cx), 28);
            *fy = rshr(smul(q, cy), 28);
            return;
        }
    }
    d = clamp_offset(rshr(dl, 16));                       /* Q.16 (|dl| < 16384 px) */
    *fx = mulsh(rshr(smul(d, cx), 14), (uint32_t)a, 30);  /* dl r / l, Q.32, times a */
    *fy = mulsh(rshr(smul(d, cy), 14), (uint32_t)a, 30);
}

/* a |d|^2 / 2 in Q.40 for the squared length q of d in Q.32 px^2 (offsets beyond 64 px):
   beyond 2^21 px^2 it is E_MAX (the caller counts it) */
static inline int64_t energy_wide(const fx_state *s, int k, int64_t q)
{
    int64_t e = mulsh(q, s->stiff[k], 31);                /* Q.32, < 2^61 */
    return e >= ((int64_t)1 << 53) ? E_MAX + 1 : shl64(e, 8);
}

/* energies of connection k (Q.40): eq. (12) a dl^2 / 2 from dl (Q.32); eq. (17) a dtheta^2
   / 2 from the corrected angle (binary); eq. (20) a |e|^2 / 2 from the offsets (Q.32),
   each from Q.24 values (products < 2^62) below 64 px */
static inline int64_t energy_euclid(const fx_state *s, int k, int64_t dl)
{
    int32_t d;
    if (fine(dl)) {
        d = (int32_t)rshr(dl, 8);                         /* Q.24 */
        return mulsh(smul(d, d), s->stiff[k], 39);        /* Q.48 x Q.30 / 2^39 = Q.40 */
    }
    d = clamp_offset(rshr(dl, 16));
    return energy_wide(s, k, smul(d, d));
}

static inline int64_t energy_torsion(const fx_state *s, int k, int64_t dth)
{
    int32_t dq = (int32_t)mulsh(dth, PI_Q28, 31);         /* radians, Q.28; |.| < 2^31 */
    return mulsh(smul(dq, dq), s->stiff[k], 47);          /* Q.56 x Q.30 / 2^47 = Q.40 */
}

static inline int64_t energy_cart(const fx_state *s, int k, int64_t ex, int64_t ey)
{
    int32_t x, y;
    if (fine(ex) && fine(ey)) {
        x = (int32_t)rshr(ex, 8);                         /* Q.24 */
        y = (int32_t)rshr(ey, 8);
        return mulsh(smla(smul(x, x), y, y), s->stiff[k], 39);
    }
    x = offset16(ex);
    y = offset16(ey);
    return energy_wide(s, k, smla(smul(x, x), y, y));
}

/* eq. (19): the Cartesian force a e (Q.32) of connection k */
static inline void cart_force(const fx_state *s, int k, int64_t ex, int64_t ey, int64_t *fx,
                              int64_t *fy)
{
    int32_t a = (int32_t)s->stiff[k];
    if (fine(ex) && fine(ey)) {                           /* Q.24 x Q.30 -> Q.32 */
        *fx = rshr(smul((int32_t)rshr(ex, 8), a), 22);
        *fy = rshr(smul((int32_t)rshr(ey, 8), a), 22);
    } else {                                              /* Q.16 x Q.30 -> Q.32 */
        *fx = rshr(smul(offset16(ex), a), 14);
        *fy = rshr(smul(offset16(ey), a), 14);
    }
}

/* Eq. (14) and the polar form of a spring vector r (Q.16), in two steps so that the spring
   pass can issue all the divisions first (they then overlap).  In the connection's rest
   frame, (u, v) = (c0 . r, c0 x r) rounded to Q.18 (finer than r, so that this rotation
   adds no error of note), with c0 = (cos th0, sin th0) (Q.30): when |v| <= u < 2^31 (r
   within 45 degrees of its rest direction, the usual case) the angle from rest is atan(t),
   t = |v| / u (Q.28, 2 zero bits added), the direction r / |r| is c0 rotated by it, and
   |r| = u cos + |v| sin of it, from the tables of atan and 1 / sqrt(1 + t^2); otherwise the
   polar form of r itself minus th0, wrapped to [-pi, pi).  Both: one division. */
typedef struct {
    uint32_t t;
    int32_t u, v;                                         /* u <= 0: polar form, octant -u */
} spring_ratio;

static inline __attribute__((always_inline)) spring_ratio geom_ratio(const fx_state *s, int k,
                                                                     int32_t rx, int32_t ry)
{
    spring_ratio g;
    int64_t u = rshr(smla(smul(s->c0x[k], rx), s->c0y[k], ry), 28);   /* Q.18, < 2^33 */
    int64_t v = rshr(smla(smul(s->c0x[k], ry), -s->c0y[k], rx), 28);   /* |c0y| <= 2^30 */
    int64_t av = v < 0 ? -v : v;
    int oct;
    if (u > 0 && av <= u && u < ((int64_t)1 << 31)) {
        uint32_t rem;
        g.u = (int32_t)u;
        g.v = (int32_t)v;
        g.t = divlu((uint32_t)av >> 4, (uint32_t)av << 28, (uint32_t)u, &rem) << 2;  /* [0, 2^30] */
        return g;
    }
    g.t = polar_ratio(rx, ry, &g.v, &oct);                /* v = max(|x|, |y|) */
    g.u = -oct;                                           /* <= 0: the octant */
    return g;
}

/* the angle from rest (binary angle, [-pi, pi)), the length (Q.16) and direction (Q.30) */
static inline __attribute__((always_inline)) int32_t geom_finish(const fx_state *s, int k,
                                                                 spring_ratio g, int32_t *l,
                                                                 int32_t *cx, int32_t *cy)
{
    if (g.u > 0) {
        int32_t a = unit_interp(FX_ATAN_TAB, g.t);
        int32_t h = unit_interp(FX_IHYP_TAB, g.t);        /* cos of the angle */
        int32_t sn = (int32_t)rshr((int64_t)umul(g.t, (uint32_t)h), 30);   /* |sin| */
        int32_t sg = g.v >> 31;                           /* -1 if v < 0: a mask, the sign */
        *l = (int32_t)rshr(smla(smul(g.u, h), (g.v ^ sg) - sg, sn), 32);   /* of a spring is */
        a = (a ^ sg) - sg;                                /* data the branch predictor */
        sn = (sn ^ sg) - sg;                              /* cannot learn */
        *cx = (int32_t)rshr(smla(smul(s->c0x[k], h), -s->c0y[k], sn), 30);
        *cy = (int32_t)rshr(smla(smul(s->c0y[k], h), s->c0x[k], sn), 30);
        return a;
    } else {
        uint32_t th;
        polar_finish(g.t, g.v, -g.u, &th, l, cx, cy);
        return (int32_t)(th - s->th0[k]);                 /* mod 2^32 = mod 2 pi */
    }
}

static inline int32_t spring_angle(const fx_state *s, int k, int32_t rx, int32_t ry, int32_t *l,
                                   int32_t *cx, int32_t *cy)
{
    return geom_finish(s, k, geom_ratio(s, k, rx, ry), l, cx, cy);
}

static inline int64_t sat_energy_of(fx_state *s, int64_t e)
{
    if (e > E_MAX) {
        s->sat_energy++;
        return E_MAX;
    }
    return e;
}

/* r = x_j - x_i of connection k, Q.32, |.| < 2^46 */
static inline void spring_vector(const fx_state *s, int k, int64_t *rx, int64_t *ry)
{
    int i = s->ca[k], j = s->cb[k];
    *rx = s->mx[j] - s->mx[i];
    *ry = s->my[j] - s->my[i];
}

/* a spring vector (Q.32) in the spring geometry's Q.16, |.| < 2^30 */
static inline int32_t geom16(int64_t r)
{
    return (int32_t)rshr(r, 16);
}

/* Eqs. (10)-(20) for every connection: the forces summed per tracker into ddx, ddy (Q.32)
   and the criterion's energy (eq. 13: each and their sum saturating at 2^21 px^2), which
   is returned.  `used` = the kinds whose geometry the model needs (its springs' kinds and
   the criterion's); each instantiation below contains only that geometry.
   Structure of arrays, one short step per pass: the connections are independent, and a
   pass whose iterations are short lets an out-of-order processor overlap many of them (a
   32-bit in-order core does the first two passes as one). */
static inline __attribute__((always_inline)) int64_t spring_passes(fx_state *s, const int used,
                                                                   int64_t *ddx, int64_t *ddy)
{
    int nc = s->nc, ek = s->ekind, k, sat = 0;
    int64_t fx[FX_MAX_CONNECTIONS], fy[FX_MAX_CONNECTIONS];
#if FX_KEEP_ANGLES
    int32_t *dth = s->dth;                                /* kept for fx_energies */
#else
    int32_t dth[FX_MAX_CONNECTIONS];
#endif
    int64_t total = 0, mean_dth = 0;
    int64_t *en = s->energy[ek];
    int64_t *grx = s->grx, *gry = s->gry;
    if (used & 3) {
        int64_t sum = 0;
        spring_ratio g[FX_MAX_CONNECTIONS];
#if FX_WORD64
        /* an out-of-order host: r and all the divisions first, so that they overlap */
        for (k = 0; k < nc; k++) {
            spring_vector(s, k, &grx[k], &gry[k]);
            g[k] = geom_ratio(s, k, geom16(grx[k]), geom16(gry[k]));
        }
#endif
        for (k = 0; k < nc; k++) {
            int32_t l, cx, cy;
#if !FX_WORD64
            /* an in-order core: one pass (the same operations per connection) */
            spring_vector(s, k, &grx[k], &gry[k]);
            g[k] = geom_ratio(s, k, geom16(grx[k]), geom16(gry[k]));
#endif
            dth[k] = geom_finish(s, k, g[k], &l, &cx, &cy);   /* eq. (14) */
            sum += dth[k];
            fx[k] = fy[k] = 0;
            if (used & 1) {
                int64_t dl = spring_dl(s, k, grx[k], gry[k], l, cx, cy);   /* eq. (10) */
                if (s->kinds[k] & 1) {                    /* eq. (11): a dl (r / l) */
                    if (l <= 0) {
                        cx = s->c0x[k];
                        cy = s->c0y[k];
                    }
                    euclid_force(s, k, dl, cx, cy, &fx[k], &fy[k]);
                }
                if (ek == 0) {                            /* eq. (12), the criterion's */
                    en[k] = sat_energy_of(s, energy_euclid(s, k, dl));
                    total = sat_add(s, total, en[k], E_MAX);
                }
            }
        }
        if ((used & 2) && nc > 0)
            mean_dth = div_round(sum, (uint32_t)nc);      /* eq. (15) */
#if FX_KEEP_ANGLES
        s->mean_dth = mean_dth;
#endif
    } else {
        for (k = 0; k < nc; k++) {                        /* r = x_j - x_i, Q.32 */
            spring_vector(s, k, &grx[k], &gry[k]);
            fx[k] = fy[k] = 0;
        }
    }
    for (k = 0; k < nc; k++) {
        int i = s->ca[k], j = s->cb[k], kind = s->kinds[k];
        int64_t d = 0, gx = fx[k], gy = fy[k], ex = 0, ey = 0;
        uint32_t a = s->stiff[k];
        if (used & 2) {
            d = dth[k] - mean_dth;                        /* eq. (15), binary angle */
            if (kind & 2) {                               /* eq. (16): rotate r by a d */
                int32_t c, sn, rx = geom16(grx[k]), ry = geom16(gry[k]);
                rotation(mulsh(d, a, 30), &c, &sn);       /* cos - 1, sin */
                gx += rshr(smla(smul(rx, c), -ry, sn), 14);   /* l (cos(th + a d) - cos th), Q.32 */
                gy += rshr(smla(smul(rx, sn), ry, c), 14);    /* (|ry| < 2^30) */
            }
        }
        if (used & 4) {
            offsets(s, k, grx[k], gry[k], &ex, &ey);      /* eq. (18) */
            sat += clamped(ex, ey);
            if (kind & 4) {                               /* eq. (19): a e */
                int64_t cxf, cyf;
                cart_force(s, k, ex, ey, &cxf, &cyf);
                gx += cxf;
                gy += cyf;
            }
        }
        ddx[i] += gx;                                     /* onto both ends */
        ddy[i] += gy;
        ddx[j] -= gx;
        ddy[j] -= gy;
        if (ek != 0) {                                    /* the criterion's energy */
            en[k] = sat_energy_of(s, (used & 2) && ek == 1 ? energy_torsion(s, k, d)  /* (17) */
                                                           : energy_cart(s, k, ex, ey));  /* (20) */
            total = sat_add(s, total, en[k], E_MAX);
        }
    }
    s->sat_energy += sat;
    return total;
}

/* one function per set of used kinds (1..7), each compiled with only that geometry */
#define SPRING_PASSES(u)                                                                   \
    static __attribute__((noinline)) int64_t spring_passes_##u(fx_state *s, int64_t *ddx,  \
                                                               int64_t *ddy)               \
    {                                                                                      \
        return spring_passes(s, u, ddx, ddy);                                              \
    }
SPRING_PASSES(1)
SPRING_PASSES(2)
SPRING_PASSES(3)
SPRING_PASSES(4)
SPRING_PASSES(5)
SPRING_PASSES(6)
SPRING_PASSES(7)
static int64_t (*const spring_passes_of[8])(fx_state *, int64_t *, int64_t *) = {
    spring_passes_7, spring_passes_1, spring_passes_2, spring_passes_3,
    spring_passes_4, spring_passes_5, spring_passes_6, spring_passes_7};

/* x0 + sum m_i (x_i - x0) / sum m_i for Q.32 positions, rounded half up: the offsets are
   split into a Q.16 high part and 16 low bits so that every product is 32 x 32 and no sum
   exceeds 2^61, then recombined exactly (msum < 2^31). */
static int64_t centre(const fx_state *s, const int64_t *x, uint32_t msum)
{
    int64_t hi = 0, lo = 0, q;
    uint32_t r;
    int i;
    for (i = 0; i < s->n; i++) {
        int64_t d = x[i] - x[0];                          /* |.| < 2^46 */
        hi = smla(hi, (int32_t)s->mq[i], (int32_t)(d >> 16));   /* < 2^55 each */
        lo += (int64_t)umul(s->mq[i], (uint32_t)d & 0xffff);  /* < 2^41 each */
    }
    q = floor_div(hi, msum, &r);
    return x[0] + shl64(q, 16) + div_round(shl64(r, 16) + lo, msum);
}
