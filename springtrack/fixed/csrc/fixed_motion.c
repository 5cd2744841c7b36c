/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): the motion
   model, this project's extension of Algorithm 1 (eqs. M1-M8 of springtrack/reference.py,
   docs/motion.md; the float kernel's springtrack/kernel/motion.pxd): each tracker's
   velocity, the half offset between its part's ON and OFF edges and the Kalman filter
   whose gains fall below alpha1 where its events come fast.  [ref] marks the functions
   translated.

   Q formats (docs/fixed_point.md, "The motion model"): v Q.32 px/us in int32 (|v| <=
   0.25 px/us = 2^30); h Q.32 px in int64, as the means; the Kalman covariance in units of
   tau_m, so that its three entries are O(1): pp, pv tau_m, vv tau_m^2, Q.32 in int64; the
   step d / tau_m and the gains K_p, K_v tau_m, Q.30 in uint32 (a mulsh gain); the lead of
   eq. (M1) Q.8 us in int32 (H <= 10^6 us). */

#define V_MAX ((int64_t)1 << 30)          /* |v| <= 0.25 px/us (reference.VELOCITY_MAX) */
#define P_ONE ((int64_t)1 << 32)          /* 1.0, Q.32: P_UNKNOWN, the bound of vv tau_m^2 */
#define THIRD_Q32 1431655765u             /* 1/3, Q.32 */
#define LEAD_MAX 0x7fffffff               /* the lead's format: < 2^31 Q.8 us (2^23 us) */

static inline int64_t clamp64(int64_t v, int64_t lim)
{
    return v > lim ? lim : (v < -lim ? -lim : v);
}

/* eq. (M1)'s reach |v| H for the spatial index, Q.16 px, rounded up (0 for a still
   tracker, so that a kernel at rest indexes as without the model); at most 2^29 (8192
   px: the box then spans the sensor) */
static inline int32_t reach16(const fx_state *s, int32_t v)
{
    uint64_t r;
    if (v == 0)
        return 0;
    r = (umul((uint32_t)(v < 0 ? -v : v), (uint32_t)s->horizon8) >> 24) + 1;
    return r > ((uint64_t)1 << 29) ? (int32_t)1 << 29 : (int32_t)r;
}

/* tracker i's velocity set to (vx, vy); the index check's slack (box_kept: the mean's
   offset from its box's centre) follows the change of eq. (M1)'s reach.  A negative slack
   re-indexes at the next check. */
static inline void set_velocity(fx_state *s, int i, int32_t vx, int32_t vy)
{
    s->devx[i] += reach16(s, s->vx[i]) - reach16(s, vx);
    s->devy[i] += reach16(s, s->vy[i]) - reach16(s, vy);
    s->vx[i] = vx;
    s->vy[i] = vy;
}

/* [ref] predict_dt: eq. (M1)'s lead max(0, min(t, t_k + H) - t_m), Q.8 us.  It is at most
   H while t_m >= t_k (an update or a spring update sets t_m; only a change of the activity
   tau moves t_k past it): held below 2^31 */
static inline int32_t lead8(const fx_state *s, int i, int64_t t)
{
    int64_t end = shl64(t, 8), k = shl64(s->tlast[i], 8) + s->horizon8, d;
    if (k < end)
        end = k;
    d = end - shl64(s->tm[i], 8);
    return d <= 0 ? 0 : (d > LEAD_MAX ? LEAD_MAX : (int32_t)d);
}

/* eq. (M1): the prediction v lead, Q.32 px (one product: |v lead| < 2^61 Q.40) */
static inline int64_t ahead(int32_t v, int32_t lead)
{
    return rshr(smul(v, lead), 8);
}

void fx_predicted(const fx_state *s, int i, int64_t t, int64_t *x, int64_t *y)
{
    int32_t lead = lead8(s, i, t);
    *x = s->mx[i] + ahead(s->vx[i], lead);                /* eq. (M1) */
    *y = s->my[i] + ahead(s->vy[i], lead);
}

/* [ref] _still: tracker i still, one edge, position unknown (its first gain is alpha1),
   no event yet (t_k = t_m = 0: its activity is 0 wherever this is called) */
