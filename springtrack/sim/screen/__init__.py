"""A second, independent event generator: scenes shown on a screen refreshed at 100 Hz and
filmed by an event camera whose pixels differ from springtrack.sim.sensor's in every
assumption (see :mod:`.pixels`): a held image per refresh instead of a continuously
moving one, anti-aliased opaque shapes blurred by the optics instead of Gaussian blobs,
photoreceptors whose latency grows in the dark (ON and OFF edges differ), unequal ON/OFF
thresholds, refractory bursts, readout jitter, shot noise and leak events.

:func:`simulate` yields ``(events, truth)`` chunks of the same types as
:func:`springtrack.sim.sensor.simulate` (``EVENT_DTYPE`` sorted by ``t``; ``TRUTH_DTYPE``
every ``TRUTH_PERIOD_US``), so the tracker, the scorer and the CLI take either.  The
truth is the part's centre in the image the screen shows at that time (the pose at the
latest refresh).
"""
from __future__ import annotations

import math

import numpy as np

from springtrack.events import EVENT_DTYPE

from .. import sensor
from .pixels import PixelArray, ScreenConfig
from .render import gaussian_taps, render
from .scenes import SCENES, ScreenScene, make_scene

NAME = "screen"


def shown_at(t_us: np.ndarray, refresh_hz: float) -> np.ndarray:
    """Time (s) of the refresh whose image is on the screen at each ``t_us``."""
    period = 1e6 / refresh_hz
    return np.floor(np.asarray(t_us) / period) * period * 1e-6


def truth_between(scene: ScreenScene, t0_us: int, t1_us: int, refresh_hz: float) -> np.ndarray:
    """Ground truth at every multiple of TRUTH_PERIOD_US in [t0_us, t1_us): the parts'
    centres in the image shown then."""
    return sensor.truth_between(scene, t0_us, t1_us, lambda t: shown_at(t, refresh_hz))


def simulate(scene, seconds: float | None = None, seed: int = 0, chunk_us: int = 100_000,
             config: ScreenConfig | None = None, stats: dict | None = None, **scene_params):
    """Generator of ``(events, truth)`` chunks covering ``[0, seconds)``.

    ``scene``: a name of :data:`SCENES` (``scene_params`` go to its constructor) or a
    scene instance; ``seconds=None`` is the scene's default.  Events are sorted by their
    readout time; an event read out after a chunk's end is handed out with the next
    chunk (none is lost; those read out after ``seconds`` are dropped and counted as
    ``late_dropped`` in ``stats``).  ``stats``, if a dict, is updated after every chunk.
    """
    scene = make_scene(scene, seed=seed, **scene_params)
    cfg = config or ScreenConfig()
    seconds = scene.default_seconds if seconds is None else float(seconds)
    if not (seconds > 0 and math.isfinite(seconds)):
        raise ValueError(f"simulate: seconds must be positive and finite, got {seconds}")
    if chunk_us < 1:
        raise ValueError(f"simulate: chunk_us must be >= 1, got {chunk_us}")
    end_us = int(round(seconds * 1e6))
    period = 1e6 / cfg.refresh_hz
    taps = gaussian_taps(cfg.blur_px) if cfg.blur_px > 0 else None

    def image(k):
        return render(scene.shapes(k * period * 1e-6), scene.background, cfg.width,
                      cfg.height, taps)

    pixels = PixelArray(cfg, image(0), seed)
    pending = np.zeros(0, EVENT_DTYPE)
    k = 1                                  # refresh k shows the scene at k * period
    t = 0
    late = 0
    while t < end_us:
        t1 = min(t + int(chunk_us), end_us)
        parts = [pending]
        while k * period < t1:
            parts.append(pixels.period(image(k), k * period, period))
            k += 1
        ev = np.concatenate(parts)
        ev = ev[np.argsort(ev["t"], kind="stable")]
        cut = int(np.searchsorted(ev["t"], t1, side="left"))
        pending = ev[cut:]
        if t1 >= end_us:
            late += len(pending)
        if stats is not None:
            stats.update(vars(pixels.stats), late_dropped=late)
        yield ev[:cut], truth_between(scene, t, t1, cfg.refresh_hz)
        t = t1


def simulate_all(scene, seconds: float | None = None, seed: int = 0, **kw):
    """The whole simulation at once: ``(events, truth)`` arrays."""
    ev, tr = zip(*simulate(scene, seconds, seed, **kw))
    return np.concatenate(ev), np.concatenate(tr)


__all__ = ["NAME", "SCENES", "ScreenConfig", "make_scene", "simulate", "simulate_all",
           "truth_between"]
