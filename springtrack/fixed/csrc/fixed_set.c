/* Part of the fixed-point kernel's one translation unit, fixed_step.c, which includes it
   (the parts share its static inline helpers, so they are not compiled alone): several
   model instances: one event assignment over their states (fx_set_*). */

/* ---- several model instances (springtrack.instances) ---------------------------------
   One fx_state per instance: its trackers, connections, gains, criteria, springs,
   energies, centre of mass and similarity frame are its own.  The set runs one event
   assignment over all of them, one clock and one spring period, and each instance's
   spring clock. */

/* [ref] step, eq. (2) over the union: each tracking instance's best tracker in turn, one
   starting from the best d^2 so far so that only a strictly smaller one wins (ties: the
   lowest instance, and in it the lowest index, as the reference's scan over all
   trackers); the winner is updated (eqs. 3-6).  Returns its index among all trackers,
   its instance in *taker. */
static inline __attribute__((always_inline)) int set_assign(fx_set *g, int64_t t, int32_t x,
                                                            int32_t y, int32_t p, int moving,
                                                            int *taker)
{
    uint32_t best_d2 = g->inst[0]->gate;                  /* p_threshold: one for all */
    int best = FX_NO_TRACKER, owner = 0, q;
    for (q = 0; q < g->ni; q++) {
        const fx_state *s = g->inst[q];
        uint32_t d2 = best_d2;
        int i;
        if (g->state[q] != FX_TRACKING)
            continue;
        i = search(s, s->sensitive_mask, x, y, &d2, t, moving);
        if (i >= 0) {
            best = i;
            best_d2 = d2;
            owner = q;
        }
    }
    if (best < 0)
        return FX_NO_TRACKER;
    take(g->inst[owner], best, t, x, y, best_d2, p, moving);
    *taker = owner;
    return g->t0[owner] + best;
}

/* [ref] spring_update(q): a tracking instance's springs and criteria (eqs. 7-22) and its
   guard; then, in any state, its spring box.  Out of line: one copy, not one in each of
   the loop's motion modes. */
static __attribute__((noinline)) void set_spring_update(fx_set *g, int q)
{
    const fx_state *s = g->inst[q];
    int64_t x0, x1, y0, y1;
    int i;
    g->n_spring_updates++;
    if (g->state[q] == FX_TRACKING)
        fx_springs(g->inst[q]);
    /* [ref] _spring_box: [ceil(min) - SPRING_BOX_PX, floor(max) + SPRING_BOX_PX] of
       instance q's means on each axis */
    x0 = x1 = s->mx[0];
    y0 = y1 = s->my[0];
    for (i = 1; i < s->n; i++) {
        x0 = s->mx[i] < x0 ? s->mx[i] : x0;
        x1 = s->mx[i] > x1 ? s->mx[i] : x1;
        y0 = s->my[i] < y0 ? s->my[i] : y0;
        y1 = s->my[i] > y1 ? s->my[i] : y1;
    }
    g->sbox[q][0] = (int32_t)-((-x0) >> FX_POS_FRAC) - FX_SPRING_BOX_PX;
    g->sbox[q][1] = (int32_t)(x1 >> FX_POS_FRAC) + FX_SPRING_BOX_PX;
    g->sbox[q][2] = (int32_t)-((-y0) >> FX_POS_FRAC) - FX_SPRING_BOX_PX;
    g->sbox[q][3] = (int32_t)(y1 >> FX_POS_FRAC) + FX_SPRING_BOX_PX;
}

/* [ref] springs: every instance's spring update, in order (the clocks left as they are) */
void fx_set_springs(fx_set *g)
{
    int q;
    for (q = 0; q < g->ni; q++)
        set_spring_update(g, q);
}

/* ---- each instance's spring clock ([ref] step) ---------------------------------------
   Instance q's count is own[q] + n_free - free0[q]: own[q] the events its trackers took
   since its last update and those no tracker took inside its spring box, n_free - free0[q]
   those no tracker took outside every box since then; its update runs when the count
   reaches the period.  An event outside every box costs one count, not one per instance:
   the loops compare n_free with next_due, the smallest n_free at which an update is due
   (set_next_due, computed again at every batch: the period may have changed). */

