"""``springtrack.Tracker``: the Python API over the tracker backends.

    >>> import springtrack
    >>> tr = springtrack.Tracker("grid3x3")                   # preset or TOML path
    >>> track = tr.run(events, sample_us=1000)               # doctest: +SKIP
    >>> tr.state()                                           # doctest: +SKIP

Backends (same results, different speed) are named in one registry,
``springtrack.backends.BACKENDS`` (cython, reference, fixed, mcu; "mcu:cortex-m7" names
the core); each offers the interface of ``springtrack.backends.Backend``.
"""
from __future__ import annotations

import numpy as np

from . import params as _params
from .backends import make_backend, spec_of
from .events import as_events, check as check_events
from .sensor_fit import check_inside
from .instances import NOT_FOUND, SEARCHING, TRACKING, ModelSet
from .acquisition.loss import LOSS_CHECK_US
from .model import ShapeModel
from .params import Params
from .sampling import MAX_PERIOD, PER_EVENT, UNSET, first_sample_time, multiples
from .track import STATE_NAMES, TRACK_DTYPE, TRACK_FIELDS, Track, data_address, join_rows

SAMPLE_CAP = 4096          # sample rows per kernel call; bounds memory for huge time gaps
ROOM_BYTES = 1 << 30       # largest buffer Tracker.run sizes ahead for its samples
_SIZE_ROOM = object()      # Tracker.run asks _run for a _Room


