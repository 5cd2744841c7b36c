"""Loss and re-acquisition on a stream: what a tracker does once its instances are placed.

:class:`Recovery` drives the tracker's backend between two events, the same way for
every backend:

* it keeps the recent events in a bounded ring (:class:`EventRing`, RING_EVENTS events:
  memory bounded by the event rate, never by the input's span);
* at every loss check (springtrack.acquisition.loss: the multiples of LOSS_CHECK_US of event time,
  on the state holding every event before it) it applies the loss rule to the
  backend's ``active`` flags; before an instance is declared lost it is searched for on
  the last window, and found where its trackers are (RESUME_SIGMA) it is not lost (an
  object that slowed down, stopped or turned: the rule's clock restarts); one found
  lost is set LOST (insensitive, its positions kept) and searched for at once;
* at every multiple of DOUBT_CHECK_US of event time, each tracking instance's share of
  the sensor's events (springtrack.acquisition.loss.ShareDoubt); an instance in doubt is verified
  (at most once per ``period / 2``, the window it searches: each search sees new events;
  while the doubt stays and nothing better is found, the waits double up to
  VERIFY_BACKOFF periods), and every instance every VERIFY_EVERY
  periods: a search on the last ``period / 2`` of events; if it finds the model away
  from its trackers and supported MOVED_SUPPORT times more than its trackers are where
  they are (:func:`springtrack.acquisition.acquire.judge` on the same events), the object moved:
  lost and re-placed there at once (a jump is caught as soon as its share falls, not
  after the activity has decayed and the hold has run);
* at every multiple of half the acquisition window of event time (``period``) while an
  instance is searching or lost, and if events came since the last such time, it runs
  :func:`springtrack.acquisition.acquire.acquire` for that instance on the last window of the ring,
  with the pixels of the tracking instances' gates removed (explaining away) and the pose
  wanted at the newest event (tracking resumes with the next event: nothing is replayed);
* a pose found with trackers off the sensor (by a search or a verification) is taken
  only when the attempt before found it at the same place: an object sliding into view is not placed half in view,
  where a tracker could not follow it;
* an instance found is placed there (``place``: positions, covariances and the rest
  geometry of the placed model, activities 0; the kernel's covariances measured on the
  window, springtrack.acquisition.spread) and tracks again -- unless it was found
  where its trackers were kept (mean Mahalanobis distance below RESUME_SIGMA: the object
  came back where it was hidden, or stood still), which resume as they were;
* an instance re-acquired or found moved while its trackers still hold the model's shape
  (all on the sensor, their mean Mahalanobis distance to their best-fit placement below
  SHAPE_SIGMA) is not
  re-placed but moved rigidly onto the pose found (the backend's ``move``: activities
  and deformation kept); a window later it is searched for once more in a narrow range
  around its trackers (REFINE_PX, REFINE_DEG, REFINE_SCALE) and, found, moved onto that
  pose (a re-placed instance otherwise tracks a few px and degrees off the truth and
  drifts as a whole; the springs keep it in that state).  Backends that cannot move an
  instance re-place it;
* every change of state is kept with its event time: ``acquired`` (first found),
  ``lost``, ``reacquired``.

Check and attempt times are fixed grids of event time, so the result does not depend on
how the input is cut into chunks.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .acquire import (MIN_EVENTS, Pose, acquire, fit_pose, judge, model_pose, place, place_checked,
                      placed_gates)
from ..events import EVENT_DTYPE
from ..instances import LOST, SEARCHING, TRACKING
from .recall import left_behind, recalled
from .spread import measured_spread
from .loss import (DOUBT_CHECK_US, LOSS_CHECK_US, MASS_HORIZON_TAU, LossRule, ShareDoubt,
                   counted, event_mass, loss_hold_us)

RING_EVENTS = 1 << 17          # ~0.4 s at 300 k events/s
NEVER = 1 << 62
RESUME_SIGMA = 1.0             # a lost instance found within this of where it was resumes
MOVED_SUPPORT = 2.0            # in doubt and found elsewhere supported this x more: moved
VERIFY_BACKOFF = 8             # a doubt that stays: verified every period, 2, 4 ... up to
#                                this x period apart while nothing better is found
VERIFY_EVERY = 40              # and every instance, in doubt or not, this x period apart
SHAPE_SIGMA = 1.0              # trackers within this of their best-fit model keep their shape
REFINE_PX = 10.0               # the refinement's search after a re-placement: +- px,
REFINE_DEG = 6.0               # +- degrees,
REFINE_SCALE = 0.07            # +- this fraction of the size


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

    def times_since(self, t_lo: int) -> np.ndarray:
        """The times of the events held from the newest back to the first with t < t_lo
        (binary search: the events are held in time order)."""
        cap = len(self.buf)
        if self.count <= cap:
            parts = [self.buf["t"][:self.count]]
        else:
            pos = self.count % cap
            parts = [self.buf["t"][pos:], self.buf["t"][:pos]]
        return np.concatenate([p[np.searchsorted(p, t_lo, "left"):] for p in parts])

    def since(self, t_lo: int) -> np.ndarray:
        """The events held with t >= t_lo, in order (only those copied)."""
        cap = len(self.buf)
        if self.count <= cap:
            parts = [self.buf[:self.count]]
        else:
            pos = self.count % cap
            parts = [self.buf[pos:], self.buf[:pos]]
        return np.concatenate([p[np.searchsorted(p["t"], t_lo, "left"):] for p in parts])

    def window(self, t_lo: int, t_hi: int) -> np.ndarray:
        """The events held with t_lo <= t < t_hi, in order."""
        ev = self.recent()
        return ev[(ev["t"] >= t_lo) & (ev["t"] < t_hi)]


def _mahalanobis(placed, x, y) -> float:
    """The mean Mahalanobis distance (the placed covariances) of positions x, y to the
    placed trackers."""
    a = placed.arrays()
    dx, dy = x - a["x"], y - a["y"]
    det = a["sxx"] * a["syy"] - a["sxy"] ** 2
    d2 = (a["syy"] * dx * dx - 2 * a["sxy"] * dx * dy + a["sxx"] * dy * dy) / det
    return float(np.mean(np.sqrt(np.maximum(d2, 0.0))))


def _where_kept(placed, x, y) -> bool:
    """The placement found lies where a lost instance's trackers were kept: their mean
    Mahalanobis distance below RESUME_SIGMA."""
    return _mahalanobis(placed, x, y) < RESUME_SIGMA


def about(pose: Pose, base: Pose) -> Pose:
    """``pose``, found for a model placed at ``base``, as a pose of the model itself.
    place(model, base) maps q to base.t + s_b R_b (q - G) and keeps the mass-weighted centre
    of mass at base.t, so placing that at ``pose`` maps q to
    pose.t + s R s_b R_b (q - G): angles add (wrapped to [-180, 180)), scales multiply."""
    ang = (pose.angle_deg + base.angle_deg + 180.0) % 360.0 - 180.0
    return replace(pose, angle_deg=ang, scale=pose.scale * base.scale)


def _grid_at_or_before(t: int, period: int) -> int:
    """The largest multiple of ``period`` <= t."""
    return t // period * period


class Recovery:
    """The loss rule and the re-acquisition for ``tracker`` (a springtrack.Tracker whose
    instances are placed): the ring, the checks, the attempts and the log of changes
    (module docstring).  ``window_us``: the acquisition window; ``bounds``: acquire's
    bounds (region, angle_deg, scale)."""

    def __init__(self, tracker, window_us: int, bounds: dict):
        self.tr = tracker
        self.window_us = int(window_us)
        self.period = max(self.window_us // 2, 1)
        self._verify_span = max(self.period // 2, 1)    # a verification's window of events
        self.bounds = dict(bounds)
        self.ring = EventRing()
        self.rule = None
        self.changes: list = []             # (t_us, label, kind)
        self.placements: list = []          # (t_us, instance, (n, 2) positions placed)
        self.attempts = 0
        self._attempt = None                # the next attempt time
        self._last_event = None             # the clock of the last event run
        self._span = None                   # the clock of the events being run
        self._partial = {}                  # instance: its last placement found partly in view
        self.doubt = None                   # the share of events taken (springtrack.acquisition.loss)
        self._doubt_at = None               # the next doubt check time
        self._verify_next = []              # per instance: no verification before this
        self._verify_wait = []              # per instance: the wait after the next one
        self._verify_due = []               # per instance: verified, doubt or not, by then
        self._mass = (0.0, None)            # the sensor's event mass and its time
        self.verifications = 0
        self.moves = 0                      # instances moved rigidly onto a pose found
        self._refine_at = {}                # instance: its refinement search time
        self.refuted = 0                    # losses refuted: found where its trackers are
        self.unplaceable = 0                # poses found that put a tracker beyond the sensor's margin
        self.recalls = 0                    # trackers left behind recalled (springtrack.acquisition.recall)
        self._recall_next = {}              # instance: no recall before this time

    def start(self, t_first: int, found) -> None:
        """The instances were placed (``found[g]``) at the window starting at t_first."""
        b = self.tr._ib
        params = self.tr.models.params
        self.rule = LossRule([(i.t0, i.t1) for i in self.tr.models],
                             loss_hold_us(params), t_first - 1)
        self.doubt = ShareDoubt(len(self.tr.models), params.activity_tau_us, loss_hold_us(params))
        self._verify_next = [0] * len(self.tr.models)
        self._verify_wait = [self._verify_span] * len(self.tr.models)
        self._verify_due = [t_first + VERIFY_EVERY * self.period] * len(self.tr.models)
        self._doubt_at = -(-t_first // DOUBT_CHECK_US) * DOUBT_CHECK_US
        for g in range(len(self.tr.models)):
            self.doubt.reset(g, t_first)
        for g, f in enumerate(found):
            if f:
                self.changes.append((t_first, self.tr.models[g].label, "acquired"))
                self._placed(t_first, g)
            else:
                b.set_state(g, SEARCHING)
        self._attempt = -(-t_first // self.period) * self.period

    def sample_period(self, sample_us: int) -> int:
        """The backend's sampling period: the checks' and the caller's samples' grids."""
        return math.gcd(LOSS_CHECK_US, sample_us) if sample_us > 0 else LOSS_CHECK_US

    def track(self, ev):
        """Process ``ev`` (EVENT_DTYPE, in time order) through the tracker's backend in
        spans: up to the first time an instance could be lost (the checks in between are
        the backend's own samples, :meth:`rows`) or the next attempt, then that check and
        the attempts.  Yields the tracker's samples (Tracks) as they are taken."""
        b = self.tr._ib
        clock = np.maximum.accumulate(np.maximum(ev["t"], b.last_t))   # the clock at each event
        pos, n = 0, len(ev)
        while pos < n:
            states = b.states()
            tracking = [s == TRACKING for s in states]
            searching = not all(tracking)
            end = self.rule.earliest(tracking)
            if searching:
                end = min(end, self._attempt)
            if any(tracking):
                end = min(end, self._doubt_at)
            j = n if end >= NEVER else int(np.searchsorted(clock, end, "left"))
            if j > pos:
                self._span = clock[pos:j]
                self.ring.push(ev[pos:j])
                yield from self.tr._run(ev[pos:j])
                self._last_event = int(clock[j - 1])
                self._span = None
                pos = j
            if pos >= n:
                break
            now = int(clock[pos])                # the state holds every event before now
            if any(tracking):
                self._stop_check(now)
                if now >= self._doubt_at:
                    self._doubt_check(self._doubt_at)
                    self._doubt_at = _grid_at_or_before(now, DOUBT_CHECK_US) + DOUBT_CHECK_US
            if searching or b.states() != states:
                if now >= self._attempt:
                    self._search(self._attempt)
                    self._attempt = _grid_at_or_before(now, self.period) + self.period

    def rows(self, t, active) -> None:
        """The backend's samples at check times ``t`` ((k,) int64) with their ``active``
        flags ((k, n) bool), taken while it ran the current span."""
        t = np.asarray(t, np.int64)
        new = t > self.rule.last
        t, active = t[new], active[new]
        if not len(t):
            return
        span = self._span
        i = np.searchsorted(span, t, "left")
        before = np.where(i > 0, span[np.maximum(i - 1, 0)],
                          -NEVER if self._last_event is None else self._last_event)
        ok = counted(t, before)
        tracking = [s == TRACKING for s in self.tr._ib.states()]
        for tk, lost in self.rule.check_rows(t[ok], active[ok], tracking):
            self._apply(tk, self._confirmed(tk, lost))
        self.rule.skip_to(int(t[-1]))

    def _stop_check(self, now: int) -> None:
        """The checks a stop before the event at ``now`` is due: the one after the last
        event run (if it is due by now), the others in between do not count."""
        if self._last_event is None:
            return
        t = _grid_at_or_before(self._last_event, LOSS_CHECK_US) + LOSS_CHECK_US
        if self.rule.last < t <= now:
            b = self.tr._ib
            tracking = [s == TRACKING for s in b.states()]
            lost = self.rule.check(t, b.snapshot(t)["active"], tracking)
            if self._apply(t, self._confirmed(t, lost)):
                self._attempt = t                 # search for it at once
        self.rule.skip_to(_grid_at_or_before(now, LOSS_CHECK_US))

    def _confirmed(self, t: int, lost) -> list:
        """Of the instances the loss rule finds lost at t, those not found where their
        trackers are by a search on the last window (an object that only slowed down,
        turned or stopped keeps its place and is not lost: its rule's clock restarts)."""
        if not lost:
            return lost
        b = self.tr._ib
        states = b.states()
        window = self.ring.window(t - self.window_us, t)
        if len(window) < MIN_EVENTS:
            return lost
        snap = b.snapshot(t)
        out = []
        for g in lost:
            inst = self.tr.models[g]
            self.attempts += 1
            x, y = (np.asarray(snap[k], float)[inst.t0:inst.t1] for k in ("x", "y"))
            pose = self._acquire_about(inst.model, x, y, window, at_us=int(window["t"][-1]),
                                       claimed=self._claimed(snap, states, but=g))
            placed = place_checked(inst.model, pose) if pose.found else None
            if placed is not None and _where_kept(placed, x, y):
                self.rule.reset(g)
                self.refuted += 1
            else:
                out.append(g)
        return out

    def _apply(self, t: int, lost) -> bool:
        """The instances ``lost`` at check time t: LOST, recorded; True if any."""
        b = self.tr._ib
        for g in lost:
            b.set_state(g, LOST)
            self.changes.append((t, self.tr.models[g].label, "lost"))
        return bool(lost)

    def _search(self, t: int) -> None:
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
        claimed = self._claimed(snap, states)
        at = int(window["t"][-1])
        for g in todo:
            self.attempts += 1
            model = mset[g].model
            inst = mset[g]
            kept = [np.asarray(snap[k], float)[inst.t0:inst.t1] for k in ("x", "y")]
            pose = (self._acquire_about(model, *kept, window, at_us=at, claimed=claimed)
                    if states[g] == LOST else
                    acquire(model, window, at_us=at, claimed=claimed, **self.bounds))
            if not pose.found:
                self._partial.pop(g, None)
                continue
            placed = place_checked(model, pose)
            if placed is None:
                self.unplaceable += 1
                continue
            if pose.in_view < inst.n and not self._stays_partly_in_view(g, placed):
                continue
            if states[g] == LOST and _where_kept(placed, *kept):
                b.set_state(g, TRACKING)          # found where it was kept: resume from there
                self._resumed(t, g, "reacquired")
            else:
                self._replace(t, g, placed, "acquired" if states[g] == SEARCHING else "reacquired",
                              pose, snap if states[g] == LOST else None, window, at, claimed)
            mset = self.tr.models
            claimed = [np.concatenate([c, np.asarray(v, float)])
                       for c, v in zip(claimed, placed_gates(model, pose))]

    def _acquire_about(self, model, x, y, window, **kw) -> Pose:
        """:func:`acquire` of an instance whose trackers are at ``x``, ``y`` (its model
        ``model``, as last placed): the rotation bounds taken about the rotation of its
        trackers (:func:`fit_pose`), not about the model's last placement -- an object that
        turned 200 degrees since it was placed is searched for where it turned to; the
        scale bounds about its last placement's (the trackers of a lost instance may have
        crowded together, and their fitted scale says little).  The pose is returned
        relative to ``model``."""
        fit = fit_pose(model, x, y)
        now = Pose(fit.tx, fit.ty, fit.angle_deg, 1.0)
        about_now = place_checked(model, now)
        if about_now is None:         # trackers gone beyond the sensor: about the model
            now = model_pose(model)
            about_now = model
        pose = acquire(about_now, window, **self.bounds, **kw)
        return about(pose, now)

    def _claimed(self, snap, states, but: int | None = None) -> list:
        """The gates (x, y, sxx, sxy, syy) of the tracking instances' trackers (but
        instance ``but``): their events are explained already."""
        live = np.array(states) == TRACKING
        if but is not None:
            live[but] = False
        live = np.repeat(live, [i.n for i in self.tr.models])
        return [np.asarray(snap[k], float)[live] for k in ("x", "y", "sxx", "sxy", "syy")]

    def _replace(self, t: int, g: int, placed, kind: str, pose=None, snap=None,
                 window=None, at=None, claimed=None) -> None:
        """Instance g placed anew as ``placed`` at t (activities 0, tracking; the kernel's
        covariances measured on ``window`` at ``at``, springtrack.acquisition.spread, ``claimed`` the
        other instances' gates), or moved rigidly onto ``pose`` where its trackers
        (``snap``) hold the model's shape."""
        if pose is None or not self._move(g, pose, snap):
            self.tr.models = self.tr.models.replaced(g, placed)
            if window is not None:
                placed = measured_spread(placed, window, self.tr.models[g].params, at, claimed)
            self.tr._ib.place(g, placed)
        self.tr._ib.set_state(g, TRACKING)
        self._resumed(t, g, kind)
        self._refine_at[g] = t + self.window_us

    def _move(self, g: int, pose, snap) -> bool:
        """Instance g moved rigidly onto ``pose`` (relative to its model) when the backend
        can and its trackers in ``snap`` hold the model's shape (SHAPE_SIGMA); True if so."""
        b = self.tr._ib
        if snap is None or not getattr(b, "movable", False):
            return False
        inst = self.tr.models[g]
        model = inst.model
        x, y = (np.asarray(snap[k], float)[inst.t0:inst.t1] for k in ("x", "y"))
        w, h = self.tr.models.width, self.tr.models.height
        if not ((x >= 0) & (x < w) & (y >= 0) & (y < h)).all():
            return False              # trackers off the sensor took no events: no shape
        now = fit_pose(model, x, y)
        here = place_checked(model, now)
        if here is None or _mahalanobis(here, x, y) >= SHAPE_SIGMA:
            return False
        # the similarity taking the trackers' pose onto the one found: x -> A x + t,
        # A = k R(d), k = s_found / s_now, d = angle_found - angle_now
        k = pose.scale / now.scale
        d = math.radians(pose.angle_deg - now.angle_deg)
        a, bb = k * math.cos(d), k * math.sin(d)
        tx = pose.tx - (a * now.tx - bb * now.ty)
        ty = pose.ty - (bb * now.tx + a * now.ty)
        g0 = model_pose(model)
        moved = place_checked(model, Pose(a * g0.tx - bb * g0.ty + tx, bb * g0.tx + a * g0.ty + ty,
                                          math.degrees(d), k))
        if moved is None:
            return False
        self.tr.models = self.tr.models.replaced(g, moved)
        b.move(g, (a, bb, tx, ty), moved)
        self.moves += 1
        return True

    def _refine(self, t: int, g: int, snap, states) -> None:
        """A window after instance g was re-placed: a narrow search around its trackers on
        the last window; found, the instance is moved onto it (:meth:`_move`)."""
        window = self.ring.window(t - self.window_us, t)
        if len(window) < MIN_EVENTS:
            return
        inst = self.tr.models[g]
        x, y = (np.asarray(snap[k], float)[inst.t0:inst.t1] for k in ("x", "y"))
        now = fit_pose(inst.model, x, y)
        if not (-180.0 + REFINE_DEG <= now.angle_deg <= 180.0 - REFINE_DEG):
            return
        self.attempts += 1
        pose = acquire(inst.model, window, at_us=int(window["t"][-1]),
                       claimed=self._claimed(snap, states, but=g),
                       region=(now.tx - REFINE_PX, now.ty - REFINE_PX,
                               now.tx + REFINE_PX, now.ty + REFINE_PX),
                       angle_deg=(now.angle_deg - REFINE_DEG, now.angle_deg + REFINE_DEG),
                       scale=(now.scale * (1 - REFINE_SCALE), now.scale * (1 + REFINE_SCALE)),
                       **{k: v for k, v in self.bounds.items()
                          if k not in ("region", "angle_deg", "scale")})
        if pose.found and pose.in_view == inst.n:
            self._move(g, pose, snap)

    def _resumed(self, t: int, g: int, kind: str) -> None:
        """Instance g tracks again from t: the rules' clocks restart, the change kept."""
        self.rule.reset(g)
        self.doubt.reset(g, t)
        self._partial.pop(g, None)
        self.changes.append((t, self.tr.models[g].label, kind))
        self._placed(t, g)

    def _doubt_check(self, t: int) -> None:
        """At doubt check time t (the state holds every event before t): each tracking
        instance's share of the events (springtrack.acquisition.loss.ShareDoubt); one in doubt is
        verified, then again once a verification's window (``period / 2``) of new events
        is in, and while the doubt stays and the searches find nothing better, after waits
        doubling up to VERIFY_BACKOFF periods."""
        b = self.tr._ib
        tau = self.tr.models.params.activity_tau_us
        mass, since = self._mass
        lo = t - int(MASS_HORIZON_TAU * tau)
        if since is None or since < lo:
            mass, since = 0.0, lo
        te = self.ring.times_since(since)
        mass = event_mass(te[te < t], t, tau, mass, since)
        self._mass = (mass, t)
        states = b.states()
        snap = None
        for g, inst in enumerate(self.tr.models):
            if states[g] != TRACKING:
                continue
            if snap is None:
                snap = b.snapshot(t)
            if t >= self._refine_at.get(g, NEVER):
                del self._refine_at[g]
                self._refine(t, g, snap, states)
                snap = b.snapshot(t)
            if self._recall(t, g, snap):
                snap = b.snapshot(t)
            taken = float(np.sum(snap["activity"][inst.t0:inst.t1]))
            doubt = self.doubt.doubt(t, g, taken, mass, inst.n)
            if not doubt:
                self._verify_wait[g] = self._verify_span
            if (doubt and t >= self._verify_next[g]) or t >= self._verify_due[g]:
                moved = self._verify(t, g, snap, states)
                self._verify_due[g] = t + VERIFY_EVERY * self.period
                if doubt:
                    wait = self._verify_wait[g]
                    self._verify_wait[g] = (self._verify_span if moved else
                                            min(2 * wait, VERIFY_BACKOFF * self.period))
                    self._verify_next[g] = t + wait

    def _recall(self, t: int, g: int, snap) -> bool:
        """Tracking instance g's trackers left behind (springtrack.acquisition.recall), recalled to
        their rest places in the frame of its active trackers: those trackers relocated
        (``relocate``: activity 0 where they now are), every other tracker, its activity,
        the rest geometry and the frame kept; a backend without ``relocate`` places the
        instance with them there and the others as they are, then restores its rest
        geometry (``move`` by the identity: the activities then start from 0).  True if
        any.  Backends that cannot move an instance do not recall."""
        b = self.tr._ib
        if not getattr(b, "movable", False) or t < self._recall_next.get(g, 0):
            return False
        inst = self.tr.models[g]
        part = {k: np.asarray(snap[k])[inst.t0:inst.t1]
                for k in ("x", "y", "sxx", "sxy", "syy", "active")}
        params = self.tr.models.params
        idx, placed = left_behind(inst.model, part, params.gate_d2,
                                  lambda: self.ring.since(t - int(params.activity_tau_us)),
                                  params.activity_threshold)
        if not len(idx):
            return False
        if hasattr(b, "relocate"):
            # only the trackers left behind move; the others keep their activities
            arr = placed.arrays()
            b.relocate(g, idx, *(arr[k][idx] for k in ("x", "y", "sxx", "sxy", "syy")))
        else:
            b.place(g, recalled(inst.model, part, idx, placed))
            b.move(g, (1.0, 0.0, 0.0, 0.0), inst.model)
        self.doubt.hold_off(g, t)
        self._recall_next[g] = t + self.rule.hold_us    # the activities built up again
        self.recalls += len(idx)
        return True

    def _verify(self, t: int, g: int, snap, states) -> bool:
        """Instance g is in doubt (or due) at t: search for it on the last ``period / 2``
        of events; if it is found away from its trackers (RESUME_SIGMA) and supported
        MOVED_SUPPORT times more than its trackers where they are (and, partly in view, found
        at the same place by the verification before), it moved: lost and re-placed there
        at t (True)."""
        window = self.ring.window(t - self._verify_span, t)
        if len(window) < MIN_EVENTS:
            return False
        self.verifications += 1
        inst = self.tr.models[g]
        model = inst.model
        claimed = self._claimed(snap, states, but=g)
        x, y = (np.asarray(snap[k], float)[inst.t0:inst.t1] for k in ("x", "y"))
        pose = self._acquire_about(model, x, y, window, claimed=claimed)
        if not pose.found:
            return False
        placed = place_checked(model, pose)
        if placed is None:
            self.unplaceable += 1
            return False
        if _where_kept(placed, x, y):
            return False
        here = judge(model, window, fit_pose(model, x, y), claimed=claimed, at=(x, y))
        if pose.supported < MOVED_SUPPORT * max(here.supported, 1):
            return False
        if pose.in_view < inst.n and not self._stays_partly_in_view(g, placed):
            return False
        self._apply(t, [g])
        self._replace(t, g, placed, "reacquired", pose, snap, window, None, claimed)
        return True

    def _stays_partly_in_view(self, g: int, placed) -> bool:
        """A pose found with some trackers off the sensor is taken only when the attempt
        before found it at the same place (RESUME_SIGMA): an object sliding into view is
        found half in view where it will not stay, and a tracker placed there falls
        behind; one that stays at the border is taken one attempt later."""
        a = placed.arrays()
        prev, self._partial[g] = self._partial.get(g), placed
        return prev is not None and _where_kept(prev, a["x"], a["y"])

    def _placed(self, t: int, g: int) -> None:
        a = self.tr.models[g].model.arrays()
        self.placements.append((t, g, np.column_stack([a["x"], a["y"]])))

    def counters(self) -> dict:
        kinds = [c[2] for c in self.changes]
        return dict(reacquire_attempts=self.attempts, verifications=self.verifications,
                    losses_refuted=self.refuted, moved=self.moves, recalled=self.recalls,
                    unplaceable=self.unplaceable, acquired=kinds.count("acquired"),
                    lost=kinds.count("lost"), reacquired=kinds.count("reacquired"))
