/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): the spatial
   index: each tracker's gate box in the cells of 8 x 8 px, re-indexed after an update. */

/* ---- spatial index ------------------------------------------------------------------- */
static inline int32_t max32(int32_t a, int32_t b)
{
    return a > b ? a : b;
}

static inline int32_t min32(int32_t a, int32_t b)
{
    return a < b ? a : b;
}

/* Move tracker i's bit from the cells of its indexed box to those of the box x0..x1,
   y0..y1: per row, only the cells of one box and not the other change (a box that moves by
   a cell changes a column and a row, not its whole area).  An empty row range is x0 > x1. */
static void index_move(fx_state *s, int i, int32_t x0, int32_t x1, int32_t y0, int32_t y1)
{
    uint64_t bit = (uint64_t)1 << i;
    int32_t ox0 = s->box_x0[i], ox1 = s->box_x1[i], oy0 = s->box_y0[i], oy1 = s->box_y1[i];
    int32_t ylo = min32(oy0, y0), yhi = max32(oy1, y1), y, x;
    if (ox0 > ox1 || oy0 > oy1)                           /* not indexed yet */
        ylo = y0, yhi = y1;
    for (y = ylo; y <= yhi; y++) {
        uint64_t *row = s->cells + y * s->gw;
        int old_row = y >= oy0 && y <= oy1 && ox0 <= ox1, new_row = y >= y0 && y <= y1;
        int32_t a0 = old_row ? ox0 : 0, a1 = old_row ? ox1 : -1;   /* old cells of the row */
        int32_t b0 = new_row ? x0 : 0, b1 = new_row ? x1 : -1;     /* new cells */
        for (x = a0; x <= min32(a1, b0 - 1); x++)          /* old, left of the new */
            row[x] &= ~bit;
        for (x = max32(a0, b1 + 1); x <= a1; x++)          /* old, right of the new */
            row[x] &= ~bit;
        for (x = b0; x <= min32(b1, a0 - 1); x++)          /* new, left of the old */
            row[x] |= bit;
        for (x = max32(b0, a1 + 1); x <= b1; x++)          /* new, right of the old */
            row[x] |= bit;
    }
}

static inline int32_t cell_of(int32_t v, int32_t gmax)
{
    int32_t c = v >> (16 + FX_CELL_SHIFT);                /* v Q.16 px; floor */
    return c < 0 ? 0 : (c > gmax ? gmax : c);
}

/* An upper bound of gate v (Q.32 px^2) for a variance v (Q.40, <= 2^52): the square of the
   gate box's half-width, for the spatial index (which needs a box that contains the gate
   box, not an exact one).  One 32 x 32 product: (v / 2^21 + 1) gate (Q.27) < 2^63, rounded
   up; relative excess < 2^-17 for v >= 0.25 px^2. */
static inline uint64_t gate_box2(const fx_state *s, int64_t v)
{
    return (umul((uint32_t)(v >> 21) + 1, s->gate) + 16383) >> 14;
}

/* half-width of the gate box for a variance v (Q.40), Q.16, rounded up */
static inline int32_t gate_half(const fx_state *s, int64_t v)
{
    return (int32_t)isqrt64(gate_box2(s, v)) + 1;
}

/* the variance up to which box_kept holds: 1/32 above v (sigma 1.5 % above), at most the
   clamp's sigma_max^2 (refresh never lets a variance exceed it) */
static inline int64_t var_lim(const fx_state *s, int64_t v)
{
    int64_t lim = v + (v >> 5);
    return lim < s->smax2 ? lim : s->smax2;
}

/* (Re)insert tracker i with its gate box sqrt(gate * sxx) x sqrt(gate * syy), enlarged by
   2^-FX_INDEX_GROW_SHIFT of itself and FX_INDEX_MARGIN, so that a covariance growing a
   little does not re-index at once (the index only selects candidates: any box that
   contains the gate box gives the same results). */
