/* engine.h: the event stream, its decoder and the kernel's sampling loop. */
#include "engine.h"
#include "board.h"
#include "fixed_step.h"
#include "fixed_telemetry.h"
#include "sampling.h"
#include "wire_codes.h"
#include "param_specs.h"
#include "xfloat.h"
#include "springtrack/io/evt2_types.h"
#include "springtrack/io/evt21_types.h"

/* entry.c's interface (the kernel's static state and its command) */
#define MCU_RUN 3
typedef struct {
    int64_t sample_us, next_t, t;
    int32_t cmd, status, nwords, nevents, cap, consumed, rows, inst;
} mcu_io_t;
extern mcu_io_t mcu_io;
extern uint64_t mcu_cells[];
extern fx_event mcu_events[];
extern int64_t mcu_counters[];
extern fx_state mcu_state[];
void mcu_main(void);
#ifndef MCU_EVENTS
#define MCU_EVENTS 256
#endif
#ifndef MCU_ROWS
#define MCU_ROWS 4
#endif
#define MCU_ROW_TRACKER 9               /* entry.c's row: per tracker x, y, sxx, sxy, syy, */
#define MCU_ROW_WORDS (4 + MCU_ROW_TRACKER * FX_MAX_TRACKERS)   /* activity, flags, vx, vy */
extern int64_t mcu_rows[MCU_ROWS][MCU_ROW_WORDS];
extern uint8_t mcu_wire[MCU_ROWS][FX_MAX_TRACKERS * FX_TELE_RECORD];

engine_t eng;
static uint32_t nevents;                 /* decoded events waiting in mcu_events */

static const volatile uint32_t *stream_head(void)
{
    return (const volatile uint32_t *)STREAM_BASE;
}

void engine_init(void)
{
    const volatile uint32_t *h = stream_head();
    eng.next_t = ST_UNSET;
    eng.stream_ok = h[0] == STREAM_MAGIC && (h[1] == STREAM_FMT_EVT2 || h[1] == STREAM_FMT_EVT21)
                    && h[2] >= 1 && h[2] <= 2048 && h[3] >= 1 && h[3] <= 2048
                    && h[4] <= STREAM_BYTES - STREAM_HDR;
    if (!eng.stream_ok)
        return;
    eng.format = h[1];
    eng.width = h[2];
    eng.height = h[3];
    eng.nbytes = h[4];
    eng.word_bytes = eng.format == STREAM_FMT_EVT2 ? 4 : 8;
    eng.await_th = 1;
    eng.last_raw = -1;
}

int64_t engine_last_t(void)
{
    return eng.loaded ? mcu_counters[10] : 0;
}

int engine_load(const int32_t *model, uint32_t nmodel, const int32_t *params, uint32_t nparams)
{
    int rc;
    if (model) {                         /* fx_load_model / fx_set_params straight from the */
        rc = fx_load_model(&mcu_state[0], model, (int32_t)nmodel, mcu_cells, MCU_CELLS);
        if (rc != FX_OK) {               /* upload buffer (entry.c's mcu_words is unused) */
            eng.loaded = 0;
            return rc;
        }
        eng.next_t = ST_UNSET;           /* a new kernel samples from its first event */
        nevents = 0;
    }
    rc = fx_set_params(&mcu_state[0], params, (int32_t)nparams);
    if (rc != FX_OK) {
        if (model)
            eng.loaded = 0;
        return rc;
    }
    eng.loaded = 1;
    return FX_OK;
}

void engine_start(void)
{
    if (eng.state == ST_ENDED) {         /* replay the stream from its start */
        eng.pos = 0;
        eng.await_th = 1;
        eng.replays++;
    }
    eng.state = ST_RUNNING;
}

void engine_stop(void)
{
    if (eng.state == ST_RUNNING)
        eng.state = ST_STOPPED;
}

void engine_reset(void)
{
    nevents = 0;
}

