/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): the spring
   update every `period` events: displacements, the energy criteria of eqs. (21)-(22), the
   energies, and the state guard's reset. */

/* [ref] springs: displacements from the same positions, applied together (Jacobi).  The
   forces of eqs. (11), (16), (19) are summed per tracker (Q.32 px, |sum| < 2^55) and
   divided by the mass once: the same sums as the reference's per-connection f / m_i.
   Only the criterion's energy kind is computed here; the spring vectors are kept for
   fx_energies(). */
__attribute__((noinline)) void fx_springs(fx_state *s)
{
    int n = s->n, nc = s->nc, used = s->used_kinds, i, k;
    int64_t ddx[FX_MAX_TRACKERS], ddy[FX_MAX_TRACKERS], total, thr, gx, gy, sx = 0, sy = 0;
    uint64_t pulled = 0, calm = ~(uint64_t)0, bad = 0, soft = 0;
    uint32_t dis[FX_MAX_TRACKERS];
    const int64_t *e = s->energy[s->ekind];
    uint32_t rem;
    s->n_spring_updates++;
    if (s->moving)                                       /* [ref] eq. (M1): the springs act */
        motion_to(s, s->last_t);                         /* on the means at the update's time */
    s->car_turned = s->car_sim;                          /* eq. (18) in the last fit's frame */
    s->car_c = s->frame_c;
    s->car_s = s->frame_s;
    for (i = 0; i < n; i++)
        ddx[i] = ddy[i] = 0;
    total = spring_passes_of[used & 7](s, ddx, ddy);
    /* bit 3: no torsional energies at this update (0, as the float kernel) */
    s->energy_stale = (7 & ~(1 << s->ekind)) | (used & 2 ? 0 : 8);
    for (i = 0; i < n; i++) {                             /* the sums of forces / m_i */
        int64_t fx = ddx[i], fy = ddy[i];
        if (!s->unit_mass) {                              /* m_i = 1: f / m_i = f exactly */
            fx = mulsh(fx, s->invm[i], 24);
            fy = mulsh(fy, s->invm[i], 24);
        }
        s->mx[i] = sat_pos(s, s->mx[i] + fx);
        s->my[i] = sat_pos(s, s->my[i] + fy);
        sx += s->mx[i] - s->mx[0];                        /* |sum| < 2^53 */
        sy += s->my[i] - s->my[0];
    }
    /* [ref] _energy_criteria: eqs. (13), (21), (22) */
    if (nc > 0) {
        s->mean_energy = (int64_t)udiv64((uint64_t)total, (uint32_t)nc, &rem);   /* eq. (13) */
        /* e > s mean; with s >= nc no connection can exceed it (e <= total = nc mean) */
        if (s->escale_never)
            thr = E_MAX;
        else                                              /* s mean < nc mean <= E_MAX */
            thr = mulsh(s->mean_energy, s->escale, s->escale_sh);
        if (!s->escale_never) {
            /* the trackers at an over-threshold connection (pulled, eq. 22) and those at
               one under it (calm: eq. 21 keeps them sensitive), as OR-reductions of the
               connections' end masks: no branch, no counting per tracker */
            calm = s->isolated;
            for (k = 0; k < nc; k++) {
                uint64_t o = (uint64_t)0 - (uint64_t)(e[k] > thr);
                pulled |= s->ends[k] & o;
                calm |= s->ends[k] & ~o;
            }
        }
    }
    if (n == 0)
        return;
    for (i = 0; i < n; i++)
        dis[i] = 0;
    if (nc > 0 && (s->pull_sim || s->car_sim)) {        /* [ref] fit_frame, the calm ones */
        fit_frame_agreeing(s, ~pulled, dis);              /* weighted by how well they agree */
        for (i = 0; i < n; i++)                           /* eq. (22) pulls by 1 - that */
            soft |= (uint64_t)(dis[i] > 0) << i;
        soft &= ~pulled;
    }
    /* centre of mass G = x0 + sum m_i (x_i - x0) / sum m_i, rounded half up */
    if (s->pull_sim) {
        gx = gy = 0;                                      /* eq. (22) uses the frame's G */
    } else if (s->equal_mass) {                           /* = x0 + round(sum (x_i - x0) / n) */
        gx = s->mx[0] + floor_div(2 * sx + n, 2 * (uint32_t)n, &rem);
        gy = s->my[0] + floor_div(2 * sy + n, 2 * (uint32_t)n, &rem);
    } else {
        uint32_t msum = 0;
        for (i = 0; i < n; i++)
            msum += s->mq[i];
        gx = centre(s, s->mx, msum);
        gy = centre(s, s->my, msum);
    }
    for (uint64_t p = pulled | soft; p; p &= p - 1) {     /* eq. (22) */
        uint32_t lo = (uint32_t)p, gain = s->energy_gain;
        int64_t tx, ty;                                   /* G + dG0, or G + s R dG0 */
        i = lo ? __builtin_ctz(lo) : 32 + __builtin_ctz((uint32_t)(p >> 32));
        if ((soft >> i) & 1)                              /* energy_gain (1 - v), Q.30 */
            gain = (uint32_t)rshr((int64_t)umul(gain, dis[i]), 24);
        if (s->pull_sim) {
            frame_target(s, i, &tx, &ty);
        } else {
            tx = gx + s->gdx0[i];
            ty = gy + s->gdy0[i];
        }
        s->mx[i] = sat_pos(s, s->mx[i] + mulsh(tx - s->mx[i], gain, 30));
        s->my[i] = sat_pos(s, s->my[i] + mulsh(ty - s->my[i], gain, 30));
        if (s->c_h > 0) {                                 /* eq. (M9): h = h - gain h */
            s->hx[i] -= mulsh(s->hx[i], gain, 30);
            s->hy[i] -= mulsh(s->hy[i], gain, 30);
        }
    }
    if (s->tau_ceil > 0 && pulled)                        /* eq. (M8) */
        pull_velocities(s, pulled);
    /* [ref] _guard: a mean outside the position box (a saturated one is) is a state no
       model within springtrack.limits reaches: counted, and the state reset to the model.
       The box is whole px: the integer parts (the high words) tell */
    for (i = 0; i < n; i++) {
        int32_t xi = (int32_t)(s->mx[i] >> FX_POS_FRAC), yi = (int32_t)(s->my[i] >> FX_POS_FRAC);
        bad |= (uint64_t)(xi < s->pos_lo_x || xi >= s->pos_hi_x || yi < s->pos_lo_y
                          || yi >= s->pos_hi_y);
    }
    if (bad) {
        s->n_resets++;
        fx_reset(s);
        return;
    }
    for (i = 0; i < n; i++)
        bad |= (uint64_t)!box_kept(s, i) << i;
    /* eq. (21): insensitive when every connection of the tracker is over */
    s->sensitive_mask = calm & (n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << n) - 1);
    while (bad) {                                         /* re-index who left its box */
        uint32_t lo = (uint32_t)bad;
        fx_reindex(s, lo ? __builtin_ctz(lo) : 32 + __builtin_ctz((uint32_t)(bad >> 32)));
        bad &= bad - 1;
    }
}

