"""The firmware's event-to-telemetry latency: the one definition every report uses.

For a snapshot of sample time T (µs of event time; the tracker state after every event
with t < T, the sampling rule of springtrack/csrc/sampling.h):

* start: the wall instant T occurred on the camera's clock (``SimCamera.wall_of``: in real
  time the simulated camera releases every event at its timestamp in wall time), the
  earliest instant the snapshot could exist;
* end: the wall instant the firmware loop put the snapshot into its telemetry queue, from
  which the host link sends it (``Recorded.wall``, stamped by ``FirmwareLoop._queue``).

So it holds the camera's share (its USB controller ends a transfer up to ``commit_us`` =
250 µs after the transfer's oldest word, as a real one does, then the USB hand-off) and the
firmware's (reader thread -> processing thread -> fused decode + track -> telemetry queue);
not the host link's transport (docs/benchmarks.md, "Host link").  Per run: every snapshot
but the first SKIP_FRACTION (the device clock's start-up); p50, p99 and max.  Over several
runs: every run's p99, and the run of median p99 as the figure.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SKIP_FRACTION = 0.05


@dataclass(frozen=True)
class Latency:
    """One run's event-to-telemetry latency, ms."""
    p50: float
    p99: float
    max: float
    snapshots: int

    def __str__(self) -> str:
        return f"p50 {self.p50:.3f} ms, p99 {self.p99:.3f} ms, max {self.max:.3f} ms"


def snapshot_latencies_ms(recorder, camera) -> np.ndarray:
    """Every recorded snapshot's latency (ms), in order, the first SKIP_FRACTION dropped.
    ``recorder``: the loop's ``firmware_sim.record.Recorder``; ``camera``: the real-time
    ``SimCamera`` that served the events."""
    lat = np.array([b.wall - camera.wall_of(int(t)) for b in recorder.blocks
                    for t in b.samples["t"]]) * 1e3
    return lat[int(len(lat) * SKIP_FRACTION):]


def summarize(lat_ms: np.ndarray) -> Latency:
    if len(lat_ms) == 0:
        raise ValueError("no snapshots: the run tracked nothing")
    return Latency(float(np.median(lat_ms)), float(np.percentile(lat_ms, 99)),
                   float(lat_ms.max()), len(lat_ms))


def median_run(runs: list[Latency]) -> Latency:
    """The run of median p99 (the lower middle one for an even count)."""
    return sorted(runs, key=lambda r: r.p99)[(len(runs) - 1) // 2]