/* springtrack/io/timebase.pxd timebase_update: the counter's new value, wraps and
   backward jumps rebased */
static int64_t timebase(uint32_t raw, int bits)
{
    int64_t r = raw, last = eng.last_raw;
    if (last >= 0 && r < last) {
        if (last - r > ((int64_t)1 << (bits - 1))) {
            eng.epoch += (int64_t)1 << bits;
            eng.time_wraps++;
        } else {
            eng.epoch += last - r + 1;
            eng.time_backwards++;
        }
    }
    eng.last_raw = r;
    return eng.epoch + r;
}

static void put_event(int64_t t, uint32_t x, uint32_t y, uint32_t p)
{
    eng.events_decoded++;
    if (eng.await_th) {                  /* no time base yet: firmware_sim's fused loop */
        eng.gap_skipped++;               /* discards these, counted */
        return;
    }
    mcu_events[nevents].t = t;
    mcu_events[nevents].x = (uint16_t)x;
    mcu_events[nevents].y = (uint16_t)y;
    mcu_events[nevents].p = (uint8_t)p;
    nevents++;
}

/* one EVT 2.0 word (springtrack/io/evt2.pxd evt2_decode_words) */
static void evt2_word(uint32_t v)
{
    uint32_t typ = evt2_type(v), x, y;
    if (typ == EVT2_CD_OFF || typ == EVT2_CD_ON) {
        x = evt2_x(v);
        y = evt2_y(v);
        if (x >= eng.width || y >= eng.height) {
            eng.outside_sensor++;
            return;
        }
        put_event(eng.th | evt2_t_low(v), x, y, typ);
    } else if (typ == EVT2_EVT_TIME_HIGH) {
        eng.time_high++;
        eng.th = timebase(evt2_time_high(v), EVT2_TH_BITS) << EVT2_TH_SHIFT;
        eng.await_th = 0;
    } else if (typ == EVT2_EXT_TRIGGER) {
        eng.triggers++;
    } else if (typ == EVT2_OTHERS || typ == EVT2_CONTINUED) {
        eng.others++;
    } else {
        eng.unknown_type++;
    }
}

/* one EVT 2.1 word (springtrack/io/evt21.pxd evt21_decode_word): an event per set bit of
   its mask, columns ascending */
static void evt21_word(uint64_t v)
{
    uint32_t typ = evt21_type(v), m, x, y, xi;
    if (typ == EVT21_EVT_NEG || typ == EVT21_EVT_POS) {
        m = evt21_mask(v);
        x = evt21_x(v);
        y = evt21_y(v);
        while (m) {
            xi = x + (uint32_t)__builtin_ctz(m);
            m &= m - 1;
            if (y >= eng.height || xi >= eng.width) {
                eng.outside_sensor++;
                continue;
            }
            put_event(eng.th | evt21_t_low(v), xi, y, typ);
        }
    } else if (typ == EVT21_EVT_TIME_HIGH) {
        eng.time_high++;
        eng.th = timebase(evt21_time_high(v), EVT21_TH_BITS) << EVT21_TH_SHIFT;
        eng.await_th = 0;
    } else if (typ == EVT21_EXT_TRIGGER) {
        eng.triggers++;
    } else if (typ == EVT21_OTHERS || typ == EVT21_CONTINUED) {
        eng.others++;
    } else {
        eng.unknown_type++;
    }
}

/* EVT 2.0 words while the time base is known: change-detection words inline (their fields
   and checks those of evt2_word), any other word through evt2_word; returns the words used */
