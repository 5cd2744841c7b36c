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
``snapshot(t)``, ``energies()``, ``mean_energy``, ``frame()``, ``last_t`` and
``counters()``.
"""
from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np

from . import params as _params
from .events import as_events, check as check_events
from .geometry import check_inside
from .model import ShapeModel, load_model
from .params import Params
from .reference import ReferenceTracker
from .sampling import MAX_PERIOD, UNSET, first_sample_time, next_sample, sample_due
from .track import TRACK_DTYPE, TRACK_FIELDS, Track

BACKENDS = ("cython", "reference", "fixed", "mcu")
SAMPLE_CAP = 4096          # sample rows per kernel call; bounds memory for huge time gaps


class ReferenceBackend:
    """Adapts ReferenceTracker to the backend interface; its ``run`` is the kernels'
    ``run`` (springtrack/_stepper.pyx) in Python, with the same sampling rule
    (springtrack.sampling)."""

    def __init__(self, model: ShapeModel, params: Params):
        self.ref = ReferenceTracker(model, params)

    def set_params(self, params: Params) -> None:
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

    def frame(self):
        return self.ref.frame()

    @property
    def last_t(self):
        return self.ref.last_t

    def counters(self):
        r = self.ref
        return dict(events_valid=r.n_valid, events_assigned=r.n_assigned,
                    skipped_back_in_time=r.n_back, skipped_outside_sensor=r.n_outside,
                    spring_updates=r.n_spring_updates, state_resets=r.n_resets)


def _cython_backend(model, params, option):
    from ._kernel import Kernel
    return Kernel(model, params)


def _fixed_backend(model, params, option):
    try:
        mod = importlib.import_module("springtrack._fixed")
    except ImportError as e:
        raise ValueError(f"backend 'fixed' is not available in this build: {e}") from None
    return mod.FixedKernel(model, params)


def _mcu_backend(model, params, option):
    from .mcu import MissingExtra
    try:
        from .mcu.backend import DEFAULT_TARGET, McuBackend
        return McuBackend(model, params, target=option or DEFAULT_TARGET)
    except (MissingExtra, RuntimeError) as e:      # no toolchain, a failed build or run
        raise ValueError(f"backend 'mcu': {e}") from None


# name -> factory(model, params, option); "name:option" passes the option (the mcu's core)
_FACTORIES = {"reference": lambda m, p, o: ReferenceBackend(m, p), "cython": _cython_backend,
              "fixed": _fixed_backend, "mcu": _mcu_backend}


def make_backend(name: str, model: ShapeModel, params: Params):
    base, _, option = name.partition(":")
    if base not in _FACTORIES or (option and base != "mcu"):
        raise ValueError(f"unknown backend {name!r}; choose from {', '.join(BACKENDS)} "
                         f"(mcu:TARGET names a core)")
    return _FACTORIES[base](model, params, option)


def resolve_params(model: ShapeModel, params=None) -> Params:
    """Defaults, then the model's [params], then ``params`` (Params, dict or TOML path)."""
    base = _params.from_mapping(model.params, where=f"{model.source} [params]")
    if params is None:
        return base
    if isinstance(params, Params):
        return params
    if isinstance(params, dict):
        return _params.from_mapping(params, base)
    if isinstance(params, (str, Path)):
        data = _params.read_toml(params)
        return _params.from_mapping(data.get("params", data), base, where=str(params))
    raise TypeError(f"params must be Params, dict, a TOML path or None, not {type(params).__name__}")