static void still(fx_state *s, int i)
{
    s->vx[i] = s->vy[i] = 0;
    s->hx[i] = s->hy[i] = 0;
    s->fon[i] = 1u << 29;                 /* 0.5 */
    s->tm[i] = 0;
    s->tlast[i] = 0;
    s->kpp[i] = P_ONE;
    s->kpv[i] = s->kvv[i] = 0;
}

/* How much of the motion model can move a mean: FX_MOTION_FULL with tau_m on or a tracker
   holding a velocity; else FX_MOTION_EDGES with c_h on or a tracker holding a half offset;
   else FX_MOTION_REST.  At rest eqs. (M1)-(M7) reduce to eqs. (3)-(5) exactly (every
   prediction is 0, the gain alpha1): the per-event path skips them and computes the same
   integers as a kernel without the model; below FX_MOTION_FULL the candidates' predictions
   are zeros and are skipped.  Decided when the parameters are set (s->moving): with
   tau_m = 0 (c_h = 0) nothing makes a zero v (h) other than zero (a move turns it, a reset
   or relocation zeroes it), and a state that keeps a mode after them is exact either way
   (its predictions add the zeros it holds). */
static int in_motion(const fx_state *s)
{
    int i, edges = s->c_h > 0;
    if (s->tau_ceil > 0)
        return FX_MOTION_FULL;
    for (i = 0; i < s->n; i++) {
        if (s->vx[i] | s->vy[i])
            return FX_MOTION_FULL;
        edges |= (s->hx[i] | s->hy[i]) != 0;
    }
    return edges ? FX_MOTION_EDGES : FX_MOTION_REST;
}

/* sqrt(v) of a Q.32 v >= 0, Q.32: isqrt of v 2^32 with v shifted by an even amount into
   62 bits (31 significant bits) */
static int64_t sqrt_q32(int64_t v)
{
    int k;
    if (v <= 0)
        return 0;
    k = (62 - bitlen64((uint64_t)v)) & ~1;                /* even, v 2^k < 2^62 */
    if (k > 32)
        k = 32;
    return shl64((int64_t)isqrt64((uint64_t)v << k), (32 - k) / 2);
}

/* [ref] _kalman, eq. (M3): tracker i's Kalman filter of position and velocity, predicted
   over d = min(t - t_k, tau_m) and updated by one event (before t_k becomes t).  Returns
   K_p, Q.30; *kv = K_v tau_m, Q.30 (|.| <= 1/2). */
static uint32_t kalman(fx_state *s, int i, int64_t t, int32_t *kv)
{
    int64_t dt = t - s->tlast[i], pp, pv, vv, x, apv, nv, lim;
    uint32_t d, d2, d3, m, r, rem, kp, kvm;
    int e, capped;
    /* d' = min(t - t_k, tau_m) / tau_m, Q.30: dt < tau_m < 2^24 us, 1 / tau_m < 2^31 */
    if (dt >= s->tau_ceil)
        d = 1u << 30;
    else if (dt <= 0)
        d = 0;
    else
        d = (uint32_t)((umul((uint32_t)dt, s->inv_tau) + ((uint64_t)1 << (s->inv_tau_sh - 31)))
                       >> (s->inv_tau_sh - 30));
    /* P^ = F P F^T + Q, in units of tau_m (q = 1 / tau_m^3): pp + d'(2 pv + d' vv) +
       d'^3 / 3, pv + d' vv + d'^2 / 2, vv + d' */
    d2 = (uint32_t)((umul(d, d) + (1u << 29)) >> 30);    /* d'^2, Q.30 */
    d3 = (uint32_t)((umul(d2, d) + (1u << 29)) >> 30);   /* d'^3, Q.30 */
    x = mulsh(s->kvv[i], d, 30);                          /* d' vv */
    pp = s->kpp[i] + mulsh(2 * s->kpv[i] + x, d, 30)
         + (int64_t)((umul(d3, THIRD_Q32) + (1u << 29)) >> 30);
    pv = s->kpv[i] + x + 2 * (int64_t)d2;                 /* d'^2 / 2 in Q.32 = 2 d2 */
    vv = s->kvv[i] + 4 * (int64_t)d;
    if (vv > P_ONE) {                                     /* vv <= 1 / tau_m^2: a spread */
        vv = P_ONE;                                       /* per tau_m; then P^ positive */
        lim = sqrt_q32(pp);                               /* by |pv| <= sqrt(pp vv) */
        pv = clamp64(pv, lim);
    }
    /* S = max(1 + pp, pp / alpha1) (S = pp / alpha1 iff pp > alpha1 / (1 - alpha1)):
       K_p = pp / S, K_v = pv / S; 1 / S from one 64 / 32 division (2^61 / S's mantissa) */
    capped = pp > s->kcap_thr;
    x = capped ? pp : pp + P_ONE;                         /* S, or S alpha1 */
    apv = pv < 0 ? -pv : pv;
    nv = capped ? mulsh(apv, s->kcap, 30) : apv;          /* |pv| / S = nv / x <= 1/2 */
    if (nv > x)
        nv = x;
    e = bitlen64((uint64_t)x) - 31;
    m = (uint32_t)(e >= 0 ? x >> e : shl64(x, -e));       /* [2^30, 2^31) */
    r = divlu((uint32_t)1 << 29, 0, m, &rem);            /* 2^61 / m */
    if (r > 0x7fffffffu)
        r = 0x7fffffffu;
    kp = capped ? s->kcap                                 /* pp < x: pp >> e < 2^31 (e >= 2) */
                : (uint32_t)((umul((uint32_t)(pp >> e), r) + (1u << 30)) >> 31);
    kvm = (uint32_t)((umul((uint32_t)(e >= 0 ? nv >> e : shl64(nv, -e)), r) + (1u << 30)) >> 31);
    *kv = pv < 0 ? -(int32_t)kvm : (int32_t)kvm;
    /* P = (I - K H) P^ */
    s->kpp[i] = pp - mulsh(pp, kp, 30);
    s->kpv[i] = pv - mulsh(pv, kp, 30);
    s->kvv[i] = vv - mulsh(apv, kvm, 30);                 /* K_v pv >= 0 */
    return kp;
}

