/* Microcontroller entry point of the fixed-point kernel (springtrack/csrc/fixed_step.c).
 *
 * Freestanding: no heap, no libc.  The kernel's state is one fixed-size struct
 * (mcu_state) with its spatial index (mcu_cells); the host (springtrack/mcu/emulator.py,
 * or a firmware's own loop) fills mcu_io and the static buffers below and calls
 * mcu_main(), which carries out mcu_io.cmd:
 *
 *   MCU_LOAD_MODEL  mcu_words[0..nwords): fixed_q.model_words      -> status
 *   MCU_SET_PARAMS  mcu_words[0..nwords): fixed_q.params_words     -> status
 *   MCU_RUN         mcu_events[0..nevents) with sampling every sample_us from next_t
 *                   (springtrack/_stepper.pyx's run_events): at most `cap` rows into
 *                   mcu_rows -> consumed, rows, next_t
 *   MCU_STEP        one event, mcu_events[0] -> status (winner or skip code)
 *   MCU_SNAPSHOT    one row at time t into mcu_rows[0]
 *   MCU_ENERGIES    every kind's energies into mcu_energy
 *   MCU_SPRINGS     one spring update
 *   MCU_MOVE        mcu_words[0..nwords): fixed_q.move_words (the instance moved rigidly
 *                   by a similarity, fx_move)                        -> status
 *
 * and then always refreshes mcu_counters.  A snapshot row is MCU_ROW_WORDS int64: t, the
 * three energy sums (Q.40), then per tracker x, y (Q.32), sxx, sxy, syy (Q.40), the
 * activity at t (Q.32) and flags (bit 0 active, bit 1 sensitive); beside it, in mcu_wire,
 * the row's TELEMETRY tracker records (csrc/fixed_telemetry.c, springtrack.wire), which
 * a firmware sends to the host as they are.
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

#define MCU_ROW_HEAD 4
#define MCU_ROW_TRACKER 7
#define MCU_ROW_WORDS (MCU_ROW_HEAD + MCU_ROW_TRACKER * FX_MAX_TRACKERS)
#define MCU_MODEL_WORDS (FX_MODEL_HEAD + FX_MODEL_TRACKER * FX_MAX_TRACKERS \
                         + FX_MODEL_CONNECTION * FX_MAX_CONNECTIONS)
#define MCU_MOVE_WORDS (FX_MOVE_HEAD + MCU_MODEL_WORDS)
#define MCU_WORDS (MCU_MOVE_WORDS > FX_PARAMS_WORDS ? MCU_MOVE_WORDS : FX_PARAMS_WORDS)
#define MCU_N_COUNTERS 14

enum { MCU_NOP = 0, MCU_LOAD_MODEL = 1, MCU_SET_PARAMS = 2, MCU_RUN = 3, MCU_STEP = 4,
       MCU_SNAPSHOT = 5, MCU_ENERGIES = 6, MCU_SPRINGS = 7, MCU_MOVE = 8 };

typedef struct {
    int64_t sample_us, next_t, t;       /* in: sampling; next_t also out */
    int32_t cmd, status, nwords, nevents, cap, consumed, rows, pad;
} mcu_io_t;

/* the layout constants, for the host (read from the symbol table, never written) */
__attribute__((used, section(".rodata.keep"))) const int32_t mcu_layout[8] = {FX_MAX_TRACKERS, FX_MAX_CONNECTIONS, MCU_EVENTS, MCU_ROWS,
                               MCU_CELLS, MCU_WORDS, MCU_ROW_WORDS, MCU_N_COUNTERS};

fx_state mcu_state;
uint64_t mcu_cells[MCU_CELLS];
mcu_io_t mcu_io;
int32_t mcu_words[MCU_WORDS];
fx_event mcu_events[MCU_EVENTS];
int64_t mcu_rows[MCU_ROWS][MCU_ROW_WORDS];
uint8_t mcu_wire[MCU_ROWS][FX_MAX_TRACKERS * FX_TELE_RECORD];
int64_t mcu_energy[3][FX_MAX_CONNECTIONS];
/* events_valid, events_assigned, skipped_back_in_time, skipped_outside_sensor,
   spring_updates, index_updates, saturated_position, saturated_activity, saturated_energy,
   saturated_inverse, last_t, mean_energy, n, state_resets */
int64_t mcu_counters[MCU_N_COUNTERS];

