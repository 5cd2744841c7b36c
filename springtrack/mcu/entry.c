/* Microcontroller entry point of the fixed-point kernel (springtrack/fixed/csrc/fixed_step.c).
 *
 * Freestanding: no heap, no libc.  The kernel's state is one fixed-size struct
 * (mcu_state) with its spatial index (mcu_cells); the host (springtrack/mcu/emulator.py,
 * or a firmware's own loop) fills mcu_io and the static buffers below and calls
 * mcu_main(), which carries out mcu_io.cmd:
 *
 *   MCU_LOAD_MODEL  mcu_words[0..nwords): fixed.q.model_words      -> status
 *   MCU_SET_PARAMS  mcu_words[0..nwords): fixed.q.params_words     -> status
 *   MCU_RUN         mcu_events[0..nevents) with sampling every sample_us from next_t
 *                   (springtrack/backends/stepper.pyx's run_events): at most `cap` rows into
 *                   mcu_rows -> consumed, rows, next_t
 *   MCU_STEP        one event, mcu_events[0] -> status (winner or skip code)
 *   MCU_SNAPSHOT    one row at time t into mcu_rows[0]
 *   MCU_ENERGIES    every kind's energies into mcu_energy
 *   MCU_SPRINGS     a spring update of every instance (their spring clocks kept)
 *   MCU_MOVE        mcu_words[0..nwords): fixed.q.move_words (the instance moved rigidly
 *                   by a similarity, fx_move)                        -> status
 *   MCU_SET_INIT    instances (springtrack.instances): mcu_words[0] = ni instances loaded
 *                   (MCU_LOAD_MODEL, MCU_SET_PARAMS with inst = 0 .. ni-1) run as one set
 *                   (fx_set: one event assignment, the instances' states) from here on, in
 *                   a build with MCU_SET                             -> status
 *   MCU_SET_STATE   instance inst's state (instances.InstanceState) = mcu_words[0]
 *   MCU_RELOCATE    mcu_words[0..nwords): fixed.q.relocate_words (trackers of the instance
 *                   put elsewhere one by one, fx_relocate)            -> status
 *
 * MCU_LOAD_MODEL, MCU_SET_PARAMS, MCU_MOVE, MCU_RELOCATE and MCU_ENERGIES act on instance
 * mcu_io.inst
 * (0 with one instance); loading an instance of a set again (placing it) keeps the set's
 * clock and the replaced state's counts.  Every call then refreshes mcu_counters, and per
 * instance mcu_means (eq. 13's mean energy, Q.40) and mcu_frames (the similarity frame:
 * c, s Q.28, gx, gy Q.32).  A snapshot row is MCU_ROW_WORDS int64: t, the three energy
 * sums (Q.40, every instance's), then per tracker (of every instance, in order) x, y
 * (Q.32, predicted to t: eq. M1), sxx, sxy, syy (Q.40), the activity at t (Q.32), flags
 * (bit 0 active, bit 1 sensitive, bits 2-3 its instance's state) and the velocity vx, vy
 * (Q.32 px/us, eq. M7); beside it, in mcu_wire, the row's TELEMETRY
 * tracker records (fixed/csrc/fixed_telemetry.c, springtrack.wire), which a firmware sends to
 * the host as they are.
 */
#include "fixed_step.h"
#include "fixed_telemetry.h"
#include "sampling.h"

#ifndef MCU_EVENTS
#define MCU_EVENTS 256                  /* event buffer, records */
#endif
#ifndef MCU_ROWS
#define MCU_ROWS 4                      /* snapshot rows per MCU_RUN */
#endif
#ifndef MCU_CELLS
#define MCU_CELLS 14400                 /* spatial index cells: 1280 x 720 px at 8 x 8 */
#endif

#ifndef MCU_ALL_ENERGIES                /* rows carry every energy kind's sum; 0: only the */
#define MCU_ALL_ENERGIES 1              /* kind the criterion uses (a firmware's telemetry) */
#endif

#ifndef MCU_INSTANCES
#define MCU_INSTANCES 1                 /* model instances (at most FX_MAX_INSTANCES) */
#endif
#ifndef MCU_SET
#define MCU_SET (MCU_INSTANCES > 1)     /* the set's code (fx_set) is built */
#endif
#ifndef MCU_SET_TRACKERS
#define MCU_SET_TRACKERS FX_MAX_TRACKERS   /* trackers of all instances together */
#endif

