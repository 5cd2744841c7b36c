/* The sampling rule of every tracker loop, in C (springtrack/sampling.py states it and is
 * its Python mirror): a track sampled every P us of event time holds, at each sample time
 * T, the state after all events with t < T.
 *   - the first sample time is the smallest multiple of P >= the first event's time
 *     (st_first_sample); a loop that has seen no event holds ST_UNSET;
 *   - before an event at t with t >= the next sample time and t >= the last event time,
 *     one snapshot per sample time <= t (st_sample_due).  An event back in time is skipped
 *     by the kernel: it neither moves time on nor triggers a sample;
 *   - an empty stretch (no event) is sampled for ST_HOLD periods after its last event,
 *     then once at its end: its later sample times are skipped but the last one <= the
 *     next event's time (st_next_sample).  So at most ST_HOLD + 1 samples are taken
 *     before any one event: the samples of a stream are bounded by its events, not by its
 *     time span (a counter wrap, a paused recording, sparse events far apart).
 * Used by springtrack/backends/stepper.pyx (run_events), the kernels' batch steps (kernel/kernel.pyx
 * ksteps, fixed_step.c fx_steps: they stop before the event st_sample_due names),
 * springtrack/mcu/entry.c and, through run_events, firmware_sim/_fused.pyx.  Integer-only,
 * like fixed_step.c.
 */
#ifndef SPRINGTRACK_SAMPLING_H
#define SPRINGTRACK_SAMPLING_H

#include <stdint.h>

#define ST_UNSET INT64_MIN
#define ST_HOLD 4               /* sample periods an empty stretch is sampled for */

/* the smallest multiple of period (> 0) >= t0; C division truncates toward zero */
static inline int64_t st_first_sample(int64_t t0, int64_t period)
{
    int64_t q = t0 / period;
    if (q * period < t0)
        q += 1;
    return q * period;
}

/* snapshots are due before an event at t */
static inline int st_sample_due(int64_t t, int64_t next_t, int64_t last_t)
{
    return t >= next_t && t >= last_t;
}

/* The sample time to take next before an event at t for which snapshots are due: next_t,
   unless the stretch since the last event time last_t has had its ST_HOLD periods
   (next_t > last_t + ST_HOLD period) and next_t is before t: then the largest multiple of
   the period <= t (the stretch's end).  next_t is a multiple of the period, so that is
   next_t plus whole periods, added in doubling steps: no 64-bit division (a 32-bit core
   has none).  Event times within +-2^62 us and a period below 2^32 us keep every sum
   within int64. */
static inline int64_t st_next_sample(int64_t t, int64_t next_t, int64_t last_t, int64_t period)
{
    int64_t step;
    if (next_t - ST_HOLD * period <= last_t || next_t >= t)
        return next_t;
    while (t - next_t >= period) {
        step = period;
        while (t - next_t - step >= step)      /* the largest period 2^k <= t - next_t */
            step += step;
        next_t += step;
    }
    return next_t;
}

#endif
