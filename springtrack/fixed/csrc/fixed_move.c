/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): moving an
   instance rigidly (springtrack.reference.ReferenceTracker.move). */

/* ---- moving an instance rigidly (springtrack.reference.ReferenceTracker.move) --------- */

/* round(c v / 2^28), half up, for c in Q.28 and |v| < 2^62 when it fits int64: v = hi 2^31
   + lo with 0 <= lo < 2^31, so c v / 2^28 = 8 c hi (exact) + c lo / 2^28 (rounded): two
   32 x 32 -> 64-bit products, one rounding.  A move is rare: one copy of the code, not
   fourteen (flash on a microcontroller) */
static __attribute__((noinline)) int64_t mulq28(int32_t c, int64_t v)
{
    return shl64(smul(c, (int32_t)(v >> 31)), 3) + rshr(smul(c, (int32_t)(v & 0x7fffffff)), 28);
}

/* (x, y) <- A (x, y) + t, A = [[a, -b], [b, a]] Q.28, Q.32 in and out */
static inline void sim_point(int32_t a, int32_t b, int64_t tx, int64_t ty, int64_t *x,
                             int64_t *y)
{
    int64_t u = *x, v = *y;
    *x = mulq28(a, u) - mulq28(b, v) + tx;
    *y = mulq28(b, u) + mulq28(a, v) + ty;
}

/* 1 if the model words w (checked for length) describe the loaded instance: the same
   sensor, position box, trackers' masses and connections (ends, kinds, stiffnesses) */
static int same_model(const fx_state *s, const int32_t *w)
{
    int i, k;
    if (w[0] != s->n || w[1] != s->nc || w[2] != s->width || w[3] != s->height
        || w[4] != s->pos_lo_x || w[5] != s->pos_hi_x || w[6] != s->pos_lo_y
        || w[7] != s->pos_hi_y)
        return 0;
    w += FX_MODEL_HEAD;
    for (i = 0; i < s->n; i++, w += FX_MODEL_TRACKER)
        if ((uint32_t)w[10] != s->mq[i] || (uint32_t)w[11] != s->invm[i])
            return 0;
    for (k = 0; k < s->nc; k++, w += FX_MODEL_CONNECTION)
        if (w[0] != s->ca[k] || w[1] != s->cb[k] || w[2] != s->kinds[k]
            || (uint32_t)w[3] != s->stiff[k])
            return 0;
    return 1;
}