#define MCU_ROW_HEAD 4
#define MCU_ROW_TRACKER 9
#define MCU_ROW_WORDS (MCU_ROW_HEAD + MCU_ROW_TRACKER * MCU_SET_TRACKERS)
#define MCU_MODEL_WORDS (FX_MODEL_HEAD + FX_MODEL_TRACKER * FX_MAX_TRACKERS \
                         + FX_MODEL_CONNECTION * FX_MAX_CONNECTIONS)
#define MCU_MOVE_WORDS (FX_MOVE_HEAD + MCU_MODEL_WORDS)
#ifndef MCU_WORDS                       /* a firmware that loads from its own buffer: 1 */
#define MCU_WORDS (MCU_MOVE_WORDS > FX_PARAMS_WORDS ? MCU_MOVE_WORDS : FX_PARAMS_WORDS)
#endif
#define MCU_N_COUNTERS 14
#define MCU_N_REPLACED 6                /* index_updates .. state_resets of placed instances */

enum { MCU_NOP = 0, MCU_LOAD_MODEL = 1, MCU_SET_PARAMS = 2, MCU_RUN = 3, MCU_STEP = 4,
       MCU_SNAPSHOT = 5, MCU_ENERGIES = 6, MCU_SPRINGS = 7, MCU_MOVE = 8, MCU_SET_INIT = 9,
       MCU_SET_STATE = 10, MCU_RELOCATE = 11 };

typedef struct {
    int64_t sample_us, next_t, t;       /* in: sampling; next_t also out */
    int32_t cmd, status, nwords, nevents, cap, consumed, rows, inst;
} mcu_io_t;

/* the layout constants, for the host (read from the symbol table, never written) */
__attribute__((used, section(".rodata.keep"))) const int32_t mcu_layout[10] = {FX_MAX_TRACKERS, FX_MAX_CONNECTIONS, MCU_EVENTS, MCU_ROWS,
                               MCU_CELLS, MCU_WORDS, MCU_ROW_WORDS, MCU_N_COUNTERS,
                               MCU_INSTANCES, MCU_SET_TRACKERS};

fx_state mcu_state[MCU_INSTANCES];
uint64_t mcu_cells[MCU_INSTANCES * MCU_CELLS];
fx_set mcu_set;                         /* ni = 0: one instance, mcu_state[0] alone */
/* the set is in use: never in a build without MCU_SET, whose code then has no fx_set */
#define SET_ON (MCU_SET && mcu_set.ni)
mcu_io_t mcu_io;
int32_t mcu_words[MCU_WORDS];
fx_event mcu_events[MCU_EVENTS];
int64_t mcu_rows[MCU_ROWS][MCU_ROW_WORDS];
uint8_t mcu_wire[MCU_ROWS][MCU_SET_TRACKERS * FX_TELE_RECORD];
int64_t mcu_energy[3][FX_MAX_CONNECTIONS];
/* events_valid, events_assigned, skipped_back_in_time, skipped_outside_sensor,
   spring_updates, index_updates, saturated_position, saturated_activity, saturated_energy,
   saturated_inverse, last_t, mean_energy, n, state_resets */
int64_t mcu_counters[MCU_N_COUNTERS];
int64_t mcu_replaced[MCU_N_REPLACED];
int64_t mcu_means[MCU_INSTANCES];
int64_t mcu_frames[MCU_INSTANCES][4];

/* one instance's trackers into a row (from its first tracker's words) and its TELEMETRY
   records; adds its energies to the row's sums */
static void instance_row(fx_state *s, int64_t t, int32_t state, int64_t *row, int64_t *sums,
                         uint8_t *wire)
{
    int i, k, q;
    fx_tele_records(s, t, wire);
    if (MCU_ALL_ENERGIES)
        fx_energies(s);                 /* the kinds the criterion does not use, when read */
    for (q = 0; q < 3; q++)
        for (k = 0; k < s->nc; k++)
            sums[q] += s->energy[q][k];
    for (i = 0; i < s->n; i++, row += MCU_ROW_TRACKER) {
        int64_t a = fx_activity(s, i, t);
        fx_predicted(s, i, t, &row[0], &row[1]);       /* eq. (M1): the means at t */
        row[2] = s->sxx[i];
        row[3] = s->sxy[i];
        row[4] = s->syy[i];
        row[5] = a;
        row[6] = (a > s->act_thr) | (int64_t)((s->sensitive_mask >> i) & 1) << 1
                 | (int64_t)state << 2;
        row[7] = s->vx[i];
        row[8] = s->vy[i];
    }
}