class Tracker:
    """Part-based shape tracker. Feed events in time order, in as many chunks as you like.

    ``model``: a ShapeModel, a preset name or a TOML path, its trackers on its sensor
    (``springtrack.geometry.TrackersOutside`` otherwise); ``params``: Params, a dict of
    overrides, a TOML path, or None (defaults < model [params] < these).
    Events that go back in time or fall outside the sensor are skipped and counted
    (:attr:`counters`), never raised.

    ``acquire=True``: the model's positions are not trusted; the first ``acquire_ms`` of
    events are buffered and the model is found in them (:mod:`springtrack.acquire`;
    ``acquire_bounds``: its region, angle_deg, scale), placed there, and tracked from
    the window's first event.  While it is not found the window slides by half its
    length (:attr:`acquisition` counts the attempts and the events dropped); call
    :meth:`flush` at the end of the input to try on a last, shorter window.
    """

    def __init__(self, model, params=None, backend: str = "cython", acquire: bool = False,
                 acquire_ms: float = 50.0, acquire_bounds: dict | None = None):
        self.model = load_model(model)
        if not acquire:          # placed by the acquisition otherwise
            check_inside(self.model)
        self.params = resolve_params(self.model, params)
        self.backend_name = backend
        self._b = make_backend(backend, self.model, self.params)
        self._sample_us = 0
        self._next_t = UNSET
        self._skipped = 0                    # sample times of empty stretches not taken
        self._recorded: list[Track] = []
        self.acquisition = None
        if acquire:
            from .acquire import Acquisition
            self.acquisition = Acquisition(self.model, int(round(acquire_ms * 1000)),
                                           **(acquire_bounds or {}))

    @property
    def ids(self) -> list[str]:
        return self.model.ids

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
        if self.acquisition is not None and not self.acquisition.done:
            yield from self._track(self._placed(self.acquisition.feed(as_events(events))))
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
            self._recorded.extend(self._track(self._placed(self.acquisition.finish())))

    def _placed(self, ready):
        """The events to track: none while acquiring; once found, the model placed at the
        pose found and the buffered events."""
        if ready is None:
            return ready
        from .acquire import place
        self.model = place(self.model, self.acquisition.pose)
        self._b = make_backend(self.backend_name, self.model, self.params)
        return ready

    def _track(self, ev):
        """Run the backend over ``ev`` in calls of at most SAMPLE_CAP sample rows; yield
        each call's samples as a Track."""
        if ev is None or len(ev) == 0:
            return
        pos, p = 0, self._sample_us
        while pos < len(ev):
            start = self._next_t
            if p and start == UNSET:
                start = first_sample_time(int(ev["t"][pos]), p)
            consumed, self._next_t, out = self._b.run(ev[pos:], p, self._next_t, SAMPLE_CAP)
            rows = 0 if out is None else len(out["t"])
            if p:                    # the sample times passed over, less those taken
                self._skipped += (self._next_t - start) // p - rows
            pos += consumed
            if rows:
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
        """Change parameters between two events; returns the new Params."""
        new = resolve_params(self.model, params) if params is not None else self.params
        if changes:
            new = _params.from_mapping(changes, new)
        self.params = new
        self._b.set_params(new)
        return new

    # ---- observation -----------------------------------------------------------------
    @property
    def last_t(self) -> int:
        return int(self._b.last_t)

    def state(self, t: int | None = None) -> np.ndarray:
        """Per-tracker structured array (id, x, y, sxx, sxy, syy, activity, active,
        sensitive) at event time ``t`` (default: the last event's time)."""
        t = self.last_t if t is None else int(t)
        snap = self._b.snapshot(max(t, 0) if t < -(1 << 60) else t)
        dt = np.dtype([("id", f"U{max(len(i) for i in self.ids)}")]
                      + [(f, TRACK_DTYPE[f]) for f in TRACK_FIELDS])
        out = np.empty(len(self.ids), dt)
        out["id"] = self.ids
        for f in TRACK_FIELDS:
            out[f] = snap[f]
        return out

    def energies(self) -> dict:
        """Energies of the last spring update: per connection for each kind (eqs. 12, 17,
        20) and ``mean``, the mean of the kind that feeds the criteria (eqs. 21-22)."""
        e = self._b.energies()
        return {"euclidean": e[0], "torsional": e[1], "cartesian": e[2],
                "mean": float(self._b.mean_energy), "kind": self.params.energy_kind}

    def frame(self) -> dict:
        """The similarity frame of the last spring update (``pull_frame`` or
        ``cartesian_frame`` = "similarity", docs/algorithm.md): ``scale`` s, ``angle`` of R
        (rad), and ``gx``, ``gy``, where the rest centre of mass G0 maps to (px); scale 1,
        angle 0 and G0 until a spring update fits one, or in the image frame."""
        c, sn, gx, gy = (float(v) for v in self._b.frame())
        return {"scale": float(np.hypot(c, sn)), "angle": float(np.arctan2(sn, c)),
                "gx": gx, "gy": gy}

    @property
    def counters(self) -> dict:
        c = dict(self._b.counters())
        if self._sample_us:
            c["samples_skipped"] = self._skipped
        if self.acquisition is not None:
            c.update(acquire_attempts=self.acquisition.attempts,
                     acquire_events_dropped=self.acquisition.events_dropped)
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
