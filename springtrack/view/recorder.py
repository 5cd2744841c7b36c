"""The Rerun recording of a track: one frame per ``every_us`` of event time.

Frames are taken at the track's own sample rows: the first row at or after the next
frame time is drawn (its trackers, springs, states, energies) with the events of the
``every_us`` before it.  Events wait in a buffer trimmed at every frame, so memory is
bounded by one frame's events however long the stream runs.
"""
from __future__ import annotations

import numpy as np

from ..events import EVENT_DTYPE, as_events
from ..live.extras import need
from ..render import LEGEND, drawn, ellipses_xy
from ..track import STATE_NAMES, TRACKING_CODE

VIEW_EVERY_US = 10_000        # a frame per 10 ms of event time (render's default window)
APPLICATION = "springtrack"   # Rerun's application id; the recording is named by the run
TIMELINE = "event_time"       # seconds of event time
BACKLOG_US = 1_000_000        # events kept for frames not drawn yet (µs of event time)
SEARCHING_CODE = STATE_NAMES.index("searching")
LOST_CODE = STATE_NAMES.index("lost")
# legend class ids (render.LEGEND's order, from 1: 0 is Rerun's "no class")
CLASS = {label: k + 1 for k, (label, _) in enumerate(LEGEND)}
ACTIVE, INACTIVE, INSENSITIVE, LOST, SPRING, ON, OFF = (
    CLASS[label] for label, _ in LEGEND)
ENERGIES = ("euclidean", "torsional", "cartesian")
# what a view logs: entity path -> what it holds
ENTITIES = {
    "sensor/events": "Points2D: the events of the last frame period, class ON / OFF",
    "sensor/trackers": "LineStrips2D: each tracker's 2σ ellipse, class by state, its id",
    "sensor/springs": "LineStrips2D: the springs between trackers of a drawn instance",
    "instances": "Scalars, a series per instance: its state code (0 searching, 1 tracking, "
                 "2 lost)",
    "energy": "Scalars, a series per kind: mean energy (euclidean, torsional, cartesian; "
              "from a device: mean)",
    "trackers/active": "Scalars: how many trackers are active",
}


def _rgb8(colour) -> tuple[int, int, int]:
    if isinstance(colour, str):
        return tuple(int(colour[i:i + 2], 16) for i in (1, 3, 5))
    return tuple(int(round(255 * float(c))) for c in colour)


