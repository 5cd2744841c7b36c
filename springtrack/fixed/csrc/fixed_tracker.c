/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): per tracker
   and per event: the clamped covariance and its inverse, d^2, the update of eqs. (3)-(6),
   and the per-event step of eq. (2) (fx_step, fx_steps). */

/* ---- per tracker --------------------------------------------------------------------- */

/* round(v / 2^k) of 0 < v < 2^62 into a mantissa, k >= 1 */
static inline int32_t mant(int64_t v, int k)
{
    return (int32_t)rshr(v, k);
}

/* [ref] _clamp_and_invert: sigma_x, sigma_y in [sigma_min, sigma_max], |rho| <= 0.99,
   then the inverse covariance of eq. (2) as three mantissas with the tracker's exponent,
   and the shifts that put a candidate's offset and d^2 in 32 bits.  One 64 / 32
   division (a reciprocal).

   Block scaling: a, b, c = sxx, sxy, syy >> sh with the larger variance in [2^30, 2^31),
   so sigma_big^2 is in [2^(sh-10), 2^(sh-9)) px^2 and every product below is 32 x 32.
   det = ac - b^2 = m 2^e with m in [2^30, 2^31); r = floor(2^61 / m); then ia = syy / det
   = c r 2^(-21 - sh - e) px^-2 (Q.40 covariances), and likewise ic, ib.  The mantissas
   are the high words ia_m = c r / 2^32 (max(a, c) r < 2^62, so max(ia_m, ic_m) <= 2^30
   and |ib2_m| = |2 b r / 2^32| < 2^31), with f = sh + e - 11 fraction bits.

   Offsets are taken as u = (Q.32 offset) >> osh, osh = max(2, ceil((sh - 1) / 2) + 1):
   |u| < 2^31 covers |offset| < 2^(osh-1) px >= 16 sigma_big (and >= 2 px), and an offset
   whose whole pixels reach 2^(osh-1) is clamped: then |offset| > 2^(osh-1) - 1 px >= 8
   sigma_big + 1 px and d^2 > 64 sigma_big^2 / (2 sigma_big^2) = 32, beyond any gate
   (<= 31), so clamping decides nothing.  d^2 (Q.27) = (sum of mantissa u u / 2^32
   terms) >> dsh, dsh = f + 5 - 2 osh, which is e - 8 or e - 7 <= 24; kept >= 1 so that the
   shift works on 32-bit words. */
static inline void refresh(fx_state *s, int i)
{
    int64_t sxx = s->sxx[i], syy = s->syy[i], sxy = s->sxy[i], big, p, bb, det;
    int32_t a, b, c, sh, e, osh, dsh, f;
    uint32_t m, r, rem;
    sxx = sxx < s->smin2 ? s->smin2 : (sxx > s->smax2 ? s->smax2 : sxx);
    syy = syy < s->smin2 ? s->smin2 : (syy > s->smax2 ? s->smax2 : syy);
    big = sxx > syy ? sxx : syy;
    sh = bitlen64((uint64_t)big) - 31;
    if (sh < 0)
        sh = 0;
    a = (int32_t)(sxx >> sh);
    c = (int32_t)(syy >> sh);
    if (sxy > big)                                        /* |sxy| <= max keeps b^2 < 2^62 */
        sxy = big;
    if (sxy < -big)
        sxy = -big;
    b = (int32_t)(sxy >> sh);
    p = smul(a, c);
    bb = smul(b, b);
    /* |rho| > 0.99: clamp (b^2 <= p - p / 32 < 0.99^2 p: certainly not, without the product) */
    if (bb > p - (p >> 5) && bb > mulsh(p, RHO2_Q30, 30)) {
        /* 0.99 sqrt(sxx syy) = 0.99 sqrt(a c) 2^sh, Q.40, 31 significant bits */
        int64_t lim = mulsh(shl64((int64_t)isqrt64((uint64_t)p), sh), RHO_Q30, 30);
        sxy = sxy < 0 ? -lim : lim;
        b = (int32_t)(sxy >> sh);
        bb = smul(b, b);
    }
    s->sxx[i] = sxx;
    s->sxy[i] = sxy;
    s->syy[i] = syy;
    det = p - bb;                                         /* > 0.0199 p */
    if (det <= 0) {                                       /* cannot happen: |rho| <= 0.99 */
        det = 1;
        s->sat_inverse++;
    }
    e = bitlen64((uint64_t)det) - 31;
    m = (uint32_t)(e >= 0 ? det >> e : shl64(det, -e));
    r = divlu((uint32_t)1 << 29, 0, m, &rem);            /* 2^61 / m in (2^30, 2^31] */
    if (r > 0x7fffffffu)
        r = 0x7fffffffu;
    f = sh + e - 11;                                      /* 21 + sh + e - 32 */
    osh = sh > 3 ? sh / 2 + 1 : 2;                        /* ceil((sh - 1) / 2) + 1, >= 2 */
    dsh = f + 5 - 2 * osh;                                /* <= 24 (e <= 31) */
    if (dsh >= 1) {                                       /* mantissas: the products' high words */
        s->ia[i] = (int32_t)((umul((uint32_t)c, r) + 0x80000000u) >> 32);
        s->ic[i] = (int32_t)((umul((uint32_t)a, r) + 0x80000000u) >> 32);
        s->ib2[i] = -(int32_t)((smul(b, (int32_t)r) + 0x40000000) >> 31);
    } else {                      /* sigma_x / sigma_y beyond ~290 only: fewer bits, dsh = 1 */
        s->ia[i] = mant((int64_t)umul((uint32_t)c, r), 33 - dsh);
        s->ic[i] = mant((int64_t)umul((uint32_t)a, r), 33 - dsh);
        s->ib2[i] = -mant(smul(b, (int32_t)r), 32 - dsh);
        dsh = 1;
    }
    s->osh[i] = (uint8_t)osh;
    s->dsh[i] = (uint8_t)dsh;
}