static uint32_t evt2_run(const uint32_t *w, uint32_t nw)
{
    uint32_t i = 0, k = nevents, W = eng.width, H = eng.height;
    int64_t th = eng.th;
    while (i < nw && k < MCU_EVENTS) {
        uint32_t v = w[i++], typ = evt2_type(v), x, y;
        if (typ > EVT2_CD_ON) {
            evt2_word(v);                /* time high (th changes), trigger, other */
            th = eng.th;
            continue;
        }
        x = evt2_x(v);
        y = evt2_y(v);
        if (x >= W || y >= H) {
            eng.outside_sensor++;
            continue;
        }
        mcu_events[k].t = th | evt2_t_low(v);
        mcu_events[k].x = (uint16_t)x;
        mcu_events[k].y = (uint16_t)y;
        mcu_events[k].p = (uint8_t)typ;
        k++;
    }
    eng.events_decoded += k - nevents;
    nevents = k;
    return i;
}

/* decode words until the event buffer has no room for one more word's events (the region
   is read as the camera interface's DMA left it: words are not written while decoded) */
static void decode(void)
{
    const uint8_t *p = (const uint8_t *)STREAM_BASE + STREAM_HDR;
    uint32_t room = eng.format == STREAM_FMT_EVT2 ? 1 : 32, used;
    while (eng.pos + eng.word_bytes <= eng.nbytes && nevents + room <= MCU_EVENTS) {
        const uint32_t *w = (const uint32_t *)(const void *)(p + eng.pos);
        if (eng.format == STREAM_FMT_EVT2 && !eng.await_th) {
            used = evt2_run(w, (eng.nbytes - eng.pos) / 4);
        } else {
            if (eng.format == STREAM_FMT_EVT2)
                evt2_word(w[0]);
            else
                evt21_word((uint64_t)w[0] | (uint64_t)w[1] << 32);
            used = 1;
        }
        eng.pos += used * eng.word_bytes;
        eng.words += used;
    }
}

/* the energy of a row for the telemetry: firmware_sim's (double)sum * 2^-40 / nc, then
   float32, rounded as those two IEEE operations round (to nearest, ties to even), in
   integers: no floating point on the core */
static uint64_t round_bits(uint64_t m, int drop, int sticky)
{
    uint64_t q, rem, half;
    if (drop <= 0)
        return m << -drop;
    q = m >> drop;
    rem = m & (((uint64_t)1 << drop) - 1);
    half = (uint64_t)1 << (drop - 1);
    if (rem > half || (rem == half && (sticky || (q & 1))))
        q++;
    return q;
}

static int bitlen(uint64_t v)
{
    int n = 0;
    while (v) {
        n++;
        v >>= 1;
    }
    return n;
}

static uint32_t energy_f32(int64_t sum, int32_t nc)
{
    uint64_t m, q;
    uint32_t r, sign = 0;
    int e, len;
    if (nc <= 0 || sum == 0)
        return 0;
    if (sum < 0) {
        sign = 0x80000000u;
        m = (uint64_t)0 - (uint64_t)sum;
    } else {
        m = (uint64_t)sum;
    }
    e = -40;                             /* value = m 2^e */
    len = bitlen(m);
    if (len > 53) {                      /* int64 -> double */
        m = round_bits(m, len - 53, 0);
        e += len - 53;
        if (bitlen(m) > 53) {
            m >>= 1;
            e++;
        }
    }
    len = bitlen(m);                     /* normalise to 53 bits, then divide by nc */
    m <<= 53 - len;
    e -= 53 - len;
    q = fx_udiv64(m << 10, (uint32_t)nc, &r);       /* >= 56 significant bits */
    e -= 10;
    len = bitlen(q);
    m = round_bits(q, len - 53, r != 0);          /* the double quotient */
    e += len - 53;
    if (bitlen(m) > 53) {
        m >>= 1;
        e++;
    }
    len = bitlen(m);                     /* double -> float32: 24 bits */
    q = round_bits(m, len - 24, 0);
    e += len - 24;
    if (bitlen(q) > 24) {
        q >>= 1;
        e++;
    }
    /* q 2^e with 2^23 <= q < 2^24: biased exponent e + 23 + 127 */
    if (e + 23 + 127 >= 255)
        return sign | 0x7F800000u;
    if (e + 23 + 127 <= 0)
        return sign;                     /* below float32's normal range: not reached */
    return sign | (uint32_t)(e + 23 + 127) << 23 | ((uint32_t)q & 0x7FFFFFu);
}