int fx_move(fx_state *s, const int32_t *w, int32_t nw)
{
    int32_t a, b;
    int64_t tx, ty;
    int i, k;
    if (nw != FX_MOVE_HEAD + FX_MODEL_HEAD + s->n * FX_MODEL_TRACKER
              + s->nc * FX_MODEL_CONNECTION)
        return FX_ERR_WORDS;
    a = w[0];                                             /* |a|, |b| < 8 (Q.28 in int32) */
    b = w[1];
    tx = word64(w + 2);
    ty = word64(w + 4);
    if (tx <= -FX_SIM_T_LIM || tx >= FX_SIM_T_LIM || ty <= -FX_SIM_T_LIM || ty >= FX_SIM_T_LIM)
        return FX_ERR_RANGE;
    w += FX_MOVE_HEAD;
    if (!same_model(s, w))
        return FX_ERR_MODEL;
    /* the energies of the last spring update stay as they were: the kinds not computed yet
       are computed now, from that update's rest geometry */
    fx_energies(s);
    w += FX_MODEL_HEAD;
    for (i = 0; i < s->n; i++, w += FX_MODEL_TRACKER)
        rest_tracker(s, i, w);
    for (k = 0; k < s->nc; k++, w += FX_MODEL_CONNECTION)
        rest_connection(s, k, w);
    for (i = 0; i < s->n; i++) {
        int64_t sxx = s->sxx[i], sxy = s->sxy[i], syy = s->syy[i];   /* Q.40, <= 2^52 */
        int64_t pxx, pxy, pyx, pyy, x = s->mx[i], y = s->my[i];
        /* mu' = A mu + t (Q.32: |A mu| < 2^49, |t| < 2^52), held inside +-FX_POS_LIM */
        sim_point(a, b, tx, ty, &x, &y);
        s->mx[i] = sat_pos(s, x);
        s->my[i] = sat_pos(s, y);
        /* v' = A v, h' = A h (eqs. M1-M8's velocity and half offset turn with the part) */
        x = s->vx[i];
        y = s->vy[i];
        s->vx[i] = (int32_t)clamp64(mulq28(a, x) - mulq28(b, y), V_MAX);
        s->vy[i] = (int32_t)clamp64(mulq28(b, x) + mulq28(a, y), V_MAX);
        x = s->hx[i];
        y = s->hy[i];
        s->hx[i] = clamp64(mulq28(a, x) - mulq28(b, y), s->h_max);
        s->hy[i] = clamp64(mulq28(b, x) + mulq28(a, y), s->h_max);
        /* Sigma' = A Sigma A^T: the rows of A Sigma (< 2^56), then times A^T (< 2^60) */
        pxx = mulq28(a, sxx) - mulq28(b, sxy);
        pxy = mulq28(a, sxy) - mulq28(b, syy);
        pyx = mulq28(b, sxx) + mulq28(a, sxy);
        pyy = mulq28(b, sxy) + mulq28(a, syy);
        s->sxx[i] = mulq28(a, pxx) - mulq28(b, pxy);
        s->sxy[i] = mulq28(b, pxx) + mulq28(a, pxy);
        s->syy[i] = mulq28(b, pyx) + mulq28(a, pyy);
        refresh(s, i);                                    /* clamped as eq. (4)'s, inverted */
        fx_reindex(s, i);
    }
    /* the frame's centre mapped; its s R is kept (2-D similarities commute) */
    sim_point(a, b, tx, ty, &s->frame_gx, &s->frame_gy);
    return FX_OK;
}

/* ---- trackers put elsewhere one by one (springtrack.reference.ReferenceTracker.relocate) */

/* words: the count m, then FX_RELOCATE_TRACKER words per tracker: its index, its mean
   (x, y Q.32) and covariance (sxx, sxy, syy Q.40), each an int64 as two words.  Every
   word is checked before anything changes.  The trackers' activities become 0; the
   others, the rest geometry, the frame and the state are kept. */
int fx_relocate(fx_state *s, const int32_t *w, int32_t nw)
{
    int32_t m, k;
    const int32_t *t;
    if (nw < 1)
        return FX_ERR_WORDS;
    m = w[0];
    if (m < 0 || m > s->n || nw != 1 + m * FX_RELOCATE_TRACKER)
        return FX_ERR_WORDS;
    for (k = 0, t = w + 1; k < m; k++, t += FX_RELOCATE_TRACKER) {
        int64_t x = word64(t + 1), y = word64(t + 3);
        int64_t sxx = word64(t + 5), sxy = word64(t + 7), syy = word64(t + 9);
        if (t[0] < 0 || t[0] >= s->n || x < -FX_POS_LIM || x >= FX_POS_LIM
            || y < -FX_POS_LIM || y >= FX_POS_LIM || sxx <= 0 || syy <= 0
            || sxx > FX_RELOCATE_COV_LIM || syy > FX_RELOCATE_COV_LIM
            || sxy <= -FX_RELOCATE_COV_LIM || sxy >= FX_RELOCATE_COV_LIM)
            return FX_ERR_RANGE;
    }
    for (k = 0, t = w + 1; k < m; k++, t += FX_RELOCATE_TRACKER) {
        int i = t[0];
        s->mx[i] = word64(t + 1);
        s->my[i] = word64(t + 3);
        s->sxx[i] = word64(t + 5);
        s->sxy[i] = word64(t + 7);
        s->syy[i] = word64(t + 9);
        s->act[i] = 0;                                    /* eq. (6): no event there yet */
        still(s, i);                                      /* [ref] _still */
        refresh(s, i);                                    /* clamped as eq. (4)'s, inverted */
        fx_reindex(s, i);
    }
    return FX_OK;
}
