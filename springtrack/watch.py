"""What a finished run says about the model on its sensor, for the end-of-run warnings of
``springtrack track``: trackers that never received an event, and trackers (or the whole
model instance) that left the sensor.

    >>> w = TrackWatch(model)                     # doctest: +SKIP
    >>> for samples in ...: w.add(samples)        # the Track rows as they are written
    >>> w.finish(tracker.state()); w.warnings()   # -> list of one-line messages

A tracker received an event if its activity (eq. 6, 0 until its first event) was ever
positive at a sample or at the end.  A tracker has left the sensor when its mean lies
outside ``[0, width) x [0, height)`` at the end; the model instance has when its centre of
mass (eq. 22's G) does; each with the sample time it went out for good.
"""
from __future__ import annotations

import numpy as np

from .instances import ModelSet
from .track import Track


class TrackWatch:
    """Accumulates a run's samples (:meth:`add`) and the final state (:meth:`finish`).
    ``models``: the tracker's model, or its ModelSet (each instance watched)."""

    def __init__(self, models):
        self.use_models(models)
        self.ids = list(self.models.ids)
        self.mass = np.concatenate([[t.mass for t in m.trackers] for m in self.models.models])
        n = len(self.ids)
        self.received = np.zeros(n, bool)
        self.out_since = np.full(n, -1, np.int64)     # sample time it went out for good
        self.model_out_since = np.full(len(self.models), -1, np.int64)
        self.last_xy = None
        self.last_centre = None
        self.never_found = []                         # instances never placed (finish)

    def use_models(self, models) -> None:
        """The models were replaced (placed by acquisition): same trackers."""
        self.models = models if isinstance(models, ModelSet) else ModelSet(models)
        self.model = self.models[0].model
        self.width, self.height = self.models.width, self.models.height

    use_model = use_models

    def _outside(self, x, y):
        return (x < 0) | (x >= self.width) | (y < 0) | (y >= self.height)

    def add(self, track: Track) -> None:
        if not len(track):
            return
        self.received |= (track.activity > 0).any(axis=0)
        out = self._outside(track.x, track.y)                       # (rows, K)
        # the first row of the trailing run of "outside" rows, per tracker
        for k in range(len(self.ids)):
            col = out[:, k]
            if not col[-1]:
                self.out_since[k] = -1
            elif not col.all():
                self.out_since[k] = track.t_us[len(col) - int(np.argmin(col[::-1]))]
            elif self.out_since[k] < 0:
                self.out_since[k] = track.t_us[0]
        centres = []
        for g, inst in enumerate(self.models):                      # eq. (22)'s G
            m = self.mass[inst.t0:inst.t1]
            gx = track.x[:, inst.t0:inst.t1] @ m / m.sum()
            gy = track.y[:, inst.t0:inst.t1] @ m / m.sum()
            gout = self._outside(gx, gy)
            if not gout[-1]:
                self.model_out_since[g] = -1
            elif not gout.all():
                self.model_out_since[g] = int(track.t_us[len(gout) - int(np.argmin(gout[::-1]))])
            elif self.model_out_since[g] < 0:
                self.model_out_since[g] = int(track.t_us[0])
            centres.append((float(gx[-1]), float(gy[-1])))
        self.last_xy = (track.x[-1], track.y[-1])
        self.last_centre = centres

    def finish(self, state, never_found=()) -> None:
        """The tracker's final state (``Tracker.state()``): events after the last sample;
        ``never_found``: labels of the instances an acquisition never found (their
        trackers were never placed, so their silence is not the model's fault)."""
        self.received |= np.asarray(state["activity"]) > 0
        self.never_found = [g for g, inst in enumerate(self.models) if inst.label in never_found]

    def warnings(self) -> list[str]:
        out = []
        unplaced = np.zeros(len(self.ids), bool)
        for g in self.never_found:
            inst = self.models[g]
            unplaced[inst.t0:inst.t1] = True
            out.append(f"the model instance {inst.label!r} was never found (searching to the "
                       f"end): its {inst.t1 - inst.t0} trackers' rows hold unplaced positions")
        never = [i for i, r, u in zip(self.ids, self.received, unplaced) if not r and not u]
        if never:
            out.append(f"{len(never)} of {len(self.ids)} tracker(s) never received an event: "
                       f"{_names(never)} (nothing moved under them, or the model does not "
                       f"match the recording: check its positions against `springtrack "
                       f"render INPUT --out grid.png`)")
        for g, since in enumerate(self.model_out_since):
            if since < 0:
                continue
            gx, gy = self.last_centre[g]
            name = self.model.name if len(self.models) == 1 else self.models[g].label
            out.append(f"the model instance {name!r} left the {self.width}x"
                       f"{self.height} sensor at t={since} us (its centre of "
                       f"mass ends at ({gx:.1f}, {gy:.1f})); its later samples track nothing")
        gone = [(i, t) for i, t in zip(self.ids, self.out_since) if t >= 0]
        if gone:
            out.append(f"{len(gone)} tracker(s) left the {self.width}x{self.height} sensor: "
                       + _names([f"{i} (t={t} us)" for i, t in gone]))
        return out


def _names(items, shown: int = 8) -> str:
    more = f" and {len(items) - shown} more" if len(items) > shown else ""
    return ", ".join(items[:shown]) + more