/* ENERGIES as firmware_sim sends them: with the last snapshot of a batch, at most once per
   WIRE_ENERGY_PERIOD_US of event time while a host receives; the criterion's kind, each connection's energy of
   the last spring update (fx_springs keeps that kind current) as float64 then float32 */
static void energies(int64_t t)
{
    static int64_t next = ST_UNSET;
    static uint32_t bits[FX_MAX_CONNECTIONS];
    const fx_state *s = &mcu_state[0];
    int32_t k;
    if (!proto_receiving() || (next != ST_UNSET && t < next))
        return;
    next = t + WIRE_ENERGY_PERIOD_US;
    for (k = 0; k < s->nc; k++)
        bits[k] = energy_f32(s->energy[s->ekind][k], 1);
    proto_energies(t, (uint32_t)s->ekind, bits, (uint32_t)s->nc);
}

/* TELEMETRY's velocity block (wire.quantise_velocities) of a row: each tracker's vx, vy
   (Q.32 px/us, eq. M7) as the fixed kernel's px/s double, then rint(v / VEL_UNIT) clipped
   to int16; 0 (no block) when every code is 0 (the motion model off) */
static const int16_t *velocities(const int64_t *row, int32_t n)
{
    static int16_t v[2 * FX_MAX_TRACKERS];
    int32_t i, any = 0;
    for (i = 0; i < 2 * n; i++) {
        int64_t q = row[4 + MCU_ROW_TRACKER * (i >> 1) + 7 + (i & 1)];
        dbits_t px_s = d_mul(d_from_int(q), Q_VEL_UNIT);
        q = d_round_scaled(d_div(px_s, WIRE_VEL_UNIT), 0);
        v[i] = (int16_t)(q > 0x7FFF ? 0x7FFF : q < -0x7FFF ? -0x7FFF : q);
        any |= v[i];
    }
    return any ? v : 0;
}

int engine_work(void)
{
    uint32_t k, rows;
    fx_state *s = &mcu_state[0];
    uint32_t t0 = board_ticks();
    if (eng.state != ST_RUNNING || !eng.loaded || !eng.stream_ok)
        return 0;
    decode();
    eng.decode_ticks += (t0 - board_ticks()) & 0xFFFFFFu;
    if (nevents == 0 && eng.pos + eng.word_bytes > eng.nbytes) {
        eng.state = ST_ENDED;
        proto_stream_ended();
        return 0;
    }
    mcu_io.cmd = MCU_RUN;
    mcu_io.sample_us = ENGINE_PERIOD_US;
    mcu_io.next_t = eng.next_t;
    mcu_io.nevents = (int32_t)nevents;
    mcu_io.cap = MCU_ROWS;
    mcu_io.inst = 0;
    mcu_main();
    eng.next_t = mcu_io.next_t;
    eng.work_ticks += (t0 - board_ticks()) & 0xFFFFFFu;    /* SysTick counts down, 24 bits */
    rows = (uint32_t)mcu_io.rows;
    for (k = 0; k < rows; k++) {
        eng.snapshots++;
        proto_telemetry(mcu_rows[k][0], energy_f32(mcu_rows[k][1 + s->ekind], s->nc),
                        mcu_wire[k], (uint32_t)s->n, velocities(mcu_rows[k], s->n));
    }
    if (rows)
        energies(mcu_rows[rows - 1][0]);
    eng.events_tracked += (uint32_t)mcu_io.consumed;
    for (k = (uint32_t)mcu_io.consumed; k < nevents; k++)     /* what the rows cut short */
        mcu_events[k - (uint32_t)mcu_io.consumed] = mcu_events[k];
    nevents -= (uint32_t)mcu_io.consumed;
    return 1;
}