void fx_refresh(fx_state *s, int i)
{
    refresh(s, i);
}

/* floor((v 2^32 - m) / 2^sh) for a pixel v and a Q.32 position m, 2 <= sh <= 31, in 32-bit
   arithmetic: with m = h 2^32 + l and d = v - h, it is the floor of d 2^32 - l; when
   |d| >= 2^(sh-1) it is clamped to +-(2^31 - 1) (the clamp decides nothing, see refresh) */
static inline int32_t offset32(int32_t v, int64_t m, int sh)
{
    int32_t d = v - (int32_t)(m >> 32);
    uint32_t l = (uint32_t)m, lim = 1u << (sh - 1), lo, hi;
    if ((uint32_t)d + lim >= 2 * lim)
        return d < 0 ? -0x7fffffff : 0x7fffffff;
    lo = 0u - l;                                          /* d 2^32 - l = hi 2^32 + lo */
    hi = (uint32_t)d - (l != 0);
    return (int32_t)((lo >> sh) | (hi << (32 - sh)));     /* its floor by 2^sh: fits int32 */
}

/* Mahalanobis d^2 = ia dx^2 + ib2 dx dy + ic dy^2 (eq. 2), Q.27, saturated at 2^32 - 1,
   of pixel (x, y) from tracker i: five 32 x 32 products (|pa|, |pc| <= 2^29, |pb| <= 2^30,
   |q| < 2^62); rounding: 2^-24 of d^2 from the mantissas plus up to |u| + 2|v| units of q
   from the floors of pa, pb, pc (docs/fixed_point.md) */
static inline uint32_t qform_at(const fx_state *s, int i, int32_t x, int32_t y, int64_t mx,
                                int64_t my)
{
    int sh = s->osh[i];
    int32_t u = offset32(x, mx, sh), v = offset32(y, my, sh);
    int32_t pa = (int32_t)(smul(s->ia[i], u) >> 32);
    int32_t pb = (int32_t)(smul(s->ib2[i], u) >> 32);
    int32_t pc = (int32_t)(smul(s->ic[i], v) >> 32);
    int64_t q = smul(pa, u) + smul(pb + pc, v);
    int k = s->dsh[i];                                    /* 1 .. 24 */
    if (q <= 0)
        return 0;
#if FX_WORD64
    q >>= k;
    return q > (int64_t)D2_SAT ? D2_SAT : (uint32_t)q;
#else
    {                                                     /* the same in 32-bit words */
        uint32_t hi = (uint32_t)((uint64_t)q >> 32), lo = (uint32_t)q;
        if (hi >> k)                                      /* q >> k >= 2^32 */
            return D2_SAT;
        return (lo >> k) | (hi << (32 - k));
    }
#endif
}

