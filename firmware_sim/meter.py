"""The tracking loop's counters and its load meter (processing time per 10 ms of events,
the quantity of the paper's Figs. 22-23, and the event rate)."""
from __future__ import annotations

import time
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

WINDOW_US = 10_000        # processing time is reported per 10 ms of events


@dataclass
class LoopCounters:
    pieces: int = 0               # pieces of transfers fed to the fused loop
    snapshots: int = 0            # snapshots taken
    updates_applied: int = 0      # model, parameter and reset updates put in effect
    updates_rejected: int = 0     # ... refused (the host got a NACK)
    proc_ns: int = 0              # wall time spent in the fused loop
    kernel_swaps: int = 0         # models loaded and resets
    processing_errors: int = 0    # exceptions while processing a transfer (counted, skipped)
    bytes_abandoned: int = 0      # bytes of transfers left unprocessed after an error or a stop
    updates_failed: int = 0       # accepted updates the kernel refused when applied (kept old)
    nonfinite_snapshots: int = 0  # snapshots of a non-finite tracker state (dropped, not sent)
    nonfinite_resets: int = 0     # trackers reset to the model because of them
    watchdog_stalls: int = 0      # episodes of transfers waiting with nothing processed

    def as_dict(self) -> dict:
        return asdict(self)


class LoadMeter:
    """Processing time per WINDOW_US of event time and events tracked per second of wall
    time, fed once per piece."""

    def __init__(self):
        self.windows: deque = deque(maxlen=4096)   # processing µs per 10 ms of events
        self._t0 = None
        self._t1 = None                            # the last event time accounted
        self._ns = 0
        self._rate: deque = deque(maxlen=64)       # (wall s, events tracked)

    def account(self, t_us: int, dt_ns: int, tracked: int) -> None:
        """``dt_ns`` of processing brought the stream to event time ``t_us``, ``tracked``
        events in all."""
        if t_us < -(1 << 60):                      # no event yet
            return
        if self._t0 is None:
            self._t0 = t_us
        self._t1 = t_us
        self._ns += dt_ns
        if t_us - self._t0 >= WINDOW_US:
            span = t_us - self._t0
            self.windows.append(self._ns / 1e3 * WINDOW_US / span)
            self._t0 = t_us
            self._ns = 0
        self._rate.append((time.monotonic(), tracked))

    def event_rate(self) -> float:
        if len(self._rate) < 2:
            return 0.0
        (w0, e0), (w1, e1) = self._rate[0], self._rate[-1]
        return (e1 - e0) / (w1 - w0) if w1 > w0 else 0.0

    def proc_us_per_10ms(self) -> dict:
        """last, mean, p99, max over the windows closed; before the first closes (a stream
        shorter than a window) the open one, scaled to a window from the event time it
        spans (its processing time as it is when it spans none)."""
        win = list(self.windows)                          # list(): atomic copy under the GIL
        if not win:
            span = (self._t1 - self._t0) if self._t0 is not None else 0
            win = [self._ns / 1e3 * (WINDOW_US / span if span > 0 else 1.0)]
        win = np.array(win)
        return dict(last=float(win[-1]), mean=float(win.mean()),
                    p99=float(np.percentile(win, 99)), max=float(win.max()))