/* the n_free at which instance q's update is due if its trackers take no other event */
static inline int64_t clock_due(const fx_set *g, int q, int32_t period)
{
    return g->free0[q] + period - g->own[q];
}

static int64_t set_next_due(const fx_set *g)
{
    int32_t period = g->inst[0]->period;
    int64_t nd = clock_due(g, 0, period);
    int q;
    for (q = 1; q < g->ni; q++)
        if (clock_due(g, q, period) < nd)
            nd = clock_due(g, q, period);
    return nd;
}

/* The clocks after a valid event at (x, y) no tracker took: the instances' whose spring
   boxes hold it counted (own), or every instance's if none does (n_free).  Returns
   next_due.  Out of line: the loops keep one call, not a copy of it in each. */
static __attribute__((noinline)) int64_t set_count_free(fx_set *g, int32_t x, int32_t y,
                                                        int64_t next_due)
{
    int32_t period = g->inst[0]->period;
    int64_t d;
    int q, near = 0;
    for (q = 0; q < g->ni; q++)
        if (x >= g->sbox[q][0] && x <= g->sbox[q][1] && y >= g->sbox[q][2]
            && y <= g->sbox[q][3]) {
            near = 1;
            g->own[q]++;
            d = clock_due(g, q, period);
            next_due = d < next_due ? d : next_due;
        }
    if (!near)
        g->n_free++;
    return next_due;
}

/* The clocks after a valid event at (x, y) that instance `taker` took (only its clock
   moved) or no tracker took (taker -1: the clocks of the instances whose spring boxes
   hold it, or every clock if none does), at time t: the updates then due, in instance
   order, each count restarted.  Returns next_due. */
static inline __attribute__((always_inline)) int64_t set_count(fx_set *g, int taker,
                                                               int32_t x, int32_t y,
                                                               int64_t next_due, int64_t t)
{
    int32_t period = g->inst[0]->period;
    int64_t d;
    int q;
    if (taker >= 0) {
        g->own[taker]++;
        d = clock_due(g, taker, period);
        if (d > g->n_free)
            return d < next_due ? d : next_due;
    } else if ((next_due = set_count_free(g, x, y, next_due)) > g->n_free) {
        return next_due;
    }
    for (q = 0; q < g->ni; q++)
        if ((taker < 0 || q == taker) && clock_due(g, q, period) <= g->n_free) {
            g->own[q] = 0;
            g->free0[q] = g->n_free;
            g->last_t = g->inst[q]->last_t = t;           /* [ref] eq. (M1): the update's time */
            set_spring_update(g, q);
        }
    return set_next_due(g);
}

/* the set's clock and event counts, copied into every instance (fx_set_params reads them) */
static void set_sync(fx_set *g)
{
    int q;
    for (q = 0; q < g->ni; q++) {
        fx_state *s = g->inst[q];
        s->last_t = g->last_t;
        s->n_valid = g->n_valid;
        s->n_back = g->n_back;
        s->n_outside = g->n_outside;
    }
}

/* the highest of the instances' motion modes (in_motion): an instance below it adds the
   zeros it holds */
static int set_in_motion(const fx_set *g)
{
    int q, m = FX_MOTION_REST;
    for (q = 0; q < g->ni; q++)
        if (g->inst[q]->moving > m)
            m = g->inst[q]->moving;
    return m;
}