/* The energies of all three kinds at the last spring update (eqs. 12, 17, 20), from the
   spring vectors it kept: the kinds the criterion does not use are computed here, when
   they are read, with the same arithmetic as fx_springs (so the values do not depend on
   when they are read).  The torsional ones from eq. (14)'s angles, which a host kept at
   the update (FX_KEEP_ANGLES; an update whose springs have no torsion has none: bit 3);
   the Euclidean ones from the lengths and directions computed again.  Offsets are
   clamped as there, not counted again. */
void fx_energies(fx_state *s)
{
    int nc = s->nc, k, stale = s->energy_stale;
    int32_t l[FX_MAX_CONNECTIONS], cx[FX_MAX_CONNECTIONS], cy[FX_MAX_CONNECTIONS];
#if FX_KEEP_ANGLES
    const int32_t *dth = s->dth;
    int64_t mean_dth = s->mean_dth;
    const int geometry = stale & 1;                       /* l, c for eq. (12) */
#else
    int32_t dth[FX_MAX_CONNECTIONS];
    int64_t mean_dth = 0, sum = 0;
    const int geometry = stale & 3;                       /* and the angles, eq. (14) */
#endif
    if (!(stale & 7))
        return;
    if (geometry) {
        for (k = 0; k < nc; k++) {
            int32_t a = spring_angle(s, k, geom16(s->grx[k]), geom16(s->gry[k]), &l[k],
                                     &cx[k], &cy[k]);
#if !FX_KEEP_ANGLES
            dth[k] = a;
            sum += a;
#else
            (void)a;                                      /* the update kept it */
#endif
        }
#if !FX_KEEP_ANGLES
        if (nc > 0)
            mean_dth = div_round(sum, (uint32_t)nc);      /* eq. (15) */
#endif
    }
    for (k = 0; k < nc; k++) {
        int64_t ex, ey, e;
        if (stale & 1) {
            e = energy_euclid(s, k, spring_dl(s, k, s->grx[k], s->gry[k], l[k], cx[k], cy[k]));
            s->energy[0][k] = e > E_MAX ? E_MAX : e;
        }
        if (stale & 2)                                    /* eq. (17) of eq. (15)'s d */
            s->energy[1][k] = stale & 8 ? 0 : energy_torsion(s, k, dth[k] - mean_dth);
        if (stale & 4) {
            offsets(s, k, s->grx[k], s->gry[k], &ex, &ey);
            e = energy_cart(s, k, ex, ey);
            s->energy[2][k] = e > E_MAX ? E_MAX : e;
        }
    }
    s->energy_stale &= 8;
}

