"""The firmware's model slot: the running model, parameters and tracker kernel, and the
update queued to replace them (a double buffer), numbered by generation.

Updates are validated and built completely in the caller's thread (a new kernel for a
model or a reset), queued, and swapped in by the processing thread between two events
(:meth:`ModelSlot.apply`).  :class:`AppliedLog` reports the event time at which each
generation took effect.
"""
from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

from springtrack import model as _model
from springtrack import params as _params
from springtrack.sensor_fit import fit_model
from springtrack.backends import check_backend_params, make_backend, spec_of
from springtrack.params import resolve as resolve_params
from springtrack.wire import Nack

from .engine import UpdateRejected

@dataclass(frozen=True, slots=True)
class _Build:
    """A model (or a reset) queued with the kernel built for it."""
    model: _model.ShapeModel
    params: _params.Params
    kernel: object
    generation: int


@dataclass(frozen=True, slots=True)
class Swap:
    """What :meth:`ModelSlot.apply` put in effect."""
    generation: int
    new_kernel: bool          # a model load or reset (else parameters changed in place)


class ApplyFailed(Exception):
    """Queued updates that could not be applied; ``swap`` is what did take effect."""

    def __init__(self, generations: list, message: str):
        super().__init__(message)
        self.generations = generations
        self.swap: Swap | None = None


def _model_code(e: BaseException) -> Nack:
    """The NACK code of an error raised while loading a model: a ``ModelError``'s own
    (``SensorError``: sensor_mismatch, ``ModelNameError``: too_long), else invalid_model
    (a parameter error inside a model file too)."""
    return e.code if isinstance(e, _model.ModelError) else Nack.INVALID_MODEL


def _reason(e: BaseException) -> str:
    if isinstance(e, RecursionError):
        return "the model text is nested too deeply to parse"
    return str(e)