static void snapshot_row(int64_t t, int64_t *row, uint8_t *wire)
{
    int q, ni = SET_ON ? mcu_set.ni : 1;
    row[0] = t;
    row[1] = row[2] = row[3] = 0;
    for (q = 0; q < ni; q++) {
        int32_t t0 = SET_ON ? mcu_set.t0[q] : 0;
        instance_row(&mcu_state[q], t, SET_ON ? mcu_set.state[q] : FX_TRACKING,
                     row + MCU_ROW_HEAD + MCU_ROW_TRACKER * t0, row + 1,
                     wire + FX_TELE_RECORD * t0);
    }
}

/* the event loop's calls, on the one instance or the set */
static int64_t steps(const fx_event *ev, int64_t n, int64_t t_stop)
{
    return SET_ON ? fx_set_steps(&mcu_set, ev, n, t_stop)
                      : fx_steps(&mcu_state[0], ev, n, t_stop);
}

static int step(const fx_event *e)
{
    return SET_ON ? fx_set_step(&mcu_set, e->t, e->x, e->y, e->p)
                      : fx_step(&mcu_state[0], e->t, e->x, e->y, e->p);
}

/* springtrack/backends/stepper.pyx run_events, the sampling rule of csrc/sampling.h: next_t
   ST_UNSET becomes the first sample time after the first event; before an event for which
   st_sample_due(t, next_t, the last event time), one row per sample time <= t (the state
   after all earlier events), an empty stretch's past its ST_HOLD periods skipped
   (st_next_sample); stops when the rows are full */
/* st_first_sample (sampling.h) without its 64-bit division, which a 32-bit core does not
   have: with r = |t0| mod p (fx_udiv64: 32-bit divisions), the smallest multiple of p >=
   t0 is t0 - r (+ p if r) for t0 >= 0, t0 + r below; p < 2^32 */
static int64_t first_sample(int64_t t0, int64_t p)
{
    uint32_t r;
    if (t0 >= 0) {
        fx_udiv64((uint64_t)t0, (uint32_t)p, &r);
        return t0 - r + (r ? p : 0);
    }
    fx_udiv64((uint64_t)0 - (uint64_t)t0, (uint32_t)p, &r);
    return t0 + r;
}

static int64_t last_t(void)
{
    return SET_ON ? mcu_set.last_t : mcu_state[0].last_t;
}

static void run(mcu_io_t *io)
{
    const int64_t never = (int64_t)(~(uint64_t)0 >> 1);
    int64_t k = 0, n = io->nevents, next_t = io->next_t;
    int32_t rows = 0;
    io->status = FX_OK;
    if (io->sample_us <= 0) {
        while (k < n) {
            k += steps(mcu_events + k, n - k, never);
            if (k < n) {                    /* stopped at t == INT64_MAX: not a sample time */
                step(&mcu_events[k]);
                k++;
            }
        }
        io->consumed = (int32_t)n;
        io->rows = 0;
        return;
    }
    if (io->sample_us >> 32) {              /* a period of 71 minutes or more */
        io->status = FX_ERR_RANGE;
        io->consumed = io->rows = 0;
        return;
    }
    if (n > 0 && next_t == ST_UNSET)
        next_t = first_sample(mcu_events[0].t, io->sample_us);
    for (;;) {
        k += steps(mcu_events + k, n - k, next_t);
        if (k >= n) {
            k = n;
            break;
        }
        for (;;) {                          /* st_sample_due: fx_steps stopped here */
            next_t = st_next_sample(mcu_events[k].t, next_t, last_t(), io->sample_us);
            if (mcu_events[k].t < next_t)
                break;
            if (rows >= io->cap || rows >= MCU_ROWS)
                goto full;
            snapshot_row(next_t, mcu_rows[rows], mcu_wire[rows]);
            rows++;
            next_t += io->sample_us;
        }
    }
full:
    io->consumed = (int32_t)k;
    io->rows = rows;
    io->next_t = next_t;
}

/* instance q loaded again (placed) in a set: the replaced state's counts kept, the set's
   clock and event counts copied, tracking */
static int32_t reload(int q, const int32_t *w, int32_t nw)
{
    fx_state *s = &mcu_state[q];
    int32_t rc;
    if (SET_ON) {
        mcu_replaced[0] += s->n_reindex;
        mcu_replaced[1] += s->sat_position;
        mcu_replaced[2] += s->sat_activity;
        mcu_replaced[3] += s->sat_energy;
        mcu_replaced[4] += s->sat_inverse;
        mcu_replaced[5] += s->n_resets;
    }
    rc = fx_load_model(s, w, nw, mcu_cells + q * MCU_CELLS, MCU_CELLS);
    if (rc == FX_OK && SET_ON) {
        s->last_t = mcu_set.last_t;
        s->n_valid = mcu_set.n_valid;
        s->n_back = mcu_set.n_back;
        s->n_outside = mcu_set.n_outside;
        fx_set_state(&mcu_set, q, FX_TRACKING);
    }
    return rc;
}