/* Derived flags, after the model and the parameters are set (and after each change). */
void fx_prepare(fx_state *s)
{
    int i, k;
    s->used_kinds = 1 << s->ekind;
    for (k = 0; k < s->nc; k++)
        s->used_kinds |= s->kinds[k] & 7;
    s->need_torsion = (s->used_kinds >> 1) & 1;
    s->unit_mass = s->equal_mass = 1;
    for (i = 0; i < s->n; i++) {
        if (s->invm[i] != (uint32_t)1 << 24)
            s->unit_mass = 0;
        if (s->mq[i] != s->mq[0])
            s->equal_mass = 0;
    }
    s->decay_span = s->dt_max < ((int64_t)1 << (2 * FX_DECAY_BITS)) ? s->dt_max
                    : ((int64_t)1 << (2 * FX_DECAY_BITS));
}

void fx_reset(fx_state *s)
{
    int i, k, q;
    for (i = 0; i < s->n; i++) {
        s->mx[i] = s->rest_x[i];
        s->my[i] = s->rest_y[i];
        s->sxx[i] = s->rest_sxx[i];
        s->sxy[i] = s->rest_sxy[i];
        s->syy[i] = s->rest_syy[i];
        s->act[i] = 0;
        still(s, i);                                      /* [ref] _still */
    }
    for (q = 0; q < 3; q++)
        for (k = 0; k < s->nc; k++)
            s->energy[q][k] = 0;
    s->mean_energy = 0;
    s->energy_stale = 0;                                  /* the energies are those zeros */
    s->sensitive_mask = s->n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << s->n) - 1;
    s->frame_c = FRAME_ONE;                               /* [ref] the identity frame about */
    s->frame_s = 0;                                       /* G0 until a fit */
    s->car_c = s->car_s = s->car_turned = 0;
    if (s->n > 0) {
        s->frame_gx = s->mx[0] - s->gdx0[0];
        s->frame_gy = s->my[0] - s->gdy0[0];
    }
    for (i = 0; i < s->n; i++) {
        refresh(s, i);
        fx_reindex(s, i);
    }
}

/* Clamp every position into +-FX_POS_LIM (after loading a model), counting saturations. */
void fx_clamp_positions(fx_state *s)
{
    int i;
    for (i = 0; i < s->n; i++) {
        s->mx[i] = sat_pos(s, s->mx[i]);
        s->my[i] = sat_pos(s, s->my[i]);
    }
}
