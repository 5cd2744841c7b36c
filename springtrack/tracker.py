"""``springtrack.Tracker``: the Python API over the tracker backends.

    >>> import springtrack
    >>> tr = springtrack.Tracker("grid3x3")                   # preset or TOML path
    >>> track = tr.run(events, sample_us=1000)               # doctest: +SKIP
    >>> tr.state()                                           # doctest: +SKIP

Backends (same results, different speed):

* ``"cython"``    float64 kernel (``_kernel.pyx``), equal to the reference to 1e-9 px;
* ``"reference"`` the pure-Python executable specification (``reference.py``), slow;
* ``"fixed"``     the integer-only kernel, when built (see docs/fixed_point.md);
* ``"mcu"``       that kernel's microcontroller build (``"mcu:cortex-m7"``, ... names the
                  core; default Cortex-M4) run in an instruction-set emulator: the same
                  results as ``"fixed"``, bit for bit, slowly (springtrack/mcu/, the
                  ``[mcu]`` extra).

Each backend object offers ``run(events, sample_us, next_t, cap)``, ``set_params``,
``snapshot(t)``, ``energies()``, ``mean_energy``, ``mean_energies()``, ``frame(g)``,
``last_t`` and ``counters()``, and for the instances' states (springtrack.instances)
``states()``, ``losses()``, ``set_state(g, state)``, ``place(g, model)`` and
``enable_loss(on)``.  A backend is made from a ShapeModel and its Params or from a
``ModelSet`` (params None: each instance's own).
"""
from __future__ import annotations

import importlib

import numpy as np

from . import params as _params
from .events import as_events, check as check_events
from .geometry import check_inside
from .instances import NOT_FOUND, SEARCHING, TRACKING, ModelSet
from .loss import LOSS_CHECK_US
from .model import ShapeModel
from .params import Params
from .reference import ReferenceTracker
from .sampling import MAX_PERIOD, UNSET, first_sample_time, next_sample, sample_due
from .track import STATE_NAMES, TRACK_DTYPE, TRACK_FIELDS, Track

BACKENDS = ("cython", "reference", "fixed", "mcu")
SAMPLE_CAP = 4096          # sample rows per kernel call; bounds memory for huge time gaps


class ReferenceBackend:
    """Adapts ReferenceTracker to the backend interface; its ``run`` is the kernels'
    ``run`` (springtrack/_stepper.pyx) in Python, with the same sampling rule
    (springtrack.sampling)."""

    def __init__(self, model, params):
        self.ref = ReferenceTracker(model, params)

    def set_params(self, params) -> None:
        self.ref.set_params(params)

    def run(self, events, sample_us, next_t, cap):
        ref = self.ref
        rows = []
        ts, xs, ys = events["t"].tolist(), events["x"].tolist(), events["y"].tolist()
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
            ref.step(t, xs[k], ys[k])
        return len(ts), next_t, (self._pack(rows) if sample_us > 0 else None)

    def _mean_energies(self):
        nc = self.ref.nc
        return [sum(e) / nc if nc else 0.0 for e in self.ref.energy]

    def _pack(self, rows):
        """Sample rows as the C loops return them (springtrack._samples.sample_buffers)."""
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

    movable = True

    def move(self, g: int, sim, model) -> None:
        self.ref.move(g, sim, model)


def _cython_backend(model, params, option):
    from ._kernel import Kernel
    return Kernel(model, params)         # one ShapeModel or a ModelSet


def _fixed_backend(model, params, option):
    try:
        mod = importlib.import_module("springtrack._fixed")
    except ImportError as e:
        raise ValueError(f"backend 'fixed' is not available in this build: {e}") from None
    if isinstance(model, ModelSet):                       # one fx_state per instance
        return mod.FixedSet(model if params is None else model.with_params(params))
    return mod.FixedKernel(model, params)


def _mcu_backend(model, params, option):
    from .mcu import MissingExtra
    try:
        from .mcu.backend import DEFAULT_TARGET, McuBackend, McuSet
        if isinstance(model, ModelSet):                   # one fx_state per instance
            return McuSet(model if params is None else model.with_params(params),
                          target=option or DEFAULT_TARGET)
        return McuBackend(model, params, target=option or DEFAULT_TARGET)
    except (MissingExtra, RuntimeError) as e:      # no toolchain, a failed build or run
        raise ValueError(f"backend 'mcu': {e}") from None


