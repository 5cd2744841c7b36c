"""Loss and re-acquisition on a stream: what a tracker does once its instances are placed.

The kernels apply the loss rule (springtrack.instances: a tracking instance with fewer
than a third of its trackers active for LOSS_HOLD_TAU time constants becomes lost and
insensitive).  :class:`Recovery` does the rest, between two events:

* it keeps the recent events in a bounded ring (:class:`EventRing`, RING_EVENTS events:
  memory bounded by the event rate, never by the input's span);
* at every multiple of half the acquisition window of event time (``period``) -- the
  state then holds every event before it, as a sample does -- while an instance is
  searching or lost, and if events came since the last such time, it runs
  :func:`springtrack.acquire.acquire` for that instance on the last window of the ring,
  with the pixels of the tracking instances' gates removed (explaining away) and the pose
  wanted at the newest event (tracking resumes with the next event: nothing is replayed);
* an instance found is placed there (``place``: positions, covariances and the rest
  geometry of the placed model, activities 0) and tracks again;
* every change of state is kept with its event time: ``acquired`` (first found),
  ``lost`` (the kernel's time of the loss), ``reacquired``.

The attempt times are a fixed grid of event time, so the result does not depend on how
the input is cut into chunks.
"""
from __future__ import annotations

import numpy as np

from .acquire import MIN_EVENTS, acquire, place, placed_gates
from .events import EVENT_DTYPE
from .instances import SEARCHING, TRACKING
from .sampling import first_sample_time

RING_EVENTS = 1 << 17          # ~0.4 s at 300 k events/s


class EventRing:
    """The last ``capacity`` events pushed, in order."""

    def __init__(self, capacity: int = RING_EVENTS):
        self.buf = np.zeros(capacity, EVENT_DTYPE)
        self.count = 0                      # events pushed in all

    def push(self, ev) -> None:
        cap = len(self.buf)
        if len(ev) > cap:
            self.count += len(ev) - cap
            ev = ev[-cap:]
        pos = self.count % cap
        k = min(len(ev), cap - pos)
        self.buf[pos:pos + k] = ev[:k]
        self.buf[:len(ev) - k] = ev[k:]
        self.count += len(ev)

    def recent(self) -> np.ndarray:
        """Every event held, oldest first (a copy)."""
        cap = len(self.buf)
        if self.count <= cap:
            return self.buf[:self.count].copy()
        pos = self.count % cap
        return np.concatenate([self.buf[pos:], self.buf[:pos]])

    def window(self, t_lo: int, t_hi: int) -> np.ndarray:
        """The events held with t_lo <= t < t_hi, in order."""
        ev = self.recent()
        return ev[(ev["t"] >= t_lo) & (ev["t"] < t_hi)]


class Recovery:
    """The loss rule's other half for ``tracker`` (a springtrack.Tracker whose instances
    are placed): the ring, the attempts and the log of changes (module docstring).
    ``window_us``: the acquisition window; ``bounds``: acquire's bounds (region,
    angle_deg, scale), relative to each instance's last placement."""

    def __init__(self, tracker, window_us: int, bounds: dict):
        self.tr = tracker
        self.window_us = int(window_us)
        self.period = max(self.window_us // 2, 1)
        self.bounds = dict(bounds)
        self.ring = EventRing()
        self.changes: list = []             # (t_us, label, kind)
        self.attempts = 0
        self._next = None                   # the next attempt time
        self._losses = None

    def start(self, t_first: int, found) -> None:
        """The instances were placed (``found[g]``) at the window starting at t_first."""
        b = self.tr._ib
        b.enable_loss(True)
        for g, f in enumerate(found):
            if f:
                self.changes.append((t_first, self.tr.models[g].label, "acquired"))
            else:
                b.set_state(g, SEARCHING)
        self._losses = b.losses()
        self._next = first_sample_time(t_first, self.period)

    def track(self, ev) -> None:
        """Process ``ev`` (EVENT_DTYPE, in time order) through the tracker's backend,
        stopping at each attempt time."""
        b = self.tr._ib
        run = np.maximum.accumulate(np.maximum(ev["t"], b.last_t))   # the clock at each event
        pos, n = 0, len(ev)
        while pos < n:
            j = int(np.searchsorted(run, self._next, "left"))      # first event at >= next
            if j > pos:
                self.tr._run(ev[pos:j])
                self.ring.push(ev[pos:j])
                pos = j
            self._poll()
            if pos < n:
                self._attempt(self._next)
                # the next grid time after this event's: no attempt without new events
                self._next = first_sample_time(max(int(run[pos]), self._next) + 1, self.period)

    def _poll(self) -> None:
        """Record the kernel's losses since the last look."""
        now = self.tr._ib.losses()
        for g, ((n0, _), (n1, t)) in enumerate(zip(self._losses, now)):
            if n1 != n0:
                self.changes.append((int(t), self.tr.models[g].label, "lost"))
        self._losses = now

    def _attempt(self, t: int) -> None:
        """At event time t: search for every instance that is not tracking."""
        b = self.tr._ib
        states = b.states()
        todo = [g for g, s in enumerate(states) if s != TRACKING]
        if not todo:
            return
        window = self.ring.window(t - self.window_us, t)
        if len(window) < MIN_EVENTS:
            return
        snap = b.snapshot(t)
        mset = self.tr.models
        live = np.repeat(np.array(states) == TRACKING, [i.n for i in mset])
        claimed = [np.asarray(snap[k], float)[live] for k in ("x", "y", "sxx", "sxy", "syy")]
        at = int(window["t"][-1])
        for g in todo:
            self.attempts += 1
            model = mset[g].model
            pose = acquire(model, window, at_us=at, claimed=claimed, **self.bounds)
            if not pose.found:
                continue
            placed = place(model, pose)
            b.place(g, placed)
            self.tr.models = mset = mset.replaced(g, placed)
            kind = "acquired" if states[g] == SEARCHING else "reacquired"
            self.changes.append((t, mset[g].label, kind))
            claimed = [np.concatenate([c, np.asarray(v, float)])
                       for c, v in zip(claimed, placed_gates(model, pose))]

    def counters(self) -> dict:
        kinds = [c[2] for c in self.changes]
        return dict(reacquire_attempts=self.attempts, acquired=kinds.count("acquired"),
                    lost=kinds.count("lost"), reacquired=kinds.count("reacquired"))
