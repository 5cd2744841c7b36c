/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): loading a
   model and parameters from the word streams of springtrack/fixed/q.py. */

/* ---- loading (the word streams of springtrack/fixed/q.py) ----------------------------- */

static inline int64_t word64(const int32_t *w)           /* low word first */
{
    return (int64_t)(((uint64_t)(uint32_t)w[1] << 32) | (uint32_t)w[0]);
}

/* tracker i's rest geometry from its FX_MODEL_TRACKER words: the mean and covariance the
   state starts from and the guard resets it to, the offset to the rest centre of mass */
static void rest_tracker(fx_state *s, int i, const int32_t *w)
{
    s->rest_x[i] = word64(w);
    s->rest_y[i] = word64(w + 2);
    s->rest_sxx[i] = word64(w + 4);
    s->rest_sxy[i] = word64(w + 6);
    s->rest_syy[i] = word64(w + 8);
    s->gdx0[i] = word64(w + 12);
    s->gdy0[i] = word64(w + 14);
}

/* connection k's rest geometry from its FX_MODEL_CONNECTION words: length, offset, angle */
static void rest_connection(fx_state *s, int k, const int32_t *w)
{
    s->l0[k] = word64(w + 4);
    s->dx0[k] = word64(w + 6);
    s->dy0[k] = word64(w + 8);
    s->th0[k] = (uint32_t)w[10];
    s->c0x[k] = w[11];
    s->c0y[k] = w[12];
}

int32_t fx_cells_needed(int32_t width, int32_t height)
{
    return (((width - 1) >> FX_CELL_SHIFT) + 1) * (((height - 1) >> FX_CELL_SHIFT) + 1);
}

int fx_load_model(fx_state *s, const int32_t *w, int32_t nw, uint64_t *cells, int32_t cell_cap)
{
    int32_t n, nc, width, height, i, k, need;
    uint8_t *z = (uint8_t *)s;
    uint32_t b;
    if (nw < FX_MODEL_HEAD)
        return FX_ERR_WORDS;
    n = w[0];
    nc = w[1];
    width = w[2];
    height = w[3];
    if (n < 0 || nc < 0 || n > FX_MAX_TRACKERS || nc > FX_MAX_CONNECTIONS)
        return FX_ERR_CAPACITY;
    if (nw != FX_MODEL_HEAD + n * FX_MODEL_TRACKER + nc * FX_MODEL_CONNECTION)
        return FX_ERR_WORDS;
    if (width < 1 || height < 1 || width > 8192 || height > 8192)
        return FX_ERR_RANGE;
    /* the position box, whole px: x_lo, x_hi, y_lo, y_hi within +-8191 */
    if (w[4] >= w[5] || w[6] >= w[7] || w[4] < -8191 || w[5] > 8191 || w[6] < -8191
        || w[7] > 8191)
        return FX_ERR_RANGE;
    need = fx_cells_needed(width, height);
    if (need > cell_cap)
        return FX_ERR_CELLS;
    for (b = 0; b < sizeof(fx_state); b++)                /* no libc: memset by hand */
        z[b] = 0;
    for (k = 0; k < need; k++)
        cells[k] = 0;
    s->cells = cells;
    s->n = n;
    s->nc = nc;
    s->width = width;
    s->height = height;
    s->gw = ((width - 1) >> FX_CELL_SHIFT) + 1;
    s->gh = ((height - 1) >> FX_CELL_SHIFT) + 1;
    s->pos_lo_x = w[4];
    s->pos_hi_x = w[5];
    s->pos_lo_y = w[6];
    s->pos_hi_y = w[7];
    w += FX_MODEL_HEAD;
    for (i = 0; i < n; i++, w += FX_MODEL_TRACKER) {
        rest_tracker(s, i, w);
        s->mx[i] = s->rest_x[i];
        s->my[i] = s->rest_y[i];
        s->sxx[i] = s->rest_sxx[i];
        s->sxy[i] = s->rest_sxy[i];
        s->syy[i] = s->rest_syy[i];
        s->mq[i] = (uint32_t)w[10];
        s->invm[i] = (uint32_t)w[11];
        s->box_x0[i] = s->box_y0[i] = 0;                  /* not indexed yet */
        s->box_x1[i] = s->box_y1[i] = -1;
        s->sensitive_mask |= (uint64_t)1 << i;
        still(s, i);                                      /* [ref] _still */
    }
    s->isolated = s->sensitive_mask;
    for (k = 0; k < nc; k++, w += FX_MODEL_CONNECTION) {
        if (w[0] < 0 || w[0] >= n || w[1] < 0 || w[1] >= n)
            return FX_ERR_RANGE;
        s->ca[k] = w[0];
        s->cb[k] = w[1];
        s->kinds[k] = w[2];
        s->stiff[k] = (uint32_t)w[3];
        rest_connection(s, k, w);
        s->ends[k] = ((uint64_t)1 << s->ca[k]) | ((uint64_t)1 << s->cb[k]);
        s->isolated &= ~s->ends[k];
    }
    fx_clamp_positions(s);
    s->frame_c = FRAME_ONE;                               /* [ref] the identity frame about */
    s->frame_s = 0;                                       /* G0 until a fit */
    if (s->n > 0) {
        s->frame_gx = s->mx[0] - s->gdx0[0];
        s->frame_gy = s->my[0] - s->gdy0[0];
    }
    s->last_t = -((int64_t)1 << 62);
    return FX_OK;
}