/* d^2 about tracker i's mean (qform_at about another mean, eq. M1's prediction) */
static inline uint32_t qform(const fx_state *s, int i, int32_t x, int32_t y)
{
    return qform_at(s, i, x, y, s->mx[i], s->my[i]);
}

uint32_t fx_d2(const fx_state *s, int i, int32_t x, int32_t y)
{
    return qform(s, i, x, y);
}

/* [ref] _update: eqs. (2)-(6) for the winning tracker i; dx, dy Q.32 from the pre-update
   mean (|.| < 2^41 inside the gate), d2 Q.27. */
/* eq. (6) for tracker i taking an event at t with d^2 = d2 (Q.27); t becomes its last */
static inline __attribute__((always_inline)) void activity_step(fx_state *s, int i, int64_t t,
                                                              uint32_t d2)
{
    int64_t p = gauss(d2);                                /* eq. (2), Q.30 */
    int64_t act = mulsh(s->act[i], decay(s, t - s->tlast[i]), 30) + p * 4;  /* eq. (6) */
    if (act > ACT_MAX) {
        act = ACT_MAX;
        s->sat_activity++;
    }
    s->act[i] = act;
    s->tlast[i] = t;
}

/* eqs. (4)-(5) for tracker i from the event's offset (dx, dy) from the pre-update mean
   (Q.32), then the inverse covariance and the index */
static inline __attribute__((always_inline)) void covariance_step(fx_state *s, int i,
                                                                int64_t dx, int64_t dy)
{
    int32_t ex = (int32_t)rshr(dx, 12), ey = (int32_t)rshr(dy, 12);    /* Q.20 px, < 2^29 */
    /* eq. (4)-(5): S <- (1 - a2) S + g e e^T, e = (dx, dy); ex ex is Q.40 px^2 */
    s->sxx[i] = ema(s->sxx[i], smul(ex, ex), s->cov_gm, s->cov_am, s->cov_sh);
    s->sxy[i] = ema(s->sxy[i], smul(ex, ey), s->cov_gm, s->cov_am, s->cov_sh);
    s->syy[i] = ema(s->syy[i], smul(ey, ey), s->cov_gm, s->cov_am, s->cov_sh);
    refresh(s, i);
    check_index(s, i);
}

/* [ref] _update: eqs. (2)-(6) for the winning tracker i; dx, dy Q.32 from the pre-update
   mean (|.| < 2^41 inside the gate), d2 Q.27. */
static __attribute__((noinline)) void update_tracker(fx_state *s, int i, int64_t t, int64_t dx,
                                                   int64_t dy, uint32_t d2)
{
    activity_step(s, i, t, d2);
    /* eq. (3): m + round(a1 (u - m)) with 0 <= a1 <= 1 lies between m and the event u, both
       inside +-FX_POS_LIM: it cannot saturate */
    s->mx[i] += mulsh(dx, s->a1, 30);
    s->my[i] += mulsh(dy, s->a1, 30);
    covariance_step(s, i, dx, dy);
}

/* eqs. (M6) / (M6b) for tracker i after an event of polarity p with the residual (rx, ry)
   about its edge (eq. M4), the mean's gain K_p = gain */
static inline __attribute__((always_inline)) void half_offsets(fx_state *s, int i, int32_t p,
                                                             int64_t rx, int64_t ry,
                                                             uint32_t gain)
{
    uint32_t gh;
    if (s->c_h <= 0)
        return;
    gh = (uint32_t)((umul(s->c_h, gain) + (1u << 29)) >> 30);
    if (s->tau_ceil > 0) {                                /* eq. (M6): h += c_h K_p s r */
        int64_t hx = mulsh(rx, gh, 30), hy = mulsh(ry, gh, 30);
        s->hx[i] = clamp64(p ? s->hx[i] + hx : s->hx[i] - hx, s->h_max);
        s->hy[i] = clamp64(p ? s->hy[i] + hy : s->hy[i] - hy, s->h_max);
    } else {
        /* eq. (M6b): f += K (on - f), b = 4 f (1 - f) (Q.30, <= 1),
           h += c_h K (b s r - (1 - b) h) */
        int64_t f = (int64_t)s->fon[i], hx, hy;
        uint32_t b, nb;
        f += mulsh((p ? (int64_t)1 << 30 : 0) - f, gain, 30);
        s->fon[i] = (uint32_t)f;
        b = (uint32_t)(((uint64_t)f * (uint64_t)(((int64_t)1 << 30) - f)) >> 28);
        nb = (1u << 30) - b;
        hx = mulsh(rx, b, 30);
        hy = mulsh(ry, b, 30);
        hx = (p ? hx : -hx) - mulsh(s->hx[i], nb, 30);
        hy = (p ? hy : -hy) - mulsh(s->hy[i], nb, 30);
        s->hx[i] = clamp64(s->hx[i] + mulsh(hx, gh, 30), s->h_max);
        s->hy[i] = clamp64(s->hy[i] + mulsh(hy, gh, 30), s->h_max);
    }
}

