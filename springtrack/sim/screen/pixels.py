"""The screen generator's pixel array: images held for one refresh period each -> events.

Sensor assumptions (each different from springtrack.sim.sensor's):

* the input is piecewise constant: the screen shows each image for a whole refresh
  period (100 Hz by default), so every change reaches the pixels as a step;
* each pixel's photoreceptor is a first-order low-pass filter of the log intensity whose
  time constant grows as its light falls (bandwidth proportional to the photocurrent):
  ``tau = tau_bright_us * I_bright / I_state``, ``I_state = exp(L) - dark`` the intensity the
  pixel is adapted to at the start of the refresh period.  Within a period the input
  ``T`` is constant, so ``L(t) = T + (L0 - T) exp(-t / tau)`` exactly.  A pixel that was
  bright responds at once, one that was dark lags: a dark part's leading edge fires
  OFF promptly, its trailing edge fires ON with a latency tail;
* log intensity ``L = ln(I + dark)`` (a dark current keeps black finite);
* per-pixel thresholds, ON and OFF with different means (``c_on``, ``c_off``) and a
  relative mismatch ``c_sigma`` (clipped at 0.3 of the mean);
* every crossing of the reference +- its threshold is an event at the analytic crossing
  time; the pixel is then blind for ``refractory_us``: an event due earlier is emitted
  when the pixel re-arms (a step fires a burst spaced by the refractory period, nothing
  is dropped);
* readout latency: every event leaves ``latency_us`` plus an exponential jitter of mean
  ``jitter_us`` after its crossing (events are re-sorted by their readout time);
* shot noise: the log intensity a pixel receives in each period carries a Gaussian error
  of ``shot_sigma * sqrt(I_bright / I)`` (photon noise, relatively larger in the dark);
* background activity: a Poisson leak of ``leak_rate_hz`` per pixel, ``leak_on_share``
  of them ON; ``hot_pixels`` pixels fire at ``hot_rate_hz``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from springtrack.events import EVENT_DTYPE


@dataclass(frozen=True)
class ScreenConfig:
    width: int = 304
    height: int = 240
    refresh_hz: float = 100.0      # screen refresh: the image is held this long
    blur_px: float = 0.7           # optics: Gaussian point-spread standard deviation, px
    dark: float = 0.02             # dark current, linear intensity units
    c_on: float = 0.25             # mean ON threshold, log-intensity units
    c_off: float = 0.18            # mean OFF threshold
    c_sigma: float = 0.06          # relative per-pixel threshold mismatch (std)
    tau_bright_us: float = 250.0   # photoreceptor time constant at I_bright
    i_bright: float = 1.0          # intensity of tau_bright_us
    tau_max_us: float = 8000.0     # the slowest photoreceptor (a black pixel)
    refractory_us: float = 300.0
    latency_us: float = 40.0       # fixed readout latency
    jitter_us: float = 30.0        # mean of the exponential readout jitter
    shot_sigma: float = 0.01       # log-intensity noise per period at I_bright
    leak_rate_hz: float = 0.2      # background activity per pixel
    leak_on_share: float = 0.8
    hot_pixels: int = 2
    hot_rate_hz: float = 50.0

    def __post_init__(self):
        if self.width < 1 or self.height < 1:
            raise ValueError(f"screen config: width and height must be >= 1, got "
                             f"{self.width}x{self.height}")
        if not self.refresh_hz > 0 or self.refresh_hz > 1e5:
            raise ValueError(f"screen config: refresh_hz must be in (0, 1e5], got {self.refresh_hz}")
        if self.c_on <= 0 or self.c_off <= 0 or self.dark <= 0:
            raise ValueError("screen config: c_on, c_off and dark must be positive")
        for name in ("blur_px", "c_sigma", "refractory_us", "latency_us", "jitter_us",
                     "shot_sigma", "leak_rate_hz", "hot_rate_hz", "hot_pixels"):
            if getattr(self, name) < 0:
                raise ValueError(f"screen config: {name} must not be negative, got "
                                 f"{getattr(self, name)}")
        if not 0.0 <= self.leak_on_share <= 1.0:
            raise ValueError(f"screen config: leak_on_share must be in [0, 1], got "
                             f"{self.leak_on_share}")
        if not 0 < self.tau_bright_us <= self.tau_max_us:
            raise ValueError("screen config: need 0 < tau_bright_us <= tau_max_us")


@dataclass
class PixelStats:
    periods: int = 0
    signal_events: int = 0
    refractory_delayed: int = 0    # events held back until their pixel re-armed
    leak_events: int = 0
    hot_events: int = 0


class PixelArray:
    """The pixels' state; :meth:`period` turns one held image into events."""

    def __init__(self, cfg: ScreenConfig, first_image: np.ndarray, seed: int):
        self.cfg = cfg
        h, w = cfg.height, cfg.width
        rng = np.random.default_rng([int(seed), 11])
        self.c_on = np.maximum(cfg.c_on * (1 + cfg.c_sigma * rng.standard_normal((h, w))),
                               0.3 * cfg.c_on).ravel()
        self.c_off = np.maximum(cfg.c_off * (1 + cfg.c_sigma * rng.standard_normal((h, w))),
                                0.3 * cfg.c_off).ravel()
        self.noise = np.random.default_rng([int(seed), 12])
        self.L = np.log(first_image.ravel() + cfg.dark)      # adapted to the first image
        self.ref = self.L.copy()
        self.busy = np.zeros(h * w)                          # re-armed at this time, us
        hot = rng.choice(h * w, size=min(cfg.hot_pixels, h * w), replace=False)
        self.hot = np.sort(hot)
        self.stats = PixelStats()
        self.l_bright = math.log(cfg.i_bright + cfg.dark)

    def period(self, image: np.ndarray, t0_us: float, dt_us: float) -> np.ndarray:
        """Events (unsorted, readout times) of the period [t0, t0 + dt) in which ``image``
        (H, W linear intensity) is shown."""
        cfg, rng = self.cfg, self.noise
        i_lin = image.ravel()
        target = np.log(i_lin + cfg.dark)
        if cfg.shot_sigma > 0:
            # photon noise: relative error ~ 1 / sqrt(photons)
            target = target + cfg.shot_sigma * np.sqrt(cfg.i_bright / np.maximum(i_lin, cfg.dark)) \
                * rng.standard_normal(target.shape)
        L0 = self.L
        # tau proportional to 1 / photocurrent at the state the pixel starts from
        i_state = np.maximum(np.exp(L0) - cfg.dark, 1e-6)
        tau = np.minimum(cfg.tau_bright_us * cfg.i_bright / i_state, cfg.tau_max_us)
        L1 = target + (L0 - target) * np.exp(-dt_us / tau)
        up = np.floor((L1 - self.ref) / self.c_on)                # crossings upward
        down = np.floor((self.ref - L1) / self.c_off)             # and downward
        n = np.where(up > 0, up, 0) + np.where(down > 0, down, 0)
        idx = np.flatnonzero(n > 0)
        events = [self._crossings(idx, n[idx].astype(np.int64), up[idx] > 0, L0[idx],
                                  target[idx], tau[idx], t0_us)]
        self.L = L1
        events.append(self._background(t0_us, dt_us))
        self.stats.periods += 1
        return np.concatenate(events)

    def _crossings(self, idx, n, on, L0, target, tau, t0_us):
        cfg = self.cfg
        if not len(idx):
            return np.zeros(0, EVENT_DTYPE)
        c = np.where(on, self.c_on[idx], -self.c_off[idx])
        ref0 = self.ref[idx]
        self.ref[idx] = ref0 + n * c                      # the reference steps per event
        # the k-th crossing (k = 1..n) of the level ref0 + k c on the exponential
        rep = np.repeat(np.arange(len(idx)), n)
        k = np.arange(len(rep)) - np.repeat(np.cumsum(n) - n, n) + 1
        level = ref0[rep] + k * c[rep]
        ratio = (level - target[rep]) / (L0[rep] - target[rep])
        t_cross = t0_us - tau[rep] * np.log(np.clip(ratio, 1e-300, 1.0))
        # refractory: each event no earlier than the previous one of its pixel + refractory
        t_emit = t_cross.copy()
        busy = self.busy[idx]
        first = np.cumsum(n) - n
        for j in range(int(n.max())):
            sel = n > j
            pos = first[sel] + j
            t = np.maximum(t_cross[pos], busy[sel])
            self.stats.refractory_delayed += int(np.count_nonzero(t > t_cross[pos]))
            t_emit[pos] = t
            busy[sel] = t + cfg.refractory_us
        self.busy[idx] = busy
        self.stats.signal_events += len(rep)
        pix = idx[rep]
        return self._pack(t_emit, pix, on[rep])

    def _readout(self, t):
        cfg = self.cfg
        jitter = self.noise.exponential(cfg.jitter_us, size=len(t)) if cfg.jitter_us > 0 else 0.0
        return np.floor(t + cfg.latency_us + jitter).astype(np.int64)

    def _pack(self, t, pix, on):
        ev = np.empty(len(t), EVENT_DTYPE)
        ev["t"] = self._readout(t)
        ev["y"], ev["x"] = np.divmod(pix, self.cfg.width)
        ev["p"] = on.astype(np.uint8)
        return ev

    def _background(self, t0_us, dt_us):
        cfg, rng = self.cfg, self.noise
        npx = cfg.width * cfg.height
        parts = []
        for rate, pixels, on_share, counter in (
                (cfg.leak_rate_hz * npx, None, cfg.leak_on_share, "leak_events"),
                (cfg.hot_rate_hz * len(self.hot), self.hot, 0.5, "hot_events")):
            m = rng.poisson(rate * dt_us * 1e-6) if rate > 0 else 0
            if not m:
                continue
            t = t0_us + rng.uniform(0.0, dt_us, size=m)
            pix = rng.integers(0, npx, size=m) if pixels is None else rng.choice(pixels, size=m)
            parts.append(self._pack(t, pix, rng.random(m) < on_share))
            setattr(self.stats, counter, getattr(self.stats, counter) + m)
        return np.concatenate(parts) if parts else np.zeros(0, EVENT_DTYPE)
