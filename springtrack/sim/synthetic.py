"""Synthetic event streams drawn from a shape model, for tests and benchmarks.

Each part of the model emits events from a Gaussian with the part's covariance around its
position; the whole shape translates and rotates smoothly; a fraction of events is
uniform background noise.  This is a statistical stand-in for a camera, not a sensor
model (the sensor simulator is ``springtrack.sim.sensor``).
"""
from __future__ import annotations

import numpy as np

from ..events import make
from ..model import ShapeModel


def part_positions(model: ShapeModel, t_us: np.ndarray, speed_px_s=(20.0, -10.0),
                   rot_deg_s: float = 0.0, wobble_px: float = 0.0):
    """True positions (len(t), K, 2) of every part at times t_us under the motion model."""
    a = model.arrays()
    cx, cy = np.average(a["x"], weights=a["mass"]), np.average(a["y"], weights=a["mass"])
    ts = np.asarray(t_us, np.float64)[:, None] / 1e6
    ang = np.deg2rad(rot_deg_s) * ts
    c, s = np.cos(ang), np.sin(ang)
    rx, ry = a["x"][None, :] - cx, a["y"][None, :] - cy
    x = cx + c * rx - s * ry + speed_px_s[0] * ts + wobble_px * np.sin(2 * np.pi * 2 * ts)
    y = cy + s * rx + c * ry + speed_px_s[1] * ts + wobble_px * np.cos(2 * np.pi * 3 * ts)
    return np.stack([x, y], axis=-1)


def blob_stream(model: ShapeModel, n: int, rate_hz: float = 300_000.0, noise: float = 0.3,
                speed_px_s=(20.0, -10.0), rot_deg_s: float = 0.0, wobble_px: float = 0.0,
                seed: int = 0, t0_us: int = 0):
    """``n`` events at ``rate_hz`` mean rate; returns (events, truth positions per event)."""
    rng = np.random.default_rng(seed)
    a = model.arrays()
    k = rng.integers(0, len(a["x"]), n)
    t = t0_us + np.cumsum(rng.exponential(1e6 / rate_hz, n)).astype(np.int64)
    pos = part_positions(model, t, speed_px_s, rot_deg_s, wobble_px)[np.arange(n), k]
    # correlated Gaussian per part: L = chol([sxx sxy; sxy syy])
    l11 = np.sqrt(a["sxx"][k])
    l21 = a["sxy"][k] / l11
    l22 = np.sqrt(np.maximum(a["syy"][k] - l21 ** 2, 1e-12))
    z1, z2 = rng.standard_normal(n), rng.standard_normal(n)
    x = pos[:, 0] + l11 * z1
    y = pos[:, 1] + l21 * z1 + l22 * z2
    bg = rng.random(n) < noise
    x[bg] = rng.uniform(0, model.width, bg.sum())
    y[bg] = rng.uniform(0, model.height, bg.sum())
    keep = (x >= 0) & (y >= 0) & (x < model.width - 0.5) & (y < model.height - 0.5)
    ev = make(t[keep], np.round(x[keep]), np.round(y[keep]), rng.integers(0, 2, keep.sum()))
    return ev, pos[keep]
