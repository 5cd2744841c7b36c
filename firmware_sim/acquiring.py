"""A tracker kernel with acquisition for the firmware's loop: ``springtrack.Tracker(...,
acquire=True)`` behind the kernel interface the loop's decoded feed drives
(``run(events, sample_us, next_t, cap)``, ``counters``, ``energies``, ``last_t``).

The model slot builds one per model (upload) and per RESET or ACQUIRE, so each starts
searching: the model's positions are not trusted, it is found in the first window of
events, then the loss rule and the re-acquisition of springtrack.acquisition.recovery run as in
``springtrack track --acquire``, and the telemetry carries each tracker's instance state
(``wire.encode_telemetry``'s trailer).  The decoded path (``firmware_sim.feed``) feeds it:
the acquisition needs the events themselves, which the fused C loop does not keep.  While the model is not
found the telemetry shows it at its place, insensitive, ``searching``; at the source's end
(:meth:`finish`) or once ``budget_ms`` of event time is searched in vain, ``not found``.
"""
from __future__ import annotations

import numpy as np

from springtrack.track import TRACK_DTYPE, TRACK_FIELDS
from springtrack.tracker import Tracker


class AcquiringKernel:
    """``AcquiringKernel(model, params, backend, acquire_ms, bounds)``: a Tracker of that
    backend with ``acquire=True``, sampled at the ``sample_us`` its first ``run`` asks for."""

    native_records = False           # telemetry quantised from the float rows

    def __init__(self, model, params, backend: str = "cython", acquire_ms: float = 50.0,
                 bounds: dict | None = None, budget_ms: float | None = None):
        self.tracker = Tracker(model, params, backend=backend, acquire=True,
                               acquire_ms=acquire_ms, acquire_bounds=bounds,
                               acquire_budget_ms=budget_ms)
        self._period = None

    def run(self, events, sample_us, next_t, cap):
        """Track every event; (events consumed, next_t (unused: the tracker keeps its own
        clock), the sample rows as the C loops return them)."""
        if self._period is None:
            self._period = int(sample_us)
            self.tracker.record(self._period)
        return len(events), next_t, self._rows(list(self.tracker.stream(events)))

    def finish(self):
        """The source ended: a search still running tries its last, shorter window, and
        ends (found, or not found); the sample rows that makes, or None."""
        if self._period is None:
            return None
        self.tracker.flush()
        return self._rows([self.tracker.samples()])

    def _rows(self, parts):
        """Tracks as the C loops' sample rows (None if none)."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return None
        t = np.concatenate([p.t_us for p in parts])
        tr = np.empty((len(t), len(self.tracker.ids)), TRACK_DTYPE)
        for f in TRACK_FIELDS:
            tr[f] = np.concatenate([getattr(p, f) for p in parts])
        energy = np.concatenate([p.energy for p in parts])
        return {"t": t, "trackers": tr, "energy": energy}

    def set_params(self, params) -> None:
        self.tracker.set_params(params)

    def energies(self):
        return self.tracker._b.energies()

    @property
    def last_t(self):
        return self.tracker.last_t if self.tracker.last_t > -(1 << 61) else -1

    def counters(self) -> dict:
        c = self.tracker.counters
        return {k: int(v) for k, v in c.items() if isinstance(v, (int, np.integer))}

    def instances(self) -> list:
        return self.tracker.instances()