class RerunView:
    """A recording stream of a track (see the package docstring)."""

    def __init__(self, target: str, models, name: str = "springtrack",
                 every_us: int = VIEW_EVERY_US):
        rr = need("rerun", "view", "the live view (--view)")
        self.rr = rr
        self.every_us = int(every_us)
        if self.every_us <= 0:
            raise ValueError(f"the view's frame period must be positive µs, got {every_us}")
        self.rec = rr.RecordingStream(APPLICATION)
        self.rec.send_recording_name(name)
        if target == "rerun":
            self.rec.spawn()
        else:
            self.rec.save(str(target))
        self.rec.log("/", rr.AnnotationContext(
            [rr.AnnotationInfo(id=CLASS[label], label=label, color=_rgb8(colour))
             for label, colour in LEGEND]), static=True)
        self.ids, self.links, self.inst, self.labels = [], [], None, []
        if models is not None:
            w, h, self.ids, self.links, self.inst, self.labels = drawn(models)
            self.rec.log("sensor", rr.Boxes2D(mins=[[-0.5, -0.5]], sizes=[[w, h]],
                                              labels=[f"{w}x{h} sensor"]), static=True)
        self.pending = np.empty(0, EVENT_DTYPE)
        self.next_t = None
        self.frames = 0
        self._named: dict = {}

    # ---- feeding -------------------------------------------------------------------
    def events(self, ev: np.ndarray) -> None:
        """Events (fields t, x, y, p, in time order) to draw with the frames that follow
        them; those more than ``BACKLOG_US`` before the newest are let go (a track's rows
        come at most an acquisition window after their events)."""
        if not len(ev):
            return
        ev = np.concatenate([self.pending, as_events(ev)])
        self.pending = ev[np.searchsorted(ev["t"], int(ev["t"][-1]) - BACKLOG_US):]

    def track(self, samples) -> None:
        """A springtrack.track.Track of sample rows: a frame at each row that reaches
        the next frame time."""
        if not len(samples):
            return
        for k in self._frame_rows(samples.t_us):
            energies = ({n: float(samples.energy[k, i]) for i, n in enumerate(ENERGIES)}
                        if samples.energy is not None else {})
            self.frame(int(samples.t_us[k]), {f: getattr(samples, f)[k] for f in
                       ("x", "y", "sxx", "sxy", "syy", "active", "sensitive", "state")},
                       energies)

    def telemetry(self, t_us: int, trackers: np.ndarray, mean_energy: float) -> None:
        """A device's telemetry snapshot (TRACK_DTYPE rows with ``state``): a frame when
        it reaches the next frame time (no events: the link carries none)."""
        if list(self._frame_rows(np.array([t_us]))):
            self.frame(int(t_us), {f: trackers[f] for f in trackers.dtype.names},
                       {"mean": float(mean_energy)})

    def _frame_rows(self, t_us: np.ndarray):
        for k in range(len(t_us)):
            t = int(t_us[k])
            if self.next_t is None or t >= self.next_t:
                self.next_t = t - t % self.every_us + self.every_us
                yield k

    # ---- drawing -------------------------------------------------------------------
    def frame(self, t_us: int, st: dict, energies: dict) -> None:
        """Log one frame at ``t_us``: the events before it, the trackers ``st`` (arrays
        x, y, sxx, sxy, syy, active, sensitive, state), ``energies`` (name -> value)."""
        rr, rec = self.rr, self.rec
        rec.set_time(TIMELINE, duration=np.timedelta64(int(t_us), "us"))
        self._draw_events(t_us)
        n = len(st["x"])
        ids = self.ids if len(self.ids) == n else [f"t{k:02d}" for k in range(n)]
        state = np.asarray(st.get("state", np.full(n, TRACKING_CODE)))
        shown = state != SEARCHING_CODE
        cls = np.where(state == LOST_CODE, LOST,
                       np.where(~np.asarray(st["sensitive"], bool), INSENSITIVE,
                                np.where(np.asarray(st["active"], bool), ACTIVE, INACTIVE)))
        pts = ellipses_xy(st["x"], st["y"], st["sxx"], st["sxy"], st["syy"])
        rec.log("sensor/trackers", rr.LineStrips2D(pts[shown], class_ids=cls[shown],
                                                   labels=[ids[k] for k in np.flatnonzero(shown)]))
        links = [(i, j) for i, j in self.links if i < n and j < n and shown[i] and shown[j]]
        rec.log("sensor/springs", rr.LineStrips2D(
            [[[st["x"][i], st["y"][i]], [st["x"][j], st["y"][j]]] for i, j in links],
            class_ids=SPRING))
        if self.inst is not None and len(self.inst) == n:
            self._series("instances", self.labels)
            rec.log("instances", rr.Scalars([float(state[self.inst == g][0])
                                             for g in range(len(self.labels))]))
        if energies:
            self._series("energy", list(energies))
            rec.log("energy", rr.Scalars(list(energies.values())))
        rec.log("trackers/active", rr.Scalars(float(np.count_nonzero(st["active"]))))
        self.frames += 1

    def _series(self, entity: str, names: list) -> None:
        """Name the series of ``entity``'s scalars (once, static)."""
        if self._named.get(entity) != names:
            self.rec.log(entity, self.rr.SeriesLines(names=names), static=True)
            self._named[entity] = list(names)

    def _draw_events(self, t_us: int) -> None:
        ev = self.pending
        lo, hi = np.searchsorted(ev["t"], [t_us - self.every_us, t_us])
        win = ev[lo:hi]
        self.rec.log("sensor/events", self.rr.Points2D(
            np.stack([win["x"], win["y"]], -1).astype(np.float32),
            class_ids=np.where(win["p"] > 0, ON, OFF).astype(np.uint16), radii=0.5))
        self.pending = ev[hi:]

    def close(self) -> None:
        """Flush what is logged (the .rrd file complete)."""
        if self.rec is not None:
            self.rec.flush()
            self.rec.disconnect()
            self.rec = None