# name -> factory(model, params, option); "name:option" passes the option (the mcu's core)
_FACTORIES = {"reference": lambda m, p, o: ReferenceBackend(m, p), "cython": _cython_backend,
              "fixed": _fixed_backend, "mcu": _mcu_backend}


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

    def snapshot(self, t):
        snap = self.tr._b.snapshot(t)
        snap["state"] = np.full(len(snap["x"]), TRACKING, np.uint8)
        return snap

    def counters(self):
        return dict(self.tr._b.counters())


def make_backend(name: str, model: ShapeModel, params: Params):
    base, _, option = name.partition(":")
    if base not in _FACTORIES or (option and base != "mcu"):
        raise ValueError(f"unknown backend {name!r}; choose from {', '.join(BACKENDS)} "
                         f"(mcu:TARGET names a core)")
    return _FACTORIES[base](model, params, option)


def _multiples(a: int, b: int, q: int) -> int:
    """How many multiples of q lie in [a, b)."""
    return -(-b // q) - -(-a // q) if b > a else 0


def resolve_params(model: ShapeModel, params=None) -> Params:
    """Defaults, then the model's [params], then ``params`` (Params, dict or TOML path)."""
    return _params.resolve(model, params)


class Tracker:
    """Part-based shape tracker. Feed events in time order, in as many chunks as you like.

    ``model``: a ShapeModel, a preset name or a TOML path, its trackers on its sensor
    (``springtrack.geometry.TrackersOutside`` otherwise), or a list of them: several model
    instances in one tracker (springtrack.instances: one event assignment across all,
    springs and energies per instance), ``instances`` copies of each; ``params``: Params,
    a dict of overrides, a TOML path, or None (defaults < model [params] < these, per
    instance).  Events that go back in time or fall outside the sensor are skipped and
    counted (:attr:`counters`), never raised.

    ``acquire=True``: the models' positions are not trusted; the first ``acquire_ms`` of
    events are buffered and the instances are found in them (:mod:`springtrack.acquire`;
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
    (:mod:`springtrack.reacquire`); :attr:`changes` lists every change of state with its
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
        self.acquisition = None
        self.recovery = None
        if acquire:
            from .acquire import Acquisition
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
        t < multiple; an empty stretch only for its first ``sampling.HOLD`` periods, see
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
        ``springtrack._stepper.layout_of``), converting them block by block inside their
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
            check_events(events)
        else:
            events = as_events(events)
        yield from self._track(events)

    def _reads_as_is(self, events) -> bool:
        """The backend's loop reads ``events`` without a conversion first."""
        if self.backend_name not in ("cython", "fixed"):
            return False
        from ._stepper import layout_of
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
        from .acquire import place
        from .reacquire import Recovery
        from .spread import measured_set
        acq = self.acquisition
        mset = self.models
        for g, pose in enumerate(acq.poses):
            if pose is not None and pose.found:
                mset = mset.replaced(g, place(mset[g].model, pose))
        self.models = mset
        # the kernel starts from the covariances measured on the window (springtrack.spread);
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
        pos = 0
        while pos < len(ev):
            start = self._next_t
            if p and start == UNSET:
                start = first_sample_time(int(ev["t"][pos]), p)
            consumed, self._next_t, out = self._b.run(ev[pos:], p, self._next_t, SAMPLE_CAP)
            pos += consumed
            t = out["t"] if out is not None else np.empty(0, np.int64)
            if q:                    # the sample times passed over, less those taken
                self._skipped += _multiples(start, self._next_t, q) - int(np.count_nonzero(t % q == 0))
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
        ``sampling.HOLD + 1`` per event: see :meth:`record`)."""
        self.record(sample_us)
        new = list(self.stream(events))
        self._recorded.extend(new)
        return Track.concat(new, self.ids)

    def samples(self, clear: bool = True) -> Track:
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
        """Per-tracker structured array (id, x, y, sxx, sxy, syy, activity, active,
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
        """Energies of the last spring update: per connection (of every instance, in
        order) for each kind (eqs. 12, 17, 20); ``mean``, the first instance's mean of the
        kind that feeds its criteria (eqs. 21-22), ``means`` every instance's."""
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