static int32_t set_init(int32_t ni)
{
#if MCU_SET
    fx_state *inst[MCU_INSTANCES];
    int q;
    if (ni < 1 || ni > MCU_INSTANCES)
        return FX_ERR_CAPACITY;
    for (q = 0; q < ni; q++)
        inst[q] = &mcu_state[q];
    return fx_set_init(&mcu_set, inst, ni);
#else
    (void)ni;
    return FX_ERR_CAPACITY;
#endif
}

static void counters(void)
{
    int q, ni = SET_ON ? mcu_set.ni : 1;
    fx_state *s = &mcu_state[0];
    for (q = 5; q < 10; q++)
        mcu_counters[q] = mcu_replaced[q - 5];
    mcu_counters[12] = 0;
    mcu_counters[13] = mcu_replaced[5];
    for (q = 0; q < ni; q++) {
        fx_state *e = &mcu_state[q];
        mcu_counters[5] += e->n_reindex;
        mcu_counters[6] += e->sat_position;
        mcu_counters[7] += e->sat_activity;
        mcu_counters[8] += e->sat_energy;
        mcu_counters[9] += e->sat_inverse;
        mcu_counters[12] += e->n;
        mcu_counters[13] += e->n_resets;
        mcu_means[q] = e->mean_energy;
        mcu_frames[q][0] = e->frame_c;
        mcu_frames[q][1] = e->frame_s;
        mcu_frames[q][2] = e->frame_gx;
        mcu_frames[q][3] = e->frame_gy;
    }
    if (SET_ON) {
        mcu_counters[0] = mcu_set.n_valid;
        mcu_counters[1] = mcu_set.n_assigned;
        mcu_counters[2] = mcu_set.n_back;
        mcu_counters[3] = mcu_set.n_outside;
        mcu_counters[4] = mcu_set.n_spring_updates;
        mcu_counters[10] = mcu_set.last_t;
    } else {
        mcu_counters[0] = s->n_valid;
        mcu_counters[1] = s->n_assigned;
        mcu_counters[2] = s->n_back;
        mcu_counters[3] = s->n_outside;
        mcu_counters[4] = s->n_spring_updates;
        mcu_counters[10] = s->last_t;
    }
    mcu_counters[11] = s->mean_energy;
}

void mcu_main(void)
{
    mcu_io_t *io = &mcu_io;
    int k, q, g = io->inst;
    fx_state *s = &mcu_state[0];
    if (g < 0 || g >= MCU_INSTANCES || (SET_ON && g >= mcu_set.ni)) {
        io->status = FX_ERR_CAPACITY;
        counters();
        return;
    }
    s += g;
    switch (io->cmd) {
    case MCU_LOAD_MODEL:
        io->status = reload(g, mcu_words, io->nwords);
        break;
    case MCU_SET_PARAMS:
        io->status = fx_set_params(s, mcu_words, io->nwords);
        break;
    case MCU_RUN:
        run(io);
        break;
    case MCU_STEP:
        io->status = step(&mcu_events[0]);
        break;
    case MCU_SNAPSHOT:
        snapshot_row(io->t, mcu_rows[0], mcu_wire[0]);
        break;
    case MCU_ENERGIES:
        fx_energies(s);
        for (q = 0; q < 3; q++)
            for (k = 0; k < s->nc; k++)
                mcu_energy[q][k] = s->energy[q][k];
        break;
    case MCU_SPRINGS:
        if (SET_ON)
            fx_set_springs(&mcu_set);
        else
            fx_springs(s);
        break;
    case MCU_MOVE:
        io->status = fx_move(s, mcu_words, io->nwords);
        break;
    case MCU_RELOCATE:
        io->status = fx_relocate(s, mcu_words, io->nwords);
        break;
    case MCU_SET_INIT:
        io->status = set_init(mcu_words[0]);
        break;
    case MCU_SET_STATE:
        if (SET_ON)
            fx_set_state(&mcu_set, g, mcu_words[0]);
        break;
    default:
        break;
    }
    counters();
}

/* where the host points the return address: mcu_main returns here, and the emulator
   stops (a firmware would not call it) */
__attribute__((noinline, used)) void mcu_halt(void)
{
    for (;;)
        __asm__ volatile("");
}