/* [ref] _update with the motion model (eqs. M1-M7, fixed_motion.c) for the winning
   tracker i of an event of polarity p at pixel (x, y), its d^2 about the predicted mean
   given */
static __attribute__((noinline)) void update_moving(fx_state *s, int i, int64_t t, int32_t x,
                                                  int32_t y, uint32_t d2, int32_t p)
{
    int32_t lead = lead8(s, i, t), kv = 0;
    uint32_t gain = s->a1;                                /* eq. (3) */
    int64_t px, py, dx, dy, rx, ry;
    if (s->tau_ceil > 0)
        gain = kalman(s, i, t, &kv);                      /* eq. (M3), before t_k = t */
    activity_step(s, i, t, d2);
    px = s->mx[i] + ahead(s->vx[i], lead);                /* eq. (M1): the mean eq. (2) */
    py = s->my[i] + ahead(s->vy[i], lead);                /* gated the event about */
    s->tm[i] = t;
    dx = shl64(x, FX_POS_FRAC) - px;                      /* eq. (5): offset from the */
    dy = shl64(y, FX_POS_FRAC) - py;                      /* predicted mean */
    /* eq. (M4): the residual about the edge of the event's polarity, m^ + s h */
    rx = p ? dx - s->hx[i] : dx + s->hx[i];
    ry = p ? dy - s->hy[i] : dy + s->hy[i];
    /* eq. (M5): m = m^ + K_p r (eq. 3 when v = h = 0 and K_p = alpha1) */
    s->mx[i] = sat_pos(s, px + mulsh(rx, gain, 30));
    s->my[i] = sat_pos(s, py + mulsh(ry, gain, 30));
    half_offsets(s, i, p, rx, ry, gain);                  /* eq. (M6) or (M6b) */
    if (s->tau_ceil > 0)                                  /* eq. (M7): v += K_v r */
        set_velocity(s, i, (int32_t)clamp64(s->vx[i] + velocity_step(s, rx, kv), V_MAX),
                     (int32_t)clamp64(s->vy[i] + velocity_step(s, ry, kv), V_MAX));
    covariance_step(s, i, dx, dy);                        /* eqs. (4)-(5) about m^ */
}

/* update_moving at FX_MOTION_EDGES (tau_m = 0, every v = 0): eq. (M1)'s prediction adds
   zeros and the gain is alpha1, so they are left out (the same integers) */
static __attribute__((noinline)) void update_edges(fx_state *s, int i, int64_t t, int32_t x,
                                                 int32_t y, uint32_t d2, int32_t p)
{
    int64_t dx, dy, rx, ry;
    activity_step(s, i, t, d2);
    s->tm[i] = t;
    dx = shl64(x, FX_POS_FRAC) - s->mx[i];                /* eq. (5) */
    dy = shl64(y, FX_POS_FRAC) - s->my[i];
    rx = p ? dx - s->hx[i] : dx + s->hx[i];               /* eq. (M4) */
    ry = p ? dy - s->hy[i] : dy + s->hy[i];
    s->mx[i] = sat_pos(s, s->mx[i] + mulsh(rx, s->a1, 30));   /* eq. (M5), K_p = alpha1 */
    s->my[i] = sat_pos(s, s->my[i] + mulsh(ry, s->a1, 30));
    half_offsets(s, i, p, rx, ry, s->a1);                 /* eq. (M6b) */
    covariance_step(s, i, dx, dy);                        /* eqs. (4)-(5) */
}