class ModelSlot:
    """``ModelSlot(backend, model, params, sensor=None, sensor_from=None)``:
    ``model``/``params`` as for ``springtrack.Tracker``; ``backend`` "cython" (float64),
    "fixed" (integer-only, docs/fixed_point.md) or "mcu" (that kernel's microcontroller build
    in an emulator, docs/mcu.md; "mcu:cortex-m7" names the core); ``sensor``: the camera's
    (width, height), which every model must fit (``springtrack.sensor_fit.fit_model`` with
    ``sensor_from``: None, "source" or "model").  The queue_* methods are thread-safe and
    raise :class:`UpdateRejected`; :meth:`apply` runs in the processing thread.  ``acquire``
    (``{"acquire_ms": ..., "bounds": {...}}``): each kernel built finds its model in the
    events first (firmware_sim.acquiring)."""

    def __init__(self, backend: str, model, params=None, sensor=None, sensor_from=None,
                 acquire: dict | None = None):
        spec_of(backend, firmware=True)      # ValueError naming the ones the firmware runs
        self.backend = backend
        self.acquire = acquire               # None, or acquire_ms and bounds: every kernel
        #                                      built searches for its model (AcquiringKernel)
        self.sensor = sensor or (None, None)
        self.sensor_from = sensor_from
        self.model = self.fit(_model.load_model(model))
        self.params = resolve_params(self.model, params)
        self.kernel = self.new_kernel(self.model, self.params)
        self.generation = 1                  # in effect
        self.lock = threading.Lock()
        self._last_gen = 1                   # last handed out
        self._build: _Build | None = None
        self._params: dict = {}              # name -> (value, generation)
        self._retired: dict = {}             # counters of the kernels swapped out

    def new_kernel(self, model, params):
        if self.acquire is not None:
            from .acquiring import AcquiringKernel
            return AcquiringKernel(model, params, self.backend, **self.acquire)
        return make_backend(self.backend, model, params)

    def check_kernel_params(self, model, params) -> None:
        """Raise ValueError if this backend's kernel would refuse ``params`` for ``model``:
        the checks its ``set_params`` runs before loading them (the fixed kernel's Q
        formats, ``springtrack.fixed.q.params_words``, also the microcontroller build's), so
        that an accepted update always applies."""
        check_backend_params(self.backend, model, params)

    def fit(self, model, uploaded: bool = False):
        """``model`` checked against the camera's sensor (springtrack.sensor_fit): a
        ``SensorError`` (a ModelError) if it does not fit.  The rule is the one the
        firmware was started with (``--sensor-from``): none refuses a mismatch, for the
        model it starts with as for an upload; an ``uploaded`` model's refusal names the
        host's way out first."""
        w, h = self.sensor
        way_out = None
        if uploaded:
            way_out = (f"upload a model made for {w}x{h} (its [sensor] width = {w}, height = "
                       f"{h} and its trackers inside), or restart the firmware with "
                       f"`firmware-sim run --sensor-from source` (uploads used on the camera's "
                       f"sensor, trackers where they are) or `--sensor-from model`")
        return fit_model(model, w, h, self.sensor_from, what="the camera's sensor",
                         source_word="source", way_out=way_out)

    @property
    def pending(self) -> bool:
        return self._build is not None or bool(self._params)

    def next_generation(self) -> int:
        """A new generation number, for an update applied outside the slot (a bias)."""
        with self.lock:
            self._last_gen += 1
            return self._last_gen

    # ---- queueing (any thread) ---------------------------------------------------------
    def queue_model(self, toml_text: str) -> int:
        """Validate a model TOML, build its kernel and queue it; queued parameter changes
        are dropped (the model brings its own).  Returns its generation."""
        try:
            m = _model.loads(toml_text, "uploaded model")
        except (ValueError, TypeError, RecursionError) as e:   # ModelError is a ValueError
            # a ModelError names its code (a name INFO cannot carry: too_long)
            raise UpdateRejected(_model_code(e), _reason(e)) from None
        try:
            m = self.fit(m, uploaded=True)
            p = resolve_params(m)
            k = self.new_kernel(m, p)
        except (ValueError, TypeError, ArithmeticError) as e:  # ParamError is a ValueError
            # a model that does not fit the sensor says so (springtrack.sensor_fit's code)
            raise UpdateRejected(_model_code(e), _reason(e)) from None
        with self.lock:
            self._last_gen += 1
            self._build = _Build(m, p, k, self._last_gen)
            self._params = {}
            return self._last_gen

    def queue_reset(self) -> int:
        """A fresh kernel of the current (or queued) model and parameters."""
        with self.lock:
            m = self._build.model if self._build else self.model
            p = self._build.params if self._build else self.params
            self._last_gen += 1
            self._build = _Build(m, p, self.new_kernel(m, p), self._last_gen)
            return self._last_gen

    def queue_param(self, name: str, value) -> int:
        """Validate one parameter against the queued state and queue it; the
        ``springtrack.params`` error's code becomes the NACK code."""
        with self.lock:
            base = self._build.params if self._build else self.params
            merged = {k: v for k, (v, _) in self._params.items()}
            merged[name] = value
            try:
                new = _params.from_mapping(merged, base)
            except _params.ParamError as e:
                raise UpdateRejected(e.code, str(e)) from None
            model = self._build.model if self._build else self.model
            try:
                self.check_kernel_params(model, new)
            except (ValueError, ArithmeticError) as e:
                raise UpdateRejected(Nack.OUT_OF_RANGE, f"{name}={value!r}: the {self.backend} "
                                                        f"kernel cannot run it: {e}") from None
            self._last_gen += 1
            self._params[name] = (_params.check(name, value), self._last_gen)
            return self._last_gen

    def params_dict(self) -> dict:
        with self.lock:
            return self.params.as_dict()

    # ---- applying (processing thread, between two events) ----------------------------------
    def apply(self) -> Swap | None:
        """Put what is queued in effect; None if nothing was.  Parameter changes the kernel
        refuses after all (they were checked when queued, so this is a defect) leave the
        running parameters as they were and raise :class:`ApplyFailed` after the rest of
        the update (a model) took effect."""
        with self.lock:
            build, self._build = self._build, None
            changes, self._params = self._params, {}
        gen = None
        if build is not None:
            self._retire(self.kernel)
            self.model, self.params, self.kernel = build.model, build.params, build.kernel
            gen = build.generation
        failed = None
        if changes:
            gens = [g for _, g in changes.values()]
            try:
                new = _params.from_mapping({n: v for n, (v, _) in changes.items()}, self.params)
                self.kernel.set_params(new)
            except (ValueError, ArithmeticError) as e:
                self.kernel.set_params(self.params)      # as before the attempt
                failed = ApplyFailed(gens, f"parameter change(s) {', '.join(changes)} of "
                                           f"generation(s) {', '.join(map(str, gens))} not "
                                           f"applied, the kernel refused them: {e}")
            else:
                self.params = new
                gen = max(gens + [gen or 0])
        if gen is not None:
            self.generation = gen
        if failed is not None:
            failed.swap = Swap(gen, build is not None) if gen is not None else None
            raise failed
        return Swap(gen, build is not None) if gen is not None else None

    # ---- counters ----------------------------------------------------------------------
    def _retire(self, kernel) -> None:
        for k, v in kernel.counters().items():
            self._retired[k] = self._retired.get(k, 0) + int(v)

    def kernel_counters(self) -> dict:
        """The tracker kernel's counters summed over every kernel this run (a model load or
        RESET starts a new one): events it skipped and, for the fixed backend, the values
        it saturated (docs/fixed_point.md)."""
        out = dict(self._retired)
        for k, v in self.kernel.counters().items():
            out[k] = out.get(k, 0) + int(v)
        return dict(out, backend=self.backend)


class AppliedLog:
    """The event time at which each generation took effect, for ``Engine.poll_applied``:
    that of the first event processed under it (or, for an update applied outside the
    tracker, the last event time when it was applied)."""

    def __init__(self):
        self._reports: deque = deque()          # (generation, t_us) not yet polled
        self._waiting: list = []                # generations awaiting their first event
        self.swaps: deque = deque(maxlen=1024)  # (generation, events tracked before it)

    def took_effect(self, generation: int, tracked: int) -> None:
        """``generation`` is in effect from the next event; ``tracked`` events came before."""
        self._waiting.append(generation)
        self.swaps.append((generation, int(tracked)))

    @property
    def waiting(self) -> bool:
        return bool(self._waiting)

    def first_event(self, t_us: int) -> None:
        """The first event under the waiting generations was at ``t_us``."""
        self._reports.extend((g, int(t_us)) for g in self._waiting)
        self._waiting = []

    def report(self, generation: int, t_us: int) -> None:
        self._reports.append((generation, int(t_us)))

    def pending(self) -> bool:
        return bool(self._reports)

    def poll(self) -> list:
        out = []
        while self._reports:
            out.append(self._reports.popleft())
        return out
