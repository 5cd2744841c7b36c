"""The sampling rule of every tracker loop, in Python: a track sampled every ``period`` µs
of event time holds, at each sample time T, the state after all events with t < T.

* The first sample time is the smallest multiple of the period >= the first event's
  time (:func:`first_sample_time`); a loop that has not seen an event yet holds
  :data:`UNSET`.
* Before an event at t with t >= the next sample time and t >= the last event time, one
  snapshot is taken per sample time <= t (:func:`sample_due`).  An event back in time
  (t < the last event time) is skipped by the kernel, so it neither moves time on nor
  triggers a sample.

The C loops (``springtrack._stepper.run_events``, used by both kernels' ``run`` and by
the firmware's fused loop, and the kernels' batch steps) use the same rule from
``springtrack/csrc/sampling.h``; tests/test_sampling.py checks that both agree on
streams with backward times, ties and gaps.
"""
from __future__ import annotations

UNSET = -(1 << 63)          # next sample time of a loop that has seen no event (INT64_MIN)


def first_sample_time(t0: int, period: int) -> int:
    """The smallest multiple of ``period`` >= ``t0``."""
    return -(-t0 // period) * period


def sample_due(t: int, next_t: int, last_t: int) -> bool:
    """Snapshots are due before an event at ``t``."""
    return t >= next_t and t >= last_t
