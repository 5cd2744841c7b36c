"""``ReferenceBackend``: the executable specification (springtrack.reference) behind the
backend interface (springtrack.backends.protocol)."""
from __future__ import annotations

import numpy as np

from ..reference import ReferenceTracker
from ..sampling import UNSET, first_sample_time, next_sample, sample_due
from ..track import TRACK_DTYPE, TRACK_FIELDS


class ReferenceBackend:
    """Adapts ReferenceTracker to the backend interface; its ``run`` is the kernels'
    ``run`` (springtrack/backends/stepper.pyx) in Python, with the same sampling rule
    (springtrack.sampling)."""

    def __init__(self, model, params):
        self.ref = ReferenceTracker(model, params)

    def set_params(self, params) -> None:
        self.ref.set_params(params)

    def run(self, events, sample_us, next_t, cap, into=None):
        """The Backend protocol's run; ``into`` is not used (the rows are packed anew)."""
        ref = self.ref
        rows = []
        ts, xs, ys = events["t"].tolist(), events["x"].tolist(), events["y"].tolist()
        ps = events["p"].tolist()
        if sample_us > 0 and ts and next_t == UNSET:
            next_t = first_sample_time(ts[0], sample_us)
        for k in range(len(ts)):
            t = ts[k]
            if sample_us > 0 and sample_due(t, next_t, ref.last_t):
                while True:
                    next_t = next_sample(t, next_t, ref.last_t, sample_us)
                    if t < next_t:
                        break
                    if len(rows) >= cap:
                        return k, next_t, self._pack(rows)
                    rows.append((next_t, ref.snapshot(next_t), self._mean_energies()))
                    next_t += sample_us
            ref.step(t, xs[k], ys[k], ps[k])
        return len(ts), next_t, (self._pack(rows) if sample_us > 0 else None)

    def _mean_energies(self):
        nc = self.ref.nc
        return [sum(e) / nc if nc else 0.0 for e in self.ref.energy]

    def _pack(self, rows):
        """Sample rows as the C loops return them (springtrack.backends.samples.sample_buffers)."""
        tr = np.empty((len(rows), self.ref.n), TRACK_DTYPE)
        for j, f in enumerate(TRACK_FIELDS):
            tr[f] = np.array([r[1][j] for r in rows], TRACK_DTYPE[f]).reshape(tr.shape)
        return {"t": np.array([r[0] for r in rows], np.int64), "trackers": tr,
                "energy": np.array([r[2] for r in rows], np.float64).reshape(len(rows), 3)}

    def snapshot(self, t):
        snap = self.ref.snapshot(t)
        return {f: np.array(v, TRACK_DTYPE[f]) for f, v in zip(TRACK_FIELDS, snap)}

    def energies(self):
        return np.array(self.ref.energy, dtype=float).reshape(3, self.ref.nc)

    @property
    def mean_energy(self):
        return self.ref.mean_energy

    def mean_energies(self):
        return list(self.ref.mean_energies)

    def frame(self, g: int = 0):
        return self.ref.frame(g)

    @property
    def last_t(self):
        return self.ref.last_t

    def counters(self):
        r = self.ref
        return dict(events_valid=r.n_valid, events_assigned=r.n_assigned,
                    skipped_back_in_time=r.n_back, skipped_outside_sensor=r.n_outside,
                    spring_updates=r.n_spring_updates, state_resets=r.n_resets)

    # the instances' states (springtrack.instances)
    def states(self) -> list:
        return list(self.ref.state)

    def set_state(self, g: int, state: int) -> None:
        self.ref.set_state(g, state)

    def place(self, g: int, model) -> None:
        self.ref.place(g, model)

    def relocate(self, g: int, idx, x, y, sxx, sxy, syy) -> None:
        self.ref.relocate(g, idx, x, y, sxx, sxy, syy)

    movable = True

    def move(self, g: int, sim, model) -> None:
        self.ref.move(g, sim, model)