static void snapshot_row(fx_state *s, int64_t t, int64_t *row, uint8_t *wire)
{
    int i, k, q;
    fx_tele_records(s, t, wire);
    row[0] = t;
    fx_energies(s);                     /* the kinds the criterion does not use, when read */
    for (q = 0; q < 3; q++) {
        int64_t tot = 0;
        for (k = 0; k < s->nc; k++)
            tot += s->energy[q][k];
        row[1 + q] = tot;
    }
    row += MCU_ROW_HEAD;
    for (i = 0; i < s->n; i++, row += MCU_ROW_TRACKER) {
        int64_t a = fx_activity(s, i, t);
        row[0] = s->mx[i];
        row[1] = s->my[i];
        row[2] = s->sxx[i];
        row[3] = s->sxy[i];
        row[4] = s->syy[i];
        row[5] = a;
        row[6] = (a > s->act_thr) | (int64_t)((s->sensitive_mask >> i) & 1) << 1;
    }
}

/* springtrack/_stepper.pyx run_events, the sampling rule of csrc/sampling.h: next_t
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

static void run(fx_state *s, mcu_io_t *io)
{
    const int64_t never = (int64_t)(~(uint64_t)0 >> 1);
    int64_t k = 0, n = io->nevents, next_t = io->next_t;
    int32_t rows = 0;
    io->status = FX_OK;
    if (io->sample_us <= 0) {
        while (k < n) {
            k += fx_steps(s, mcu_events + k, n - k, never);
            if (k < n) {                    /* stopped at t == INT64_MAX: not a sample time */
                fx_step(s, mcu_events[k].t, mcu_events[k].x, mcu_events[k].y);
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
        k += fx_steps(s, mcu_events + k, n - k, next_t);
        if (k >= n) {
            k = n;
            break;
        }
        for (;;) {                          /* st_sample_due: fx_steps stopped here */
            next_t = st_next_sample(mcu_events[k].t, next_t, s->last_t, io->sample_us);
            if (mcu_events[k].t < next_t)
                break;
            if (rows >= io->cap || rows >= MCU_ROWS)
                goto full;
            snapshot_row(s, next_t, mcu_rows[rows], mcu_wire[rows]);
            rows++;
            next_t += io->sample_us;
        }
    }
full:
    io->consumed = (int32_t)k;
    io->rows = rows;
    io->next_t = next_t;
}

void mcu_main(void)
{
    fx_state *s = &mcu_state;
    mcu_io_t *io = &mcu_io;
    int k, q;
    switch (io->cmd) {
    case MCU_LOAD_MODEL:
        io->status = fx_load_model(s, mcu_words, io->nwords, mcu_cells, MCU_CELLS);
        break;
    case MCU_SET_PARAMS:
        io->status = fx_set_params(s, mcu_words, io->nwords);
        break;
    case MCU_RUN:
        run(s, io);
        break;
    case MCU_STEP:
        io->status = fx_step(s, mcu_events[0].t, mcu_events[0].x, mcu_events[0].y);
        break;
    case MCU_SNAPSHOT:
        snapshot_row(s, io->t, mcu_rows[0], mcu_wire[0]);
        break;
    case MCU_ENERGIES:
        fx_energies(s);
        for (q = 0; q < 3; q++)
            for (k = 0; k < s->nc; k++)
                mcu_energy[q][k] = s->energy[q][k];
        break;
    case MCU_SPRINGS:
        fx_springs(s);
        break;
    case MCU_MOVE:
        io->status = fx_move(s, mcu_words, io->nwords);
        break;
    default:
        break;
    }
    mcu_counters[0] = s->n_valid;
    mcu_counters[1] = s->n_assigned;
    mcu_counters[2] = s->n_back;
    mcu_counters[3] = s->n_outside;
    mcu_counters[4] = s->n_spring_updates;
    mcu_counters[5] = s->n_reindex;
    mcu_counters[6] = s->sat_position;
    mcu_counters[7] = s->sat_activity;
    mcu_counters[8] = s->sat_energy;
    mcu_counters[9] = s->sat_inverse;
    mcu_counters[10] = s->last_t;
    mcu_counters[11] = s->mean_energy;
    mcu_counters[12] = s->n;
    mcu_counters[13] = s->n_resets;
}

/* where the host points the return address: mcu_main returns here, and the emulator
   stops (a firmware would not call it) */
__attribute__((noinline, used)) void mcu_halt(void)
{
    for (;;)
        __asm__ volatile("");
}