int fx_set_params(fx_state *s, const int32_t *w, int32_t nw)
{
    int i;
    if (nw != FX_PARAMS_WORDS)
        return FX_ERR_WORDS;
    const int32_t *mw = w + FX_PARAMS_HEAD + 2 * FX_DECAY_N;     /* the motion model's */
    if (w[3] < 31 || w[3] > 62 || w[12] < 1 || w[12] > 62 || w[18] < 1 || w[19] < 0
        || w[19] > 2 || (uint32_t)w[22] > 1 || (uint32_t)w[23] > 1)
        return FX_ERR_RANGE;
    if (mw[0] < 0 || mw[0] > (1 << 24) || mw[1] < 0 || mw[2] < 30 || mw[2] > 62 || mw[3] < 0
        || (uint32_t)mw[4] > (1u << 30) || (uint32_t)mw[5] > (1u << 30) || word64(mw + 6) < 0
        || word64(mw + 8) < 0 || word64(mw + 8) > ((int64_t)64 << 32))
        return FX_ERR_RANGE;
    /* [ref] eq. (6): a new tau decays from the change on */
    if (s->has_params && s->n_valid > 0
        && ((uint32_t)w[20] != s->tau_bits[0] || (uint32_t)w[21] != s->tau_bits[1])) {
        for (i = 0; i < s->n; i++) {
            s->act[i] = fx_activity(s, i, s->last_t);
            s->tlast[i] = s->last_t;
        }
    }
    s->a1 = (uint32_t)w[0];
    s->cov_gm = (uint32_t)w[1];
    s->cov_am = (uint32_t)w[2];
    s->cov_sh = w[3];
    s->energy_gain = (uint32_t)w[4];
    s->gate = (uint32_t)w[5];
    s->k_tau = (uint32_t)w[6];
    s->dt_max = word64(w + 7);
    s->act_thr = word64(w + 9);
    s->escale = (uint32_t)w[11];
    s->escale_sh = w[12];
    s->escale_never = w[13];
    s->smin2 = word64(w + 14);
    s->smax2 = word64(w + 16);
    s->period = w[18];
    s->ekind = w[19];
    s->tau_bits[0] = (uint32_t)w[20];
    s->tau_bits[1] = (uint32_t)w[21];
    s->pull_sim = w[22];
    s->car_sim = w[23];
    s->tau_ceil = mw[0];                                  /* the motion model (fixed_motion.c) */
    s->inv_tau = (uint32_t)mw[1];
    s->inv_tau_sh = mw[2];
    s->horizon8 = mw[3];
    s->c_h = (uint32_t)mw[4];
    s->kcap = (uint32_t)mw[5];
    s->kcap_thr = word64(mw + 6);
    s->h_max = word64(mw + 8);
    s->moving = in_motion(s);
    for (i = 0; i < FX_DECAY_N; i++) {
        s->decay_lo[i] = (uint32_t)w[FX_PARAMS_HEAD + i];
        s->decay_hi[i] = (uint32_t)w[FX_PARAMS_HEAD + FX_DECAY_N + i];
    }
    fx_prepare(s);
    for (i = 0; i < s->n; i++) {
        refresh(s, i);
        fx_reindex(s, i);
    }
    if (!s->has_params)
        s->n_reindex = 0;                                 /* the first indexing is no update */
    s->has_params = 1;
    return FX_OK;
}