/* eq. (M7)'s step K_v r = (K_v tau_m) r / tau_m, Q.32 px/us, for a residual r Q.32 px */
static inline int64_t velocity_step(const fx_state *s, int64_t r, int32_t kv)
{
    int64_t y = mulsh(r, (uint32_t)(kv < 0 ? -kv : kv), 30);    /* Q.32 px */
    return mulsh(kv < 0 ? -y : y, s->inv_tau, s->inv_tau_sh);
}

/* [ref] the springs' eq. (M1): every mean predicted to the update's time t, t_m = t */
static void motion_to(fx_state *s, int64_t t)
{
    int i;
    for (i = 0; i < s->n; i++) {
        if (s->vx[i] | s->vy[i]) {
            int32_t lead = lead8(s, i, t);
            s->mx[i] = sat_pos(s, s->mx[i] + ahead(s->vx[i], lead));
            s->my[i] = sat_pos(s, s->my[i] + ahead(s->vy[i], lead));
        }
        s->tm[i] = t;
    }
}

/* [ref] _pull_velocities, eq. (M8): the velocity of each tracker eq. (22) pulled (bits of
   `pulled`) moves toward the mass-weighted mean velocity of the trackers left alone, by
   energy_gain: v = v + a_en (v_calm - v) (v_calm 0 if none is calm).  Weights mq (Q.24,
   <= 2^24): sums < 2^60, one rounded division each */
static void pull_velocities(fx_state *s, uint64_t pulled)
{
    int64_t sx = 0, sy = 0, bx = 0, by = 0;
    uint32_t w = 0;
    int i;
    for (i = 0; i < s->n; i++) {
        if ((pulled >> i) & 1)
            continue;
        w += s->mq[i];
        sx = smla(sx, (int32_t)s->mq[i], s->vx[i]);
        sy = smla(sy, (int32_t)s->mq[i], s->vy[i]);
    }
    if (w > 0) {                                          /* w <= 64 2^24 < 2^31 */
        bx = div_round(sx, w);
        by = div_round(sy, w);
    }
    for (; pulled; pulled &= pulled - 1) {
        uint32_t lo = (uint32_t)pulled;
        i = lo ? __builtin_ctz(lo) : 32 + __builtin_ctz((uint32_t)(pulled >> 32));
        set_velocity(s, i, s->vx[i] + (int32_t)mulsh(bx - s->vx[i], s->energy_gain, 30),
                     s->vy[i] + (int32_t)mulsh(by - s->vy[i], s->energy_gain, 30));
    }
}

