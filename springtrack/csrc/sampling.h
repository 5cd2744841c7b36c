/* The sampling rule of every tracker loop, in C (springtrack/sampling.py states it and is
 * its Python mirror): a track sampled every P us of event time holds, at each sample time
 * T, the state after all events with t < T.
 *   - the first sample time is the smallest multiple of P >= the first event's time
 *     (st_first_sample); a loop that has seen no event holds ST_UNSET;
 *   - before an event at t with t >= the next sample time and t >= the last event time,
 *     one snapshot per sample time <= t (st_sample_due).  An event back in time is skipped
 *     by the kernel: it neither moves time on nor triggers a sample.
 * Used by springtrack/_stepper.pyx (run_events), the kernels' batch steps (_kernel.pyx
 * ksteps, fixed_step.c fx_steps: they stop before the event st_sample_due names) and,
 * through run_events, firmware_sim/_fused.pyx.  Integer-only, like fixed_step.c.
 */
#ifndef SPRINGTRACK_SAMPLING_H
#define SPRINGTRACK_SAMPLING_H

#include <stdint.h>

#define ST_UNSET INT64_MIN

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

#endif