int fx_set_step(fx_set *g, int64_t t, int32_t x, int32_t y, int32_t p)
{
    const fx_state *s0 = g->inst[0];
    int best, taker = -1;
    if (t < g->last_t) {
        g->n_back++;
        set_sync(g);
        return FX_BACK_IN_TIME;
    }
    g->last_t = t;
    if (x >= s0->width || y >= s0->height || x < 0 || y < 0) {
        g->n_outside++;
        set_sync(g);
        return FX_OUT_OF_SENSOR;
    }
    g->n_valid++;
    set_sync(g);
    switch (set_in_motion(g)) {                           /* three copies: the mode */
    case FX_MOTION_FULL:
        best = set_assign(g, t, x, y, p, FX_MOTION_FULL, &taker);
        break;
    case FX_MOTION_EDGES:
        best = set_assign(g, t, x, y, p, FX_MOTION_EDGES, &taker);
        break;
    default:
        best = set_assign(g, t, x, y, p, FX_MOTION_REST, &taker);
    }
    if (best >= 0)
        g->n_assigned++;
    set_count(g, best >= 0 ? taker : -1, x, y, set_next_due(g), t);
    return best;
}

/* fx_steps for a set: the same loop, the sampling rule's stop included */
int64_t fx_set_steps(fx_set *g, const fx_event *ev, int64_t n, int64_t t_stop)
{
    int mode = set_in_motion(g);
    batch o = mode == FX_MOTION_FULL
                  ? steps_loop(0, g, ev, n, t_stop, g->last_t, 0, FX_MOTION_FULL)
              : mode == FX_MOTION_EDGES
                  ? steps_loop(0, g, ev, n, t_stop, g->last_t, 0, FX_MOTION_EDGES)
                  : steps_loop(0, g, ev, n, t_stop, g->last_t, 0, FX_MOTION_REST);
    g->last_t = o.last_t;
    g->n_valid += o.k - o.n_back - o.n_skipped;
    g->n_assigned += o.n_assigned;
    g->n_back += o.n_back;
    g->n_outside += o.n_skipped;
    set_sync(g);
    return o.k;
}

/* Instance q's state (springtrack.instances.InstanceState): a tracking instance's
   trackers are all sensitive (the next spring update decides eq. 21 again), the others'
   none, and only tracking instances take events and run their springs. */
void fx_set_state(fx_set *g, int q, int32_t state)
{
    fx_state *s = g->inst[q];
    g->state[q] = state;
    s->sensitive_mask = state != FX_TRACKING ? 0
                        : s->n == 64 ? ~(uint64_t)0 : ((uint64_t)1 << s->n) - 1;
}

/* A set of the ni loaded states inst[0..ni), all tracking, the clocks and counts zero. */
int fx_set_init(fx_set *g, fx_state *const *inst, int32_t ni)
{
    int32_t q, t0 = 0, c = 0;
    if (ni < 1 || ni > FX_MAX_INSTANCES)
        return FX_ERR_CAPACITY;
    for (q = 0; q < ni; q++) {
        t0 += inst[q]->n;
        c += inst[q]->nc;
        if (inst[q]->width != inst[0]->width || inst[q]->height != inst[0]->height)
            return FX_ERR_RANGE;
    }
    if (t0 > FX_MAX_SET_TRACKERS || c > FX_MAX_SET_CONNECTIONS)
        return FX_ERR_CAPACITY;
    g->ni = ni;
    g->last_t = -((int64_t)1 << 62);
    g->n_valid = g->n_assigned = g->n_back = g->n_outside = g->n_spring_updates = 0;
    g->n_free = 0;
    for (q = 0, t0 = 0; q < ni; q++) {
        g->inst[q] = inst[q];
        g->own[q] = g->free0[q] = 0;
        g->sbox[q][0] = g->sbox[q][2] = -FX_SPRING_BOX_ALL;
        g->sbox[q][1] = g->sbox[q][3] = FX_SPRING_BOX_ALL;
        g->t0[q] = t0;
        t0 += inst[q]->n;
        fx_set_state(g, q, FX_TRACKING);
    }
    return FX_OK;
}

/* eq. (6) evaluated lazily at time t, Q.32 */
int64_t fx_activity(const fx_state *s, int i, int64_t t)
{
    return mulsh(s->act[i], decay(s, t - s->tlast[i]), 30);
}