/* eq. (2) for candidate i: it becomes the best if its d^2 is below the best so far; with
   velocities (`moving` FX_MOTION_FULL, a constant in the callers) about its mean predicted
   to t (eq. M1) */
static inline __attribute__((always_inline)) void candidate(const fx_state *s, int i, int32_t x,
                                                            int32_t y, uint32_t *best_d2,
                                                            int *best, int64_t t, int moving)
{
    uint32_t d2;
    if (moving == FX_MOTION_FULL) {
        int32_t lead = lead8(s, i, t);
        d2 = qform_at(s, i, x, y, s->mx[i] + ahead(s->vx[i], lead),
                      s->my[i] + ahead(s->vy[i], lead));
    } else {
        d2 = qform(s, i, x, y);
    }
    if (d2 < *best_d2) {
        *best_d2 = d2;
        *best = i;
    }
}

/* eq. (2) for one valid event at pixel (x, y): the sensitive trackers indexed in the
   event's cell (mask), in index order, so ties resolve as in the reference's full scan.
   Returns the best tracker within the gate (its d^2 in *best_d2, which holds the gate on
   entry) or FX_NO_TRACKER. */
static inline __attribute__((always_inline)) int search(const fx_state *s, uint64_t mask,
                                                        int32_t x, int32_t y, uint32_t *best_d2,
                                                        int64_t t, int moving)
{
    uint64_t m = s->cells[(y >> FX_CELL_SHIFT) * s->gw + (x >> FX_CELL_SHIFT)] & mask;
    int best = FX_NO_TRACKER;
#if FX_WORD64
    while (m) {                                           /* index order: ties as the reference */
        int i = __builtin_ctzll(m);
        m &= m - 1;
        candidate(s, i, x, y, best_d2, &best, t, moving);
    }
#else
    /* the mask's 32-bit halves in turn (low bits first: the same order), and a build for
       at most 32 trackers has only the first */
    int half;
    for (half = 0; half < (FX_MAX_TRACKERS > 32 ? 2 : 1); half++) {
        uint32_t w = (uint32_t)(m >> (32 * half));
        while (w) {
            int i = __builtin_ctz(w) + 32 * half;
            w &= w - 1;
            candidate(s, i, x, y, best_d2, &best, t, moving);
        }
    }
#endif
    return best;
}

/* eqs. (3)-(6) for the winner `best` of eq. (2) (its d^2 given), of an event of polarity
   p; with the motion model (`moving`) eqs. (M1)-(M7) */
static inline __attribute__((always_inline)) void take(fx_state *s, int best, int64_t t,
                                                      int32_t x, int32_t y, uint32_t d2,
                                                      int32_t p, int moving)
{
    if (moving == FX_MOTION_FULL)
        update_moving(s, best, t, x, y, d2, p);
    else if (moving == FX_MOTION_EDGES)
        update_edges(s, best, t, x, y, d2, p);
    else
        update_tracker(s, best, t, shl64(x, FX_POS_FRAC) - s->mx[best],
                       shl64(y, FX_POS_FRAC) - s->my[best], d2);
}

/* eq. (2) and eqs. (3)-(6) for one valid event at pixel (x, y): the winner is updated.
   Returns the winner or FX_NO_TRACKER. */
static inline __attribute__((always_inline)) int assign(fx_state *s, uint64_t mask, int64_t t,
                                                        int32_t x, int32_t y, int32_t p,
                                                        int moving)
{
    uint32_t best_d2 = s->gate;
    int best = search(s, mask, x, y, &best_d2, t, moving);
    if (best >= 0)
        take(s, best, t, x, y, best_d2, p, moving);
    return best;
}

