"""The sampling rule of every tracker loop, in Python: a track sampled every ``period`` µs
of event time holds, at each sample time T, the state after all events with t < T.

* The first sample time is the smallest multiple of the period >= the first event's
  time (:func:`first_sample_time`); a loop that has not seen an event yet holds
  :data:`UNSET`.
* Before an event at t with t >= the next sample time and t >= the last event time, one
  snapshot is taken per sample time <= t (:func:`sample_due`).  An event back in time
  (t < the last event time) is skipped by the kernel, so it neither moves time on nor
  triggers a sample.
* An empty stretch (no event) is sampled for :data:`HOLD` periods after its last event
  (the activities' decay, eq. 6, over its start), then once at its end: its later sample
  times are skipped but the last one <= the next event's time, which holds the state as the
  stretch left it (:func:`next_sample`); sampling goes on from there.  So a stream's samples
  are bounded by its events, at most :data:`PER_EVENT` (HOLD + 1) before each event, not
  by its time span: a counter wrap, a paused recording or sparse events far apart do not
  produce hours of identical rows.  Within a stretch the trackers do not move; only their
  activities decay, and the sample at its end shows where they went.

The C loops (``springtrack.backends.stepper.run_events``, used by both kernels' ``run`` and by
the firmware's fused loop, the kernels' batch steps and the microcontroller build's entry
point) use the same rule from ``springtrack/csrc/sampling.h``; tests/test_springtrack/test_sampling.py
checks that all agree on streams with backward times, ties and gaps.
"""
from __future__ import annotations

UNSET = -(1 << 63)          # next sample time of a loop that has seen no event (INT64_MIN)
HOLD = 4                    # sample periods an empty stretch is sampled for (ST_HOLD)
PER_EVENT = HOLD + 1        # at most this many samples are taken before any one event
MAX_PERIOD = 1 << 32        # sampling periods are below this (µs; 71 minutes)


def first_sample_time(t0: int, period: int) -> int:
    """The smallest multiple of ``period`` >= ``t0``."""
    return -(-t0 // period) * period


def multiples(a: int, b: int, period: int) -> int:
    """How many multiples of ``period`` lie in [a, b): the sample times a loop passed over
    from next sample time ``a`` to ``b`` (less those it took: the ones it skipped)."""
    return -(-b // period) - -(-a // period) if b > a else 0


def sample_due(t: int, next_t: int, last_t: int) -> bool:
    """Snapshots are due before an event at ``t``."""
    return t >= next_t and t >= last_t


def next_sample(t: int, next_t: int, last_t: int, period: int) -> int:
    """The sample time to take next before an event at ``t`` whose snapshots are due:
    ``next_t``, or past an empty stretch's HOLD periods the last sample time <= ``t`` (the
    stretch's end)."""
    if next_t - HOLD * period <= last_t or next_t >= t:
        return next_t
    return t // period * period
