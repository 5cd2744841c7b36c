"""The loss rule, the same for every backend: when a model instance's evidence collapses.

*A tracking instance is lost when fewer than a third of its trackers are active
(A_i > A_up, eq. 6) at every loss check over ``LOSS_HOLD_TAU`` activity time constants
of event time, once its evidence was there: at least a third of its trackers active at
one check since it was placed.*  The checks are at the multiples T of ``LOSS_CHECK_US``
of event time, on the state that holds every event before T (a sample: the sampling rule
of springtrack.sampling), and count only when an event came in the LOSS_CHECK_US before
T: no events, no check, so a silent sensor is not a loss until events come again.

Why activity (docs/acquisition.md): when the object jumps away, leaves the view or is
fully hidden, its trackers receive no events and their activity decays with tau; the
energy of eq. (13) would not notice (trackers left on empty space stop moving, their
springs stay at rest), and energies of different kinds are not comparable.  The hold
rides out short gaps (a blink, an occluder's edge); a fraction rather than "none"
because clutter crossing a lost model keeps a few trackers active.  Evidence that was
never there cannot collapse: an object too faint or slow to keep a third of its trackers
active (A_up is a rate: about A_up / tau events per second per tracker) is not declared
lost over and over, and a freshly placed instance (activities 0) has time to gather it.

*Doubt* (:class:`ShareDoubt`) is the quick signal that asks for a verification rather
than a verdict: the share of the sensor's events an instance's trackers take, the sum of
their activities (eq. 6: each event taken adds its kernel value, decaying with tau) over
the same sum for every event on the sensor (as if one tracker had taken each with
kernel value 1), falls below DOUBT_SHARE of its own running level.  A jump shows at once
(the trackers stop taking while the object's events go on elsewhere); a motion reversal
does not (the object and its share of the events pause together); an occluder does
(its events are not taken), which is why doubt only triggers a search and the search
decides (springtrack.acquisition.recovery).

Every backend reports the same ``active`` flags (the fixed kernel agrees with the float
kernel on them, docs/benchmarks.md), so :class:`LossRule` reads them from the backend's
snapshot and decides in one place.
"""
from __future__ import annotations

import math

import numpy as np

LOSS_ACTIVE_DIV = 3      # lost while LOSS_ACTIVE_DIV x (active trackers) < trackers ...
LOSS_HOLD_TAU = 3.0      # ... at every check for this many activity time constants
LOSS_CHECK_US = 1000     # checks at the multiples of this much event time
DOUBT_CHECK_US = 5000    # doubt is looked at on the multiples of this much event time
DOUBT_SHARE = 0.7        # in doubt below this x its running share of the events
SHARE_LEVEL_TAU = 100.0  # the running share's time constant, in activity time constants
MASS_HORIZON_TAU = 8.0   # events older than this many tau no longer count in the mass


def loss_hold_us(params) -> int:
    """The hold time in µs for these parameters: LOSS_HOLD_TAU tau, rounded up to whole
    check periods."""
    return int(math.ceil(LOSS_HOLD_TAU * params.activity_tau_us / LOSS_CHECK_US)) * LOSS_CHECK_US


def counted(t, last_event_before) -> np.ndarray:
    """Which check times ``t`` count: an event came in the LOSS_CHECK_US before each
    (``last_event_before``: the time of the last event before each check)."""
    return np.asarray(last_event_before) >= np.asarray(t) - LOSS_CHECK_US


def collapsed(active, n: int) -> bool:
    """The evidence of an instance of ``n`` trackers with ``active`` of them active is
    too low: LOSS_ACTIVE_DIV x active < n."""
    return LOSS_ACTIVE_DIV * int(active) < n