/* One event (Algorithm 1).  Returns the winning tracker, FX_NO_TRACKER or a skip code. */
int fx_step(fx_state *s, int64_t t, int32_t x, int32_t y, int32_t p)
{
    int best;
    if (t < s->last_t) {
        s->n_back++;
        return FX_BACK_IN_TIME;
    }
    s->last_t = t;
    if (x >= s->width || y >= s->height || x < 0 || y < 0) {
        s->n_outside++;
        return FX_OUT_OF_SENSOR;
    }
    s->n_valid++;
    switch (s->moving) {                                  /* three copies: in_motion */
    case FX_MOTION_FULL:
        best = assign(s, s->sensitive_mask, t, x, y, p, FX_MOTION_FULL);
        break;
    case FX_MOTION_EDGES:
        best = assign(s, s->sensitive_mask, t, x, y, p, FX_MOTION_EDGES);
        break;
    default:
        best = assign(s, s->sensitive_mask, t, x, y, p, FX_MOTION_REST);
    }
    if (best >= 0)
        s->n_assigned++;
    if (++s->since_spring >= s->period) {
        s->since_spring = 0;
        fx_springs(s);
    }
    return best;
}

/* the batch loop of fx_steps (g NULL: state s) and fx_set_steps (the set g), the event
   counters, the clock and (for s) the sensitive mask kept in registers (the springs are
   the only other writer of the mask); inlined into each, so g's tests vanish */
typedef struct {
    int64_t k, last_t;
    int32_t until, n_assigned, n_skipped, n_back;
} batch;

static inline __attribute__((always_inline)) int set_assign(fx_set *g, int64_t t, int32_t x,
                                                            int32_t y, int32_t p, int moving,
                                                            int *taker);
static inline __attribute__((always_inline)) int64_t set_count(fx_set *g, int taker,
                                                               int32_t x, int32_t y,
                                                               int64_t next_due, int64_t t);
static int64_t set_next_due(const fx_set *g);

static inline __attribute__((always_inline)) batch steps_loop(fx_state *s, fx_set *g,
                                                            const fx_event *ev, int64_t n,
                                                            int64_t t_stop, int64_t last_t,
                                                            int32_t since_spring, int moving)
{
    const fx_state *s0 = g ? g->inst[0] : s;
    uint32_t width = (uint32_t)s0->width, height = (uint32_t)s0->height;
    int32_t period = s0->period;
    batch o = {0, last_t, period - since_spring, 0, 0, 0};   /* until >= 1 */
    uint64_t mask = g ? 0 : s->sensitive_mask;
    int64_t next_due = g ? set_next_due(g) : 0;           /* the set's spring clocks */
    int taker = -1, best;
    for (o.k = 0; o.k < n; o.k++) {
        int64_t t = ev[o.k].t;
        uint32_t x = ev[o.k].x, y = ev[o.k].y;
        int32_t p = ev[o.k].p;
        if (st_sample_due(t, t_stop, o.last_t))
            break;
        if (t < o.last_t) {
            o.n_back++;
            continue;
        }
        o.last_t = t;
        if (x >= width || y >= height) {
            o.n_skipped++;
            continue;
        }
        if (g) {                                          /* each instance's clock */
            best = set_assign(g, t, (int32_t)x, (int32_t)y, p, moving, &taker);
            o.n_assigned += best >= 0;
            next_due = set_count(g, best >= 0 ? taker : -1, (int32_t)x, (int32_t)y,
                                 next_due, o.last_t);
            continue;
        }
        o.n_assigned += assign(s, mask, t, (int32_t)x, (int32_t)y, p, moving) >= 0;
        if (--o.until <= 0) {
            o.until = period;
            s->last_t = o.last_t;                         /* eq. (M1): the update's time */
            fx_springs(s);
            mask = s->sensitive_mask;
        }
    }
    return o;
}

/* fx_step over a batch */
int64_t fx_steps(fx_state *s, const fx_event *ev, int64_t n, int64_t t_stop)
{
    /* three copies of the loop: the motion model's mode (in_motion, per batch) */
    batch o = s->moving == FX_MOTION_FULL
                  ? steps_loop(s, 0, ev, n, t_stop, s->last_t, s->since_spring, FX_MOTION_FULL)
              : s->moving == FX_MOTION_EDGES
                  ? steps_loop(s, 0, ev, n, t_stop, s->last_t, s->since_spring, FX_MOTION_EDGES)
                  : steps_loop(s, 0, ev, n, t_stop, s->last_t, s->since_spring, FX_MOTION_REST);
    s->last_t = o.last_t;
    s->since_spring = s->period - o.until;
    s->n_valid += o.k - o.n_back - o.n_skipped;
    s->n_assigned += o.n_assigned;
    s->n_back += o.n_back;
    s->n_outside += o.n_skipped;
    return o.k;
}
