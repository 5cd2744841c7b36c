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

from .model import ShapeModel
from .track import Track


class TrackWatch:
    """Accumulates a run's samples (:meth:`add`) and the final state (:meth:`finish`)."""

    def __init__(self, model: ShapeModel):
        self.model = model
        self.ids = list(model.ids)
        self.width, self.height = model.width, model.height
        self.mass = np.array([t.mass for t in model.trackers], float)
        n = len(self.ids)
        self.received = np.zeros(n, bool)
        self.out_since = np.full(n, -1, np.int64)     # sample time it went out for good
        self.model_out_since = -1
        self.last_xy = None
        self.last_centre = None

    def use_model(self, model: ShapeModel) -> None:
        """The model was replaced (placed by acquisition): same trackers, new sensor check."""
        self.model = model
        self.width, self.height = model.width, model.height

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
        gx = track.x @ self.mass / self.mass.sum()                  # eq. (22)'s G
        gy = track.y @ self.mass / self.mass.sum()
        gout = self._outside(gx, gy)
        if not gout[-1]:
            self.model_out_since = -1
        elif not gout.all():
            self.model_out_since = int(track.t_us[len(gout) - int(np.argmin(gout[::-1]))])
        elif self.model_out_since < 0:
            self.model_out_since = int(track.t_us[0])
        self.last_xy = (track.x[-1], track.y[-1])
        self.last_centre = (float(gx[-1]), float(gy[-1]))

    def finish(self, state) -> None:
        """The tracker's final state (``Tracker.state()``): events after the last sample."""
        self.received |= np.asarray(state["activity"]) > 0

    def warnings(self) -> list[str]:
        out = []
        never = [i for i, r in zip(self.ids, self.received) if not r]
        if never:
            out.append(f"{len(never)} of {len(self.ids)} tracker(s) never received an event: "
                       f"{_names(never)} (nothing moved under them, or the model does not "
                       f"match the recording: check its positions against `springtrack "
                       f"render INPUT --out grid.png`)")
        if self.model_out_since >= 0:
            gx, gy = self.last_centre
            out.append(f"the model instance {self.model.name!r} left the {self.width}x"
                       f"{self.height} sensor at t={self.model_out_since} us (its centre of "
                       f"mass ends at ({gx:.1f}, {gy:.1f})); its later samples track nothing")
        gone = [(i, t) for i, t in zip(self.ids, self.out_since) if t >= 0]
        if gone:
            out.append(f"{len(gone)} tracker(s) left the {self.width}x{self.height} sensor: "
                       + _names([f"{i} (t={t} us)" for i, t in gone]))
        return out


def _names(items, shown: int = 8) -> str:
    more = f" and {len(items) - shown} more" if len(items) > shown else ""
    return ", ".join(items[:shown]) + more