class LossRule:
    """The rule's clock for ``ranges`` (per instance: its trackers [t0, t1)) and a hold
    of ``hold_us``.  :meth:`check` at a check time returns the instances lost then;
    :meth:`earliest` says how long no loss can happen, so that a driver may run events up
    to then in one go and feed the checks in between afterwards."""

    def __init__(self, ranges, hold_us: int, start_us: int = 0):
        self.ranges = [(int(a), int(b)) for a, b in ranges]
        self.hold_us = int(hold_us)
        self.last = (int(start_us) // LOSS_CHECK_US) * LOSS_CHECK_US   # last check time seen
        self.low_since = [None] * len(self.ranges)   # first check that found it low
        self.armed = [False] * len(self.ranges)      # its evidence was there once

    def reset(self, g: int) -> None:
        """Instance g (re)starts tracking, placed anew: its clock restarts, disarmed."""
        self.low_since[g] = None
        self.armed[g] = False

    def earliest(self, tracking) -> int:
        """The first check time at which an instance could be found lost (a multiple of
        LOSS_CHECK_US after :attr:`last`); 1 << 62 when none is tracking."""
        out = 1 << 62
        for g, on in enumerate(tracking):
            if on:
                low = self.low_since[g]
                start = low if (low is not None and self.armed[g]) else self.last + LOSS_CHECK_US
                out = min(out, max(start + self.hold_us, self.last + LOSS_CHECK_US))
        return out

    def skip_to(self, t: int) -> None:
        """Check times up to ``t`` were not counted (no events before them)."""
        self.last = max(self.last, int(t))

    def check_rows(self, ts, active, tracking) -> list:
        """:meth:`check` at each of the counted check times ``ts`` (k,) in order, ``active``
        (k, n); returns [(t, [instances lost at t]), ...] for the times that lost any.
        While every tracking instance has its evidence at every row (the common case) the
        rows are taken at once."""
        ts = np.asarray(ts, np.int64)
        if not len(ts):
            return []
        active = np.asarray(active, bool)
        well = all(not on or not np.any(LOSS_ACTIVE_DIV * active[:, a:b].sum(axis=1) < b - a)
                   for on, (a, b) in zip(tracking, self.ranges))
        if well:
            for g, on in enumerate(tracking):
                if on:
                    self.armed[g] = True
                self.low_since[g] = None
            self.last = max(self.last, int(ts[-1]))
            return []
        out = []
        for t, act in zip(ts.tolist(), active):
            lost = self.check(t, act, tracking)
            if lost:
                out.append((t, lost))
        return out

    def check(self, t: int, active, tracking) -> list:
        """At check time ``t``: ``active`` (n,) bool of every tracker, ``tracking`` per
        instance; the instances found lost (their clocks reset)."""
        self.last = max(self.last, int(t))
        active = np.asarray(active, bool)
        lost = []
        for g, (t0, t1) in enumerate(self.ranges):
            low = collapsed(active[t0:t1].sum(), t1 - t0)
            if tracking[g] and not low:
                self.armed[g] = True
            if not tracking[g] or not low or not self.armed[g]:
                self.low_since[g] = None
                continue
            if self.low_since[g] is None:
                self.low_since[g] = t
            if t - self.low_since[g] >= self.hold_us:
                lost.append(g)
                self.low_since[g] = None
        return lost


def event_mass(t_events, t: int, tau_us: float, mass: float = 0.0, since: int | None = None) -> float:
    """The activity (eq. 6) of a tracker that took every event with kernel value 1, at
    time ``t``: sum over ``t_events`` (all before t) of exp(-(t - t_ev) / tau), plus
    ``mass`` carried from time ``since`` (decayed to t)."""
    out = 0.0 if since is None else mass * math.exp(-(int(t) - int(since)) / tau_us)
    te = np.asarray(t_events, np.float64)
    if len(te):
        out += float(np.exp((te - float(t)) / tau_us).sum())
    return out


class ShareDoubt:
    """Per instance: its share of the sensor's events, sum of its trackers' activities
    over :func:`event_mass`, against a running level (time constant SHARE_LEVEL_TAU tau,
    started a hold after the instance is placed, when its activities have built up).
    :meth:`doubt` says whether the share fell below DOUBT_SHARE of the level."""

    def __init__(self, n_instances: int, tau_us: float, hold_us: int):
        self.tau = float(tau_us)
        self.hold = int(hold_us)
        self.level = [None] * n_instances      # running share
        self.t = [None] * n_instances          # time of the last update
        self.start = [0] * n_instances         # the level starts from here

    def reset(self, g: int, t: int) -> None:
        """Instance g placed or resumed at t: a new level, from a hold after t."""
        self.level[g], self.t[g], self.start[g] = None, None, int(t) + self.hold

    def hold_off(self, g: int, t: int) -> None:
        """Instance g's activities were reset at t, its place kept (a recall,
        springtrack.acquisition.recall): not judged for a hold, its level kept."""
        self.start[g] = max(self.start[g], int(t) + self.hold)

    def doubt(self, t: int, g: int, taken: float, mass: float, n: int) -> bool:
        """At time t, instance g (``n`` trackers, activities summing to ``taken``) with
        the sensor's event ``mass``: in doubt?  Too few events on the sensor (mass below
        n): no doubt and no update, nothing to judge by."""
        if t < self.start[g] or mass < n:
            return False
        share = taken / mass
        level = self.level[g]
        if level is None:
            self.level[g], self.t[g] = share, int(t)
            return False
        low = share < DOUBT_SHARE * level
        # the running level: level += (share - level)(1 - exp(-dt / (SHARE_LEVEL_TAU tau)))
        k = 1.0 - math.exp(-(int(t) - self.t[g]) / (SHARE_LEVEL_TAU * self.tau))
        self.level[g] = level + (share - level) * k
        self.t[g] = int(t)
        return low