void fx_reindex(fx_state *s, int i)
{
    int32_t hx = gate_half(s, s->sxx[i]), hy = gate_half(s, s->syy[i]);     /* Q.16 */
    int32_t cx = pos16(s->mx[i]), cy = pos16(s->my[i]);
    int32_t x0, x1, y0, y1;
    /* eq. (M1): the gate box anywhere along the prediction, up to |v| H from the mean */
    hx += (hx >> FX_INDEX_GROW_SHIFT) + FX_INDEX_MARGIN + reach16(s, s->vx[i]);
    hy += (hy >> FX_INDEX_GROW_SHIFT) + FX_INDEX_MARGIN + reach16(s, s->vy[i]);
    s->bx_lo[i] = cx - hx;
    s->bx_hi[i] = cx + hx;
    s->by_lo[i] = cy - hy;
    s->by_hi[i] = cy + hy;
    /* box_kept's slack: while sxx <= sxx_lim the gate half-width is at most
       gate_half(sxx_lim), so the mean may move by the rest of hx (>= 0: the enlargement
       is 1/8 and 3 px, the growth allowed about 1/64) */
    s->sxx_lim[i] = var_lim(s, s->sxx[i]);
    s->syy_lim[i] = var_lim(s, s->syy[i]);
    s->bcx[i] = cx;
    s->bcy[i] = cy;
    s->devx[i] = max32(hx - gate_half(s, s->sxx_lim[i]), 0) - reach16(s, s->vx[i]);
    s->devy[i] = max32(hy - gate_half(s, s->syy_lim[i]), 0) - reach16(s, s->vy[i]);
    x0 = cell_of(s->bx_lo[i], s->gw - 1);
    x1 = cell_of(s->bx_hi[i], s->gw - 1);
    y0 = cell_of(s->by_lo[i], s->gh - 1);
    y1 = cell_of(s->by_hi[i], s->gh - 1);
    if (x0 != s->box_x0[i] || x1 != s->box_x1[i] || y0 != s->box_y0[i] || y1 != s->box_y1[i]) {
        index_move(s, i, x0, x1, y0, y1);                 /* the box covers other cells */
        s->box_x0[i] = x0;
        s->box_x1[i] = x1;
        s->box_y0[i] = y0;
        s->box_y1[i] = y1;
    }
    s->n_reindex++;
}

/* d >= h  <=>  d >= 0 and d^2 >= h^2 (h^2 = g2, Q.32); d is Q.16 */
static inline int inside(int32_t d, uint64_t g2)
{
    return d >= 0 && (uint64_t)smul(d, d) >= g2;
}

/* 1 if tracker i's gate box lies inside its indexed box (the exact test, for
   fx_check_index) */
static inline int box_ok(const fx_state *s, int i)
{
    /* positions to Q.16 (floor): an error < 2^-16 px, far inside the 3 px index margin;
       both sides of an axis are inside iff the nearer one is (one square per axis) */
    int32_t x = pos16(s->mx[i]), y = pos16(s->my[i]);
    return inside(min32(x - s->bx_lo[i], s->bx_hi[i] - x) - reach16(s, s->vx[i]),
                  gate_box2(s, s->sxx[i]))
        && inside(min32(y - s->by_lo[i], s->by_hi[i] - y) - reach16(s, s->vy[i]),
                  gate_box2(s, s->syy[i]));
}

/* 1 if tracker i's mean and variances are still within the slack fx_reindex noted (less
   eq. (M1)'s reach at the current velocity, kept by set_velocity): a sufficient test for
   box_ok, four comparisons (the exact one needs the gate box of the current variances,
   two products and two squares) */
static inline int box_kept(const fx_state *s, int i)
{
    int32_t dx = pos16(s->mx[i]) - s->bcx[i], dy = pos16(s->my[i]) - s->bcy[i];
    return (dx < 0 ? -dx : dx) <= s->devx[i] && (dy < 0 ? -dy : dy) <= s->devy[i]
        && s->sxx[i] <= s->sxx_lim[i] && s->syy[i] <= s->syy_lim[i];
}

/* Re-index tracker i if its gate box may have left the box it is indexed with. */
static inline void check_index(fx_state *s, int i)
{
    if (!box_kept(s, i))
        fx_reindex(s, i);
}

/* 1 if every tracker's gate box lies inside its indexed box and its bit is set in every
   cell of that box (tests). */
int fx_check_index(const fx_state *s)
{
    int i, cx, cy;
    for (i = 0; i < s->n; i++) {
        if (!box_ok(s, i))
            return 0;
        for (cy = s->box_y0[i]; cy <= s->box_y1[i]; cy++)
            for (cx = s->box_x0[i]; cx <= s->box_x1[i]; cx++)
                if (!((s->cells[cy * s->gw + cx] >> i) & 1))
                    return 0;
    }
    return 1;
}
