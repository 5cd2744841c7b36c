"""Simulated ATIS sensor: scene -> log-intensity frames -> events, with ground truth.

The contrast-threshold model of ESIM (Rebecq et al., CoRL 2018) and v2e (Hu et al.,
CVPRW 2021), kernels in ``springtrack/sim/_sensor.pyx``:

* the scene is rendered at adaptive steps (ESIM's adaptive sampling): each block of
  ``step_us`` (default 4 ms) is halved, down to ``min_step_us``, until nothing in the
  scene moves more than ``max_disp_px`` within a step; the log intensity of each pixel
  is interpolated linearly in time between two renders;
* each pixel keeps a reference log intensity; every crossing of reference +- its
  threshold emits an ON (p = 1) / OFF (p = 0) event at the interpolated crossing time
  and moves the reference by one threshold;
* thresholds differ per pixel: ``C * (1 + N(0, c_sigma))`` (clipped at 0.25 C);
* an event within ``refractory_us`` of the pixel's previous event is suppressed
  (counted in :attr:`Sensor.stats`); the reference still moves;
* background activity: a Poisson process of ``noise_rate_hz`` per pixel, random pixel
  and polarity; optional hot pixels, each a Poisson source of ``hot_rate_hz``; noise
  events are not subject to the refractory period;
* ATIS geometry 304 x 240 by default; the whole run is a function of the seed only
  (chunking does not change it: the noise streams are consumed in time order).

:func:`simulate` yields ``(events, truth)`` chunks so a long scene never holds all its
events in memory; events are sorted by ``t`` within and across chunks; ``truth`` is a
:data:`TRUTH_DTYPE` array of each part's true position every ``TRUTH_PERIOD_US``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from springtrack.events import EVENT_DTYPE

from . import _sensor
from .scenes import SCENES, Scene, make_scene

TRUTH_PERIOD_US = 1000
TRUTH_DTYPE = np.dtype([("t", "<i8"), ("part", "U16"), ("x", "<f8"), ("y", "<f8")])
_NOISE_BATCH = 4096
_FAR_PAST = -(1 << 62)
DISK_R = math.sqrt(2.0)


@dataclass(frozen=True)
class SensorConfig:
    width: int = 304
    height: int = 240
    c_on: float = 0.2             # ON threshold, log-intensity units (v2e default)
    c_off: float = 0.2            # OFF threshold
    c_sigma: float = 0.03         # relative per-pixel threshold mismatch (std)
    refractory_us: int = 100
    noise_rate_hz: float = 0.1    # background activity per pixel
    hot_pixels: int = 0
    hot_rate_hz: float = 200.0
    step_us: int = 4000           # largest rendering step; log intensity linear in between
    min_step_us: int = 250        # smallest rendering step
    max_disp_px: float = 0.5      # largest motion of any blob/occluder within one step

    def __post_init__(self):
        for name in ("width", "height", "step_us", "min_step_us"):
            if getattr(self, name) < 1:
                raise ValueError(f"sensor config: {name} must be >= 1, got {getattr(self, name)}")
        if self.c_on <= 0 or self.c_off <= 0:
            raise ValueError(f"sensor config: thresholds must be positive, got c_on={self.c_on}, "
                             f"c_off={self.c_off}")
        if self.c_sigma < 0 or self.refractory_us < 0 or self.max_disp_px <= 0:
            raise ValueError(f"sensor config: c_sigma and refractory_us must not be negative "
                             f"and max_disp_px must be positive, got {self.c_sigma}, "
                             f"{self.refractory_us}, {self.max_disp_px}")
        if self.noise_rate_hz < 0 or self.hot_rate_hz < 0 or self.hot_pixels < 0:
            raise ValueError("sensor config: noise rates and hot_pixels must not be negative")
        if self.min_step_us > self.step_us:
            raise ValueError(f"sensor config: min_step_us={self.min_step_us} exceeds "
                             f"step_us={self.step_us}")


class _PoissonSource:
    """Events of a homogeneous Poisson process over a fixed pixel set, drawn in batches
    from its own random stream, handed out in time order."""

    def __init__(self, rng, rate_hz: float, xs: np.ndarray, ys: np.ndarray):
        self.rng, self.rate = rng, rate_hz * len(xs)
        self.xs, self.ys = xs.astype(np.uint16), ys.astype(np.uint16)
        self.t_last = 0.0
        self.buf = np.zeros(0, EVENT_DTYPE)

    def take(self, t_end_us: int) -> np.ndarray:
        """All events with t < t_end_us not handed out yet."""
        if self.rate <= 0:
            return np.zeros(0, EVENT_DTYPE)
        parts = []
        while True:
            if len(self.buf) == 0:
                self._refill()
            k = int(np.searchsorted(self.buf["t"], t_end_us, side="left"))
            parts.append(self.buf[:k])
            self.buf = self.buf[k:]
            if len(self.buf):
                return np.concatenate(parts)

    def _refill(self):
        n = _NOISE_BATCH
        gaps = self.rng.exponential(1e6 / self.rate, size=n)
        t = self.t_last + np.cumsum(gaps)
        self.t_last = float(t[-1])
        idx = self.rng.integers(0, len(self.xs), size=n)
        ev = np.empty(n, EVENT_DTYPE)
        ev["t"] = np.floor(t).astype(np.int64)
        ev["x"], ev["y"] = self.xs[idx], self.ys[idx]
        ev["p"] = self.rng.integers(0, 2, size=n, dtype=np.uint8)
        self.buf = ev


def _bbox(frame, width, height):
    """Pixel rectangle (x0, y0, x1, y1) holding everything the frame draws, or None."""
    rects = []
    if len(frame.blobs):
        b = frame.blobs
        rad = np.where(b[:, 6] > 0, DISK_R + 6.0 / np.where(b[:, 6] > 0, b[:, 6], 1.0), 3.5)
        rx, ry = rad * np.sqrt(b[:, 2]), rad * np.sqrt(b[:, 4])     # as in _sensor.render
        rects.append((b[:, 0] - rx, b[:, 1] - ry, b[:, 0] + rx, b[:, 1] + ry))
    if len(frame.occluders):
        o = frame.occluders
        rad = 1.0 + 6.0 / o[:, 6]          # as in _sensor.render
        rx, ry = rad * np.sqrt(o[:, 2]), rad * np.sqrt(o[:, 4])
        rects.append((o[:, 0] - rx, o[:, 1] - ry, o[:, 0] + rx, o[:, 1] + ry))
    if not rects:
        return None
    x0 = min(float(r[0].min()) for r in rects)
    y0 = min(float(r[1].min()) for r in rects)
    x1 = max(float(r[2].max()) for r in rects)
    y1 = max(float(r[3].max()) for r in rects)
    box = (max(0, int(math.floor(x0)) - 1), max(0, int(math.floor(y0)) - 1),
           min(width, int(math.floor(x1)) + 2), min(height, int(math.floor(y1)) + 2))
    return box if box[0] < box[2] and box[1] < box[3] else None


def _union(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


@dataclass
class SensorStats:
    steps: int = 0
    signal_events: int = 0
    refractory_suppressed: int = 0
    noise_events: int = 0
    hot_events: int = 0
    pixels_processed: int = 0


class Sensor:
    """State of one simulated sensor looking at one scene; advance with :meth:`chunks`."""

    def __init__(self, scene: Scene, seed: int = 0, config: SensorConfig | None = None):
        self.scene, self.cfg = scene, config or SensorConfig()
        cfg = self.cfg
        h, w = cfg.height, cfg.width
        rng = np.random.default_rng([int(seed), 1])
        lo_on, lo_off = 0.25 * cfg.c_on, 0.25 * cfg.c_off
        self.c_on = np.maximum(cfg.c_on * (1 + cfg.c_sigma * rng.standard_normal((h, w))),
                               lo_on).astype(np.float32)
        self.c_off = np.maximum(cfg.c_off * (1 + cfg.c_sigma * rng.standard_normal((h, w))),
                                lo_off).astype(np.float32)
        self.scratch = np.empty((h, w), np.float32)
        self.lprev = np.empty((h, w), np.float32)
        self.lnew = np.empty((h, w), np.float32)
        self.last_t = np.full((h, w), _FAR_PAST, np.int64)
        self.frame = scene.frame(0.0)
        self._render(self.lprev, self.frame, (0, 0, w, h))
        self.lnew[...] = self.lprev
        self.lref = self.lprev.copy()                   # sensor reset at t = 0
        self.box = _bbox(self.frame, w, h)
        ys, xs = np.divmod(np.arange(h * w), w)
        self.noise = _PoissonSource(np.random.default_rng([int(seed), 2]), cfg.noise_rate_hz,
                                    xs, ys)
        hot = rng.choice(h * w, size=min(cfg.hot_pixels, h * w), replace=False)
        self.hot = _PoissonSource(np.random.default_rng([int(seed), 3]), cfg.hot_rate_hz,
                                  hot % w, hot // w)
        self.t_us = 0
        self.stats = SensorStats()
        self.buf = np.empty(1 << 16, EVENT_DTYPE)

    def _render(self, dst, frame, box):
        x0, y0, x1, y1 = box
        _sensor.render(dst, np.ascontiguousarray(frame.blobs, dtype=np.float64),
                       np.ascontiguousarray(frame.occluders, dtype=np.float64),
                       float(self.scene.background), x0, y0, x1, y1, self.scratch)

    def _moved(self, a, b) -> float:
        """Largest change of a centre or a standard deviation between two frames, px
        (infinite when an occluder appears or disappears)."""
        d = 0.0
        for u, v in ((a.blobs, b.blobs), (a.occluders, b.occluders)):
            if u.shape != v.shape:
                return math.inf
            if len(u):
                d = max(d, float(np.abs(u[:, :2] - v[:, :2]).max()),
                        float(np.abs(np.sqrt(u[:, [2, 4]]) - np.sqrt(v[:, [2, 4]])).max()))
        return d

    def _block(self, n: int, dt: int) -> int:
        """Advance by ``dt`` us, halving the step while the scene moves too much."""
        cfg = self.cfg
        frame = self.scene.frame((self.t_us + dt) * 1e-6)
        if dt >= 2 * cfg.min_step_us and self._moved(self.frame, frame) > cfg.max_disp_px:
            half = dt // 2
            n = self._block(n, half)
            return self._block(n, dt - half)
        return self._step(n, dt, frame)

    def _step(self, n: int, dt: int, frame) -> int:
        """Render ``frame`` (at t + dt) and emit the events of [t, t + dt) into self.buf
        from index n; returns the new n."""
        cfg = self.cfg
        t0 = self.t_us
        box1 = _bbox(frame, cfg.width, cfg.height)
        box = _union(self.box, box1)
        if box is not None:
            self._render(self.lnew, frame, box)
            x0, y0, x1, y1 = box
            start = 0
            while True:
                n, resume, supp = _sensor.emit(
                    self.lprev, self.lnew, self.lref, self.c_on, self.c_off, self.last_t,
                    x0, y0, x1, y1, start, float(t0), float(dt), cfg.refractory_us,
                    self.buf.ctypes.data, n, len(self.buf))
                self.stats.refractory_suppressed += supp
                if resume < 0:
                    break
                grown = np.empty(2 * len(self.buf), EVENT_DTYPE)
                grown[:n] = self.buf[:n]
                self.buf, start = grown, resume
            self.stats.pixels_processed += (x1 - x0) * (y1 - y0)
        self.frame, self.box, self.t_us = frame, box1, t0 + dt
        self.stats.steps += 1
        return n

    def advance(self, t_end_us: int) -> np.ndarray:
        """Events of [current time, t_end_us), sorted by t (stable: signal in pixel
        order, then noise, then hot pixels for equal timestamps)."""
        n = 0
        while self.t_us < t_end_us:
            to_grid = self.cfg.step_us - self.t_us % self.cfg.step_us   # blocks on a fixed grid
            n = self._block(n, min(to_grid, t_end_us - self.t_us))
        signal = self.buf[:n]
        noise = self.noise.take(self.t_us)
        hot = self.hot.take(self.t_us)
        self.stats.signal_events += n
        self.stats.noise_events += len(noise)
        self.stats.hot_events += len(hot)
        ev = np.concatenate([signal, noise, hot])
        return ev[np.argsort(ev["t"], kind="stable")]


def truth_between(scene: Scene, t0_us: int, t1_us: int, shown=None) -> np.ndarray:
    """Ground truth at every multiple of TRUTH_PERIOD_US in [t0_us, t1_us); ``shown``, if
    given, maps those times (us array) to the scene times (s) whose pose is seen then."""
    first = -(-t0_us // TRUTH_PERIOD_US) * TRUTH_PERIOD_US
    times = np.arange(first, t1_us, TRUTH_PERIOD_US, dtype=np.int64)
    k = len(scene.part_ids)
    out = np.empty(len(times) * k, TRUTH_DTYPE)
    if not len(times):
        return out
    seen = times * 1e-6 if shown is None else shown(times)
    cache = {}
    xy = np.stack([cache.setdefault(t, scene.truth(t)) for t in seen.tolist()])  # (T, K, 2)
    out["t"] = np.repeat(times, k)
    out["part"] = np.tile(np.array(scene.part_ids), len(times))
    out["x"] = xy[:, :, 0].ravel()
    out["y"] = xy[:, :, 1].ravel()
    return out


def simulate(scene, seconds: float | None = None, seed: int = 0, chunk_us: int = 100_000,
             config: SensorConfig | None = None, stats: dict | None = None, **scene_params):
    """Generator of ``(events, truth)`` chunks covering ``[0, seconds)``.

    ``scene`` is a name in :data:`springtrack.sim.scenes.SCENES` (``scene_params`` go to its
    constructor) or a Scene instance; ``seconds=None`` is the scene's default duration,
    ``math.inf`` streams without end (for a simulated camera).  ``chunk_us`` is rounded up
    to a multiple of the rendering step.  If ``stats`` is a dict it is updated with the
    sensor's counters after every chunk.
    """
    scene = make_scene(scene, seed=seed, **scene_params)
    cfg = config or SensorConfig()
    seconds = scene.default_seconds if seconds is None else float(seconds)
    if not seconds > 0:
        raise ValueError(f"simulate: seconds must be positive, got {seconds}")
    if chunk_us < 1:
        raise ValueError(f"simulate: chunk_us must be >= 1, got {chunk_us}")
    chunk_us = -(-int(chunk_us) // cfg.step_us) * cfg.step_us
    end_us = math.inf if math.isinf(seconds) else int(round(seconds * 1e6))
    sensor = Sensor(scene, seed, cfg)
    t = 0
    while t < end_us:
        t1 = min(t + chunk_us, end_us)
        events = sensor.advance(t1)
        truth = truth_between(scene, t, t1)
        t = sensor.t_us
        if stats is not None:
            stats.update(vars(sensor.stats))
        yield events, truth


def simulate_all(scene, seconds: float | None = None, seed: int = 0, **kw):
    """The whole simulation at once: ``(events, truth)`` arrays (finite ``seconds``)."""
    if seconds is not None and math.isinf(seconds):
        raise ValueError("simulate_all: seconds must be finite")
    ev, tr = zip(*simulate(scene, seconds, seed, **kw))
    return np.concatenate(ev), np.concatenate(tr)


def write_truth_csv(path, truth_chunks) -> int:
    """Write truth chunks as CSV ``t_us,part,x,y``; returns the number of rows."""
    rows = 0
    with open(path, "w") as f:
        f.write("t_us,part,x,y\n")
        for tr in truth_chunks:
            f.writelines(f"{t},{p},{x:.4f},{y:.4f}\n"
                         for t, p, x, y in zip(tr["t"].tolist(), tr["part"].tolist(),
                                               tr["x"].tolist(), tr["y"].tolist()))
            rows += len(tr)
    return rows


__all__ = ["SensorConfig", "Sensor", "simulate", "simulate_all", "truth_between",
           "write_truth_csv", "TRUTH_DTYPE", "TRUTH_PERIOD_US", "SCENES"]
