/* The tracking side of the firmware image: the event stream (a DMA-style memory region,
 * springtrack/mcu/stream.py), its EVT 2.0 / 2.1 decoder fused with the fixed-point kernel
 * (entry.c's MCU_RUN, fixed/csrc/fixed_step.c: the host's --backend fixed, compiled for the
 * core), sampling every ENGINE_PERIOD_US of event time into TELEMETRY frames.
 *   engine_init()      read the stream's header (geometry, format)
 *   engine_load(...)   a checked model and/or parameter words into the kernel
 *   engine_start/stop  run from where it stopped; after the stream ended, replay it
 *   engine_work()      decode and track one batch of words; 0 when there is nothing to do
 */
#ifndef SPRINGTRACK_FW_ENGINE_H
#define SPRINGTRACK_FW_ENGINE_H

#include <stdint.h>

#define ENGINE_PERIOD_US 1000            /* telemetry period, event time (firmware-sim's) */

enum { ST_IDLE = 0, ST_RUNNING, ST_STOPPED, ST_ENDED };

typedef struct {
    uint32_t state, loaded, format, width, height, word_bytes;
    uint32_t stream_ok;                  /* the stream region holds a valid header */
    uint32_t pos, nbytes;                /* read position and size of the words */
    int64_t next_t;                      /* the next sample time (ST_UNSET: none yet) */
    uint32_t generation;
    /* decoder: time base (springtrack/io/timebase.pxd) and counters */
    int64_t epoch, last_raw, th;
    uint32_t await_th;
    uint64_t words, events_decoded, events_tracked, gap_skipped, outside_sensor, time_high,
        triggers, others, unknown_type, time_wraps, time_backwards, snapshots, replays;
    uint64_t work_ticks;                 /* SysTick ticks spent decoding and tracking */
    uint64_t decode_ticks;               /* ... of which decoding */
} engine_t;

extern engine_t eng;

void engine_init(void);
int engine_load(const int32_t *model, uint32_t nmodel, const int32_t *params, uint32_t nparams);
void engine_start(void);
void engine_stop(void);
void engine_reset(void);
int engine_work(void);
int64_t engine_last_t(void);

/* outputs.c: a snapshot's TELEMETRY (records of n trackers, the energy as float32 bits, the
   velocity block's 2n codes or 0) */
void proto_telemetry(int64_t t, uint32_t energy_bits, const uint8_t *records, uint32_t n,
                     const int16_t *velocity);
void proto_stream_ended(void);
/* proto.c: ENERGIES (each connection's energy of one kind as float32 bits), sent while a
   host session receives */
int proto_receiving(void);
void proto_energies(int64_t t, uint32_t kind, const uint32_t *bits, uint32_t n);

#endif