class _Room:
    """One buffer for the sample rows of a :meth:`Tracker.run` call, sized ahead from its
    events' time span, so that the kernel writes every row once where the returned Track
    keeps it (rather than a buffer per kernel call, joined by a copy).  Rows beyond it go
    to buffers of SAMPLE_CAP rows as usual."""

    def __init__(self, rows: int, n: int):
        self.t = np.empty(rows, np.int64)
        self.trackers = np.empty((rows, n), TRACK_DTYPE)
        self.energy = np.empty((rows, 3))
        self.used = 0
        self.parts = 0                    # kernel calls that wrote their rows here

    @classmethod
    def sized(cls, ev, period: int, next_t: int, n: int) -> "_Room | None":
        """A room for the samples of ``ev`` (time-ordered but for events back in time)
        every ``period`` µs: one per multiple of the period up to the last event's time,
        at most PER_EVENT per event (springtrack.sampling); None where SAMPLE_CAP rows hold
        them or it would take more than ROOM_BYTES."""
        if not period or not len(ev):
            return None
        t0, t1 = int(ev["t"][0]), int(ev["t"][-1])
        start = next_t if next_t != UNSET else first_sample_time(t0, period)
        rows = min((t1 - start) // period + 1, PER_EVENT * len(ev)) if t1 >= start else 0
        if rows <= SAMPLE_CAP or rows * (n * TRACK_DTYPE.itemsize + 32) > ROOM_BYTES:
            return None
        try:
            return cls(rows, n)
        except MemoryError:          # no address space for it (strict overcommit): per call
            return None

    def rest(self) -> dict | None:
        """The rows not written yet, as buffers for a backend's ``run(into=...)``."""
        u = self.used
        if u >= len(self.t):
            return None
        return {"t": self.t[u:], "trackers": self.trackers[u:], "energy": self.energy[u:]}

    def took(self, out: dict) -> None:
        """Count a backend's sample rows ``out`` if it wrote them here (a backend may
        return rows of its own)."""
        u = self.used
        if (u < len(self.t) and len(out["t"])
                and data_address(out["t"]) == data_address(self.t[u:])
                and data_address(out["trackers"]) == data_address(self.trackers[u:])):
            self.used += len(out["t"])
            self.parts += 1

    def track(self, parts: list, ids) -> "Track | None":
        """The run's samples as one Track if every part was written here, in order (a
        compact copy when the room is less than half used: the span overestimated them,
        an empty stretch sampled only for its hold), else None."""
        if self.parts != len(parts):
            return None
        u = self.used
        t, rows, en = self.t[:u], self.trackers[:u], self.energy[:u]
        if 2 * u < len(self.t):
            t, rows, en = t.copy(), join_rows([rows]), en.copy()
        return Track.of_rows(t, ids, rows, en)



class _OneInstance:
    """A kernel of one model (fixed, mcu: placed by hand, without acquisition) seen through
    the instances' interface.  Its one instance tracks throughout: states change only under
    acquisition, which runs every backend on its kernel of a set (``Tracker._use``)."""

    def __init__(self, tracker):
        self.tr = tracker

    def __getattr__(self, key):
        return getattr(self.tr._b, key)

    def mean_energies(self):
        return [self.tr._b.mean_energy]

    def set_params(self, params):
        self.tr._b.set_params(params if isinstance(params, Params) else params[0])

    def frame(self, g: int = 0):
        return self.tr._b.frame()

    def states(self):
        return [int(TRACKING)]

    movable = True          # every one-model kernel moves its instance rigidly

    def move(self, g, sim, model):
        """Instance g moved rigidly by ``sim`` (springtrack.reference.ReferenceTracker.move),
        ``model`` its model moved by the same similarity."""
        self.tr._b.move(sim, model)

    def relocate(self, g, idx, x, y, sxx, sxy, syy):
        """Instance g's trackers ``idx`` put elsewhere, the others kept
        (springtrack.reference.ReferenceTracker.relocate)."""
        self.tr._b.relocate(idx, x, y, sxx, sxy, syy)

    def snapshot(self, t):
        snap = self.tr._b.snapshot(t)
        snap["state"] = np.full(len(snap["x"]), TRACKING, np.uint8)
        return snap

    def counters(self):
        return dict(self.tr._b.counters())


def resolve_params(model: ShapeModel, params=None) -> Params:
    """Defaults, then the model's [params], then ``params`` (Params, dict or TOML path)."""
    return _params.resolve(model, params)


class Tracker:
    """Part-based shape tracker. Feed events in time order, in as many chunks as you like.

    ``model``: a ShapeModel, a preset name or a TOML path, its trackers on its sensor
    (``springtrack.sensor_fit.TrackersOutside`` otherwise), or a list of them: several model
    instances in one tracker (springtrack.instances: one event assignment across all,
    springs and energies per instance), ``instances`` copies of each; ``params``: Params,
    a dict of overrides, a TOML path, or None (defaults < model [params] < these, per
    instance).  Events that go back in time or fall outside the sensor are skipped and
    counted (:attr:`counters`), never raised.

    ``acquire=True``: the models' positions are not trusted; the first ``acquire_ms`` of
    events are buffered and the instances are found in them (:mod:`springtrack.acquisition.acquire`;
    ``acquire_bounds``: its region, angle_deg, scale; each instance found explains its
    events away before the next search), placed there, and tracked from the window's first
    event.  While none is found the window slides by half its length (:attr:`acquisition`
    counts the attempts and the events dropped) and the samples of the events let go show
    every instance at its model's place, insensitive, ``searching``; call :meth:`flush` at
    the end of the input to try on a last, shorter window.  An instance still unfound then,
    or once ``acquire_budget_ms`` of event time is searched in vain (None: until the input
    ends), is ``not found``: its samples say so and later events are not searched.  Then
    the loss rule watches every instance, and an
    instance not found yet or lost is searched for again in the recent events
    (:mod:`springtrack.acquisition.recovery`); :attr:`changes` lists every change of state with its
    event time.
    """

    def __init__(self, model, params=None, backend: str = "cython", acquire: bool = False,
                 acquire_ms: float = 50.0, acquire_bounds: dict | None = None,
                 instances: int = 1, acquire_budget_ms: float | None = None):
        self.models = ModelSet(model, params, instances)
        if not acquire:          # placed by the acquisition otherwise
            for m in self.models.models:
                check_inside(m)
        self.backend_name = backend
        self._acquire = acquire
        self._use(self.models)
        self._sample_us = 0
        self._next_t = UNSET
        self._skipped = 0                    # sample times of empty stretches not taken
        self._recorded: list[Track] = []
        self._room = None                    # Tracker.run's sample buffer (_Room)
        self.acquisition = None
        self.recovery = None
        if acquire:
            from .acquisition.acquire import Acquisition
            budget = None if acquire_budget_ms is None else int(round(acquire_budget_ms * 1000))
            self.acquisition = Acquisition(self.models, int(round(acquire_ms * 1000)), budget,
                                           **(acquire_bounds or {}))
        self._search_t = UNSET               # the last sample time of a search's rows
        self._search_wait = np.empty(0, np.int64)   # its sample times not yet final

    def _use(self, mset: ModelSet) -> None:
        """A backend for ``mset``: ``_b`` the kernel, ``_ib`` the kernel with the
        instances' interface (states, set_state, place).  One instance placed by hand runs
        on the backend's kernel of one model; several, or any with acquisition (whose
        states change), on its kernel of a set (fixed: FixedSet, mcu: McuSet), which holds
        a lost instance as the reference does."""
        if len(mset) > 1 or self._acquire:
            self._b = make_backend(self.backend_name, mset, None)
        else:
            self._b = make_backend(self.backend_name, mset[0].model, mset[0].params)
        self._ib = self._b if hasattr(self._b, "states") else _OneInstance(self)

    @property
    def model(self) -> ShapeModel:
        """The first instance's model (as placed, with acquisition)."""
        return self.models[0].model

    @property
    def params(self) -> Params:
        """The first instance's parameters (the shared ones are every instance's)."""
        return self.models.params

    @property
    def ids(self) -> list[str]:
        """Tracker ids, unique across the instances (springtrack.instances.unique_ids)."""
        return self.models.ids

    @property
    def changes(self) -> list:
        """Every change of an instance's state, in order: (event time µs, instance label,
        "acquired" | "lost" | "reacquired")."""
        return [] if self.recovery is None else list(self.recovery.changes)

    def instances(self) -> list[dict]:
        """Per instance: label, model name, state name and its counts of changes."""
        states = self._ib.states() if self._found_any() else [self._search_state()] * len(self.models)
        out = []
        for g, inst in enumerate(self.models):
            counts = {k: 0 for k in ("acquired", "lost", "reacquired")}
            for _, label, kind in self.changes:
                if label == inst.label:
                    counts[kind] += 1
            out.append(dict(label=inst.label, model=inst.model.name,
                            state=STATE_NAMES[states[g]], **counts))
        return out

    # ---- feeding -------------------------------------------------------------------
    def record(self, sample_us: int) -> None:
        """Keep a snapshot every ``sample_us`` µs of event time (state after events with
        t < multiple; an empty stretch only for its first ``sampling.HOLD`` periods and at its end, see
        springtrack.sampling); the kernel takes them inside its loop.  Collect with
        :meth:`samples`, or take them as they come with :meth:`stream`."""
        sample_us = int(sample_us)
        if not 0 < sample_us < MAX_PERIOD:
            raise ValueError(f"sample_us must be a positive number of microseconds below "
                             f"{MAX_PERIOD}, got {sample_us}")
        if self._sample_us and sample_us != self._sample_us:
            raise ValueError("the sampling period cannot change once recording has started")
        self._sample_us = sample_us

    def process(self, events) -> None:
        """Consume an event array (fields t µs, x, y, p), in time order; the samples taken
        wait for :meth:`samples`.  The kernels read the common layouts as they are (packed
        or aligned records, t int64 or uint64, x/y int16 or uint16, p bool or int:
        ``springtrack.backends.stepper.layout_of``), converting them block by block inside their
        loop; anything else is converted first.  Either way the values are checked
        (``springtrack.events.check``: EventError for the first event out of range)."""
        self._recorded.extend(self.stream(events))

    def stream(self, events):
        """Consume an event array like :meth:`process`, yielding the samples as the kernel
        takes them: Tracks of at most ``SAMPLE_CAP`` rows, so memory stays bounded however
        many samples the events produce."""
        if self.acquisition is not None:
            ev = as_events(events)
            if not self.acquisition.done:
                ready = self.acquisition.feed(ev)
                yield from self._searching(ready)
                ev = self._placed(ready)
            yield from self._track(ev)
            return
        if self._reads_as_is(events):
            from .backends.stepper import in_range
            if not in_range(events):       # one pass; else field by field, naming the first
                check_events(events)
        else:
            events = as_events(events)
        yield from self._track(events)

    def _reads_as_is(self, events) -> bool:
        """The backend's loop reads ``events`` without a conversion first."""
        if not spec_of(self.backend_name)[0].reads_layouts:
            return False
        from .backends.stepper import layout_of
        return layout_of(events) is not None

    def flush(self) -> None:
        """End of input: if the acquisition is still looking, try on what it buffered."""
        if self.acquisition is not None and not self.acquisition.done:
            ready = self.acquisition.finish()
            self._recorded.extend(self._searching(ready))
            self._recorded.extend(self._track(self._placed(ready)))

    def _found_any(self) -> bool:
        return self.acquisition is None or self.acquisition.done

    def _search_state(self) -> int:
        """Every instance's state while none is found: searching, or not found."""
        return int(NOT_FOUND if self.acquisition.exhausted else SEARCHING)

    def _searching(self, ready=None):
        """The samples of the events the acquisition let go unfound, as a Track: one at
        the first sample time after each event (the state there follows it: the sampling
        rule), every instance at its model's place, inactive and insensitive, in its search
        state.  A time the tracking may still take (at or after the first event still
        buffered, or ``ready``'s first, those of a find) waits, or goes once found."""
        acq = self.acquisition
        t = acq.take_dropped()
        q = self._sample_us
        if not q:
            return
        times = np.union1d(self._search_wait, (t // q + 1) * q)
        times = times[times > self._search_t]
        kept = int(ready["t"][0]) if ready is not None else acq.first_kept_t
        self._search_wait = np.empty(0, np.int64)
        if kept is not None:
            if ready is None:
                self._search_wait = times[times >= kept]
            times = times[times < kept]
        if not len(times):
            return
        self._search_t = int(times[-1])
        a = self.models.arrays()
        rows = np.zeros((len(times), len(self.ids)), TRACK_DTYPE)
        for f in ("x", "y", "sxx", "sxy", "syy"):
            rows[f] = a[f]
        rows["state"] = self._search_state()
        yield Track.from_samples({"t": times.astype(np.int64), "trackers": rows,
                                  "energy": np.zeros((len(times), 3))}, self.ids)

    def _placed(self, ready):
        """The events to track: none while acquiring; once an instance is found, the
        instances placed at the poses found (the others searching) and the buffered
        events, from which the loss rule and the re-acquisition take over."""
        if ready is None:
            return ready
        from .acquisition.acquire import place
        from .acquisition.recovery import Recovery
        from .acquisition.spread import measured_set
        acq = self.acquisition
        mset = self.models
        for g, pose in enumerate(acq.poses):
            if pose is not None and pose.found:
                mset = mset.replaced(g, place(mset[g].model, pose))
        self.models = mset
        # the kernel starts from the covariances measured on the window (springtrack.acquisition.spread);
        # the set keeps the models' own, which the searches use
        t0 = int(ready["t"][0])
        found = [g for g, p in enumerate(acq.poses) if p is not None and p.found]
        self._use(measured_set(mset, ready[ready["t"] < t0 + acq.window_us], t0, found))
        self.recovery = Recovery(self, acq.window_us, acq.bounds)
        self.recovery.start(int(ready["t"][0]), [p is not None and p.found for p in acq.poses])
        return ready

    def _track(self, ev):
        """Run the backend over ``ev`` in calls of at most SAMPLE_CAP sample rows; yield
        each call's samples as a Track."""
        if ev is None or len(ev) == 0:
            return
        if self.recovery is not None:
            yield from self.recovery.track(ev)
            return
        yield from self._run(ev)

    def _run(self, ev):
        """Run the backend over ``ev`` in calls of at most SAMPLE_CAP sample rows; yield
        each call's samples as a Track.  With the recovery the backend also samples at the
        loss rule's check times, whose rows go to the recovery first."""
        rec = self.recovery
        q = self._sample_us
        p = q if rec is None else rec.sample_period(q)
        if self._room is _SIZE_ROOM:
            self._room = _Room.sized(ev, p, self._next_t, len(self.ids)) if rec is None else None
        room = self._room
        pos = 0
        while pos < len(ev):
            start = self._next_t
            if p and start == UNSET:
                start = first_sample_time(int(ev["t"][pos]), p)
            into = room.rest() if room is not None else None
            cap = SAMPLE_CAP if into is None else len(into["t"])
            consumed, self._next_t, out = self._b.run(ev[pos:], p, self._next_t, cap, into=into)
            pos += consumed
            if into is not None and out is not None:
                room.took(out)
            t = out["t"] if out is not None else np.empty(0, np.int64)
            if q:                    # the sample times passed over, less those taken
                self._skipped += multiples(start, self._next_t, q) - int(np.count_nonzero(t % q == 0))
            if not len(t):
                continue
            if isinstance(self._ib, _OneInstance):      # its kernel keeps no states
                out["trackers"]["state"] = TRACKING
            if rec is not None:      # the loss rule's checks are samples too
                chk = t % LOSS_CHECK_US == 0
                rec.rows(t[chk], out["trackers"]["active"][chk])
                if p != q:
                    keep = t % q == 0 if q else np.zeros(len(t), bool)
                    out = {k: out[k][keep] for k in ("t", "trackers", "energy")}
                    if not len(out["t"]):
                        continue
            yield Track.from_samples(out, self.ids)

    def run(self, events, sample_us: int = 1000) -> Track:
        """Process events and return the samples taken during this call (at most
        ``sampling.PER_EVENT`` per event: see :meth:`record`)."""
        self.record(sample_us)
        self._room = _SIZE_ROOM              # _run sizes it on the events as checked
        try:
            parts = list(self.stream(events))
            room = self._room
        finally:
            self._room = None
        new = room.track(parts, self.ids) if isinstance(room, _Room) else None
        if new is None:
            new = Track.concat(parts, self.ids)
        if len(new):                 # kept once: samples() returns it as it is
            self._recorded.append(new)
        return new

    def samples(self, clear: bool = True) -> Track:
        """The samples recorded (by :meth:`process`, :meth:`run`, :meth:`flush`) since the
        last call that cleared them; a Track returned by :meth:`run` is shared, not copied."""
        tr = Track.concat(self._recorded, self.ids)
        if clear:
            self._recorded = []
        return tr

    # ---- control ---------------------------------------------------------------------
    def set_params(self, params=None, **changes) -> Params:
        """Change parameters between two events, for every instance (``params`` over the
        defaults and each model's [params], then ``changes``); returns the first
        instance's new Params."""
        if params is not None:
            plist = [resolve_params(m, params) for m in self.models.models]
        else:
            plist = self.models.params_list
        if changes:
            plist = [_params.from_mapping(changes, p) for p in plist]
        self.models = self.models.with_params(plist)
        self._ib.set_params(plist)
        return plist[0]

    # ---- observation -----------------------------------------------------------------
    @property
    def last_t(self) -> int:
        return int(self._b.last_t)

    def state(self, t: int | None = None) -> np.ndarray:
        """Per-tracker structured array (id, x, y, sxx, sxy, syy, activity, vx, vy, active,
        sensitive, state) at event time ``t`` (default: the last event's time)."""
        t = self.last_t if t is None else int(t)
        snap = self._ib.snapshot(max(t, 0) if t < -(1 << 60) else t)
        dt = np.dtype([("id", f"U{max(len(i) for i in self.ids)}")]
                      + [(f, TRACK_DTYPE[f]) for f in TRACK_FIELDS])
        out = np.empty(len(self.ids), dt)
        out["id"] = self.ids
        for f in TRACK_FIELDS:
            out[f] = snap[f]
        return out

    def energies(self) -> dict:
        """Energies per connection (of every instance, in order, each at its instance's
        last spring update) for each kind (eqs. 12, 17, 20); ``mean``, the first
        instance's mean of the kind that feeds its criteria (eqs. 21-22), ``means`` every
        instance's."""
        e = self._b.energies()
        return {"euclidean": e[0], "torsional": e[1], "cartesian": e[2],
                "mean": float(self._b.mean_energy),
                "means": [float(v) for v in self._ib.mean_energies()],
                "kind": self.params.energy_kind}

    def frame(self, instance: int = 0) -> dict:
        """An instance's similarity frame of the last spring update (``pull_frame`` or
        ``cartesian_frame`` = "similarity", docs/algorithm.md): ``scale`` s, ``angle`` of R
        (rad), and ``gx``, ``gy``, where the rest centre of mass G0 maps to (px); scale 1,
        angle 0 and G0 until a spring update fits one, or in the image frame."""
        c, sn, gx, gy = (float(v) for v in self._ib.frame(instance))
        return {"scale": float(np.hypot(c, sn)), "angle": float(np.arctan2(sn, c)),
                "gx": gx, "gy": gy}

    @property
    def counters(self) -> dict:
        c = dict(self._ib.counters())
        if self._sample_us:
            c["samples_skipped"] = self._skipped
        if self.acquisition is not None:
            c.update(acquire_attempts=self.acquisition.attempts,
                     acquire_events_dropped=self.acquisition.events_dropped)
        if self.recovery is not None:
            c.update(self.recovery.counters())
        return c


def profile(tracker: Tracker, events, bin_us: int = 10_000, sink=None) -> dict:
    """Process ``events`` bin by bin (``bin_us`` of event time) and time each bin: the
    quantity of the paper's Figs. 22-23.  Returns arrays ``t_us`` (bin start), ``events``
    and ``proc_us`` (wall time spent in the kernel, µs; includes ~1 µs of call overhead)
    for the bins that hold events (a run of events in one bin; an empty stretch has no
    bins, so the arrays are bounded by the events, not their time span).  The samples
    taken go to ``sink`` as they come (see :meth:`Tracker.stream`), else wait for
    :meth:`Tracker.samples`; the time spent in ``sink`` is not counted."""
    import time
    ev = as_events(events)
    b = ev["t"] // bin_us
    starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]]) if len(ev) else np.empty(0, np.int64)
    ends = np.r_[starts[1:], len(ev)].astype(np.int64)
    keep = sink if sink is not None else tracker._recorded.append
    proc = np.zeros(len(starts))
    for k in range(len(starts)):
        spent, tick = 0.0, time.perf_counter()
        for part in tracker.stream(ev[starts[k]:ends[k]]):
            spent += time.perf_counter() - tick
            keep(part)
            tick = time.perf_counter()
        proc[k] = (spent + time.perf_counter() - tick) * 1e6
    return {"t_us": (b[starts] * bin_us).astype(np.int64), "events": ends - starts,
            "proc_us": proc}
