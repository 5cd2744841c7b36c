"""When the motion model is on: a model's parts measured moving fast for their size.

Eq. (3) moves a tracker toward each event as if its part stood still.  A part that
crosses more than its own size (sigma) within the millisecond or so by which an event
camera's ON and OFF edges lag each other is then tracked on the edge that fires first
(the real dot of evt2_sample.raw: 16 px off its centre); the motion model (eqs. M1-M9 of
springtrack/reference.py: velocity and both edges per tracker, docs/motion.md) follows
its centre.  On slow scenes the paper's step is kept (the motion model costs per event and
is not better everywhere: docs/motion.md), so the model is switched on by measurement:

* the learner measures the parts it finds (springtrack.learning.learner) and writes
  :data:`MOTION_ON` into a learned model of fast parts;
* ``springtrack track --model M`` measures a model given by hand with :func:`probe`:
  the model tracked (float kernel, the paper's step) over the stream's first
  :data:`PROBE_MS` (after the acquisition's window with ``--acquire``), each part's speed
  taken from its positions (:func:`robust_speeds`) and the model's from the median over
  its parts (:data:`PROBE_QUANTILE`: a hand-placed or acquired model's first milliseconds
  hold catch-ups and sparse parts whose jitter would read as speed).

Either way the rule is :func:`fast_enough`: the parts' v / sigma above
``motion_sigmas_per_ms`` part sizes per millisecond (a learner parameter, default
:data:`MOTION_SIGMAS_PER_MS`; 0: never), and never when the user or the model already set
either of the motion model's parameters (:func:`decided`); :func:`choose` is ``track``'s
whole decision for a model given by hand, for the Python API too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .discovery import quiet_nan
from .settings import MOTION_SIGMAS_PER_MS

# the motion model's parameters a model of fast parts gets (docs/motion.md)
MOTION_ON = {"motion_tau_us": 1000.0, "polarity_gain": 1.0}
# the paper's step (eq. 3), which the probe tracks with
MOTION_OFF = {"motion_tau_us": 0.0, "polarity_gain": 0.0}
SPEED_QUANTILE = 0.9          # a model's speed: this quantile of its parts' speeds
PROBE_MS = 10.0               # the probe's tracked window (after the acquisition's)
PROBE_SAMPLE_US = 200         # the probe's sample period
PROBE_SMOOTH_US = 2000        # positions averaged over this before differencing
ACQUIRE_SIZES = 4.0           # a fast model's acquisition window: its parts cross this
ACQUIRE_MIN_MS = 1.0          # many sizes in it, and it is at least this long
PROBE_QUANTILE = 0.5          # a probed model's speed: the median over its parts (the
                              # object moving fast, not its few noisiest trackers)


def sizes_per_ms(v: np.ndarray, sig: np.ndarray, quantile: float = SPEED_QUANTILE) -> float:
    """How fast the parts move for their size: the ``quantile`` over the parts of v / sigma
    (v in px/s, sigma in px; part sizes per millisecond; 0 if no part's speed is known)."""
    ok = np.isfinite(v) & np.isfinite(sig) & (sig > 0)
    if not ok.any():
        return 0.0
    return float(np.quantile(v[ok] / sig[ok], quantile)) * 1e-3


def sets_motion(params) -> bool:
    """Whether ``params`` (a dict, or None) sets either of the motion model's parameters."""
    return bool(params) and any(k in params for k in MOTION_ON)


def fast_enough(fast: float, threshold: float) -> bool:
    """The rule: parts crossing ``fast`` sizes per ms want the motion model when above a
    positive ``threshold`` (0: never)."""
    return threshold > 0 and fast > threshold


def robust_speeds(t_us: np.ndarray, x: np.ndarray, y: np.ndarray, ok: np.ndarray,
                  smooth_us: int = PROBE_SMOOTH_US) -> np.ndarray:
    """(K,) each tracker's speed in px/s: its positions ``x``, ``y`` (T, K) at ``t_us`` (T,),
    where ``ok`` (T, K) holds, averaged over ``smooth_us`` bins, and the median over the
    bins of the displacement between consecutive bins per bin length.  The median keeps
    one jump (an acquisition's first catch-up, a re-placement) from reading as speed; NaN
    for a tracker with fewer than two consecutive bins."""
    k = x.shape[1] if x.ndim == 2 else 0
    if len(t_us) < 2 or k == 0:
        return np.full(k, np.nan)
    b = (t_us - t_us[0]) // smooth_us
    nb = int(b[-1]) + 1
    cnt = np.zeros((nb, k))
    sx = np.zeros((nb, k))
    sy = np.zeros((nb, k))
    w = ok.astype(float)
    np.add.at(cnt, b, w)
    np.add.at(sx, b, np.where(ok, x, 0.0))
    np.add.at(sy, b, np.where(ok, y, 0.0))
    with quiet_nan():
        mx, my = sx / cnt, sy / cnt                       # NaN: no sample in the bin
        step = np.hypot(np.diff(mx, axis=0), np.diff(my, axis=0)) / (smooth_us * 1e-6)
        return np.nanmedian(step, axis=0)


@dataclass(frozen=True)
class SpeedProbe:
    """What :func:`probe` measured."""
    speed_px_s: float          # the PROBE_QUANTILE of the parts' speeds (NaN: none measured)
    sizes_per_ms: float        # the PROBE_QUANTILE of v / sigma, part sizes per ms
    parts: int                 # trackers whose speed was measured
    window_ms: float           # the probe's event time span
    events: int                # the events it tracked

    @property
    def measured(self) -> bool:
        return self.parts > 0


def tracked_sigmas(sxx: np.ndarray, syy: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(K,) each tracker's size sigma = sqrt((sxx + syy) / 2) in px, from the medians of its
    tracked covariance (T, K) where ``ok`` holds (NaN where it never does): the size its
    part's events give, not the model's starting covariance."""
    with quiet_nan():
        return np.sqrt(0.5 * (np.nanmedian(np.where(ok, sxx, np.nan), axis=0)
                              + np.nanmedian(np.where(ok, syy, np.nan), axis=0)))


def probe(model, events: np.ndarray, params=None, acquire: bool = False,
          acquire_ms: float = 50.0, acquire_bounds: dict | None = None,
          instances: int = 1) -> SpeedProbe:
    """The model's parts' speed on ``events`` (the stream's first window: see
    :func:`probe_window_us`), tracked by the float kernel with the paper's step
    (``params`` without the motion model) and, with ``acquire``, found first as
    ``springtrack.Tracker`` finds them.  Only samples where the instance tracks and the
    tracker is active count."""
    from ..tracker import Tracker
    from ..track import TRACKING_CODE
    base = {**dict(params or {}), **MOTION_OFF}
    tr = Tracker(model, params=base or None, backend="cython", acquire=acquire,
                 acquire_ms=acquire_ms, acquire_bounds=acquire_bounds, instances=instances)
    tr.record(PROBE_SAMPLE_US)
    tr.process(events)
    tr.flush()
    track = tr.samples()
    span = (int(events["t"][-1]) - int(events["t"][0])) / 1e3 if len(events) else 0.0
    if not len(track):
        return SpeedProbe(math.nan, 0.0, 0, span, len(events))
    ok = track.active & (track.state == TRACKING_CODE)
    v = robust_speeds(track.t_us, track.x, track.y, ok)
    sig = tracked_sigmas(track.sxx, track.syy, ok)
    good = np.isfinite(v)
    speed = float(np.quantile(v[good], PROBE_QUANTILE)) if good.any() else math.nan
    return SpeedProbe(speed, sizes_per_ms(v, sig, PROBE_QUANTILE), int(good.sum()), span,
                      len(events))


def fast_acquire_ms(sizes_per_ms: float, acquire_ms: float) -> float:
    """The acquisition window (ms) for parts crossing ``sizes_per_ms`` of their sizes per ms:
    the search scores the window's events as one picture, so a part that crosses its size
    within it is found on its smeared trail (the real dot in 50 ms: a circle); the window
    in which it crosses :data:`ACQUIRE_SIZES`, at least :data:`ACQUIRE_MIN_MS`, at most
    ``acquire_ms``."""
    if not sizes_per_ms > 0:
        return acquire_ms
    return min(acquire_ms, max(ACQUIRE_MIN_MS, ACQUIRE_SIZES / sizes_per_ms))


def probe_window_us(acquire: bool, acquire_ms: float) -> int:
    """The probe's window from the stream's first event: the acquisition's (when it finds
    the model) and :data:`PROBE_MS` of tracking."""
    return int(round(((acquire_ms if acquire else 0.0) + PROBE_MS) * 1000))


def decided(models, params=None, threshold: float = MOTION_SIGMAS_PER_MS) -> bool:
    """Whether the motion model is settled without a probe: never (``threshold`` 0), set
    by ``params`` (a dict) or a model's [params], or decided by the learner that made a
    model (its [learned] table holds the speed it measured).  ``models``: ShapeModels."""
    return (not threshold > 0 or sets_motion(params)
            or any(sets_motion(m.params) or "sizes_per_ms" in (m.learned or {})
                   for m in models))


@dataclass(frozen=True)
class MotionChoice:
    """What :func:`choose` decided."""
    params: dict | None        # the parameters to track with (None: as given)
    acquire_ms: float          # the acquisition window to use (ms)
    probe: SpeedProbe | None   # what was measured (None: settled without a probe)
    refused: str = ""          # why a backend refused the motion model ("" if it did not)

    @property
    def on(self) -> bool:
        return self.params is not None


def choose(model, events: np.ndarray, params: dict | None = None,
           threshold: float = MOTION_SIGMAS_PER_MS, backend: str = "cython",
           acquire: bool = False, acquire_ms: float = 50.0, acquire_ms_given: bool = True,
           acquire_bounds: dict | None = None, instances: int = 1) -> MotionChoice:
    """``track``'s decision for a model given by hand (a ShapeModel or a list), on the
    stream's first events (at least :func:`probe_window_us` of them): unless
    :func:`decided`, :func:`probe` the parts' speed and, above ``threshold`` part sizes
    per ms, return ``params`` with :data:`MOTION_ON` (if ``backend`` accepts them for
    every model; else ``refused`` says why) and, with ``acquire`` and a window the user
    did not give (``acquire_ms_given`` False), :func:`fast_acquire_ms`.

    The Python API's counterpart of ``springtrack track --model M``::

        c = choose(model, events[:n_first], acquire=True, acquire_ms_given=False)
        tr = springtrack.Tracker(model, c.params, acquire=True, acquire_ms=c.acquire_ms)
    """
    from ..backends import check_backend_params
    from ..params import resolve
    models = list(model) if isinstance(model, (list, tuple)) else [model]
    given = dict(params or {})
    if decided(models, given, threshold) or not len(events):
        return MotionChoice(None, acquire_ms, None)
    p = probe(model, events, given, acquire=acquire, acquire_ms=acquire_ms,
              acquire_bounds=acquire_bounds, instances=instances)
    if not (p.measured and fast_enough(p.sizes_per_ms, threshold)):
        return MotionChoice(None, acquire_ms, p)
    chosen = {**given, **MOTION_ON}
    try:
        for m in models:
            check_backend_params(backend, m, resolve(m, chosen))
    except ValueError as e:
        return MotionChoice(None, acquire_ms, p, refused=str(e))
    if acquire and not acquire_ms_given:
        acquire_ms = fast_acquire_ms(p.sizes_per_ms, acquire_ms)
    return MotionChoice(chosen, acquire_ms, p)
