"""The exact truth of the real dot of evt2_sample.raw (a dark dot circling on a Gen3 sensor).

Every ``window_us`` the dot's centre is measured as the midpoint of the median ON-event and
the median OFF-event positions (its trailing and leading edges); a circle is fitted to those
midpoints (algebraic least squares, Kasa) and the angle about its centre to a line in time,
so the truth at any time is a point on that circle turning uniformly.  The residuals say how
good it is (radial ~0.5 px on the recording).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DotTruth:
    cx: float                 # circle centre, px
    cy: float
    radius: float             # px
    omega: float              # rad/us, the angle's rate (signed: image axes, y down)
    phase: float              # rad, the angle at t = t0
    t0: int                   # us
    radial_rms: float         # px, the midpoints' distance to the circle, RMS
    radial_median: float      # px, median |radial residual|
    along_median: float       # px, median |residual along the circle| (timing fit)
    windows: int              # midpoints used

    def at(self, t_us) -> tuple[np.ndarray, np.ndarray]:
        """The dot's centre (x, y) in px at the times ``t_us`` (array)."""
        a = self.phase + self.omega * (np.asarray(t_us, np.float64) - self.t0)
        return self.cx + self.radius * np.cos(a), self.cy + self.radius * np.sin(a)

    @property
    def turns_per_s(self) -> float:
        return abs(self.omega) * 1e6 / (2.0 * np.pi)

    @property
    def speed_px_s(self) -> float:
        return abs(self.omega) * 1e6 * self.radius


def midpoints(events: np.ndarray, window_us: int = 200, min_events: int = 50):
    """Per window of ``window_us``: (t_mid_us, x, y), the midpoint of the median ON and the
    median OFF event; windows with fewer than ``min_events`` of either polarity are left out."""
    t = events["t"]
    t0 = int(t[0])
    k = (t - t0) // window_us
    out = []
    for w in range(int(k[-1]) + 1):
        lo, hi = np.searchsorted(k, [w, w + 1])
        sel = events[lo:hi]
        on = sel[sel["p"] == 1]
        off = sel[sel["p"] == 0]
        if len(on) < min_events or len(off) < min_events:
            continue
        x = 0.5 * (np.median(on["x"].astype(float)) + np.median(off["x"].astype(float)))
        y = 0.5 * (np.median(on["y"].astype(float)) + np.median(off["y"].astype(float)))
        out.append((t0 + w * window_us + 0.5 * window_us, x, y))
    return np.array(out)


def dot_truth(events: np.ndarray, window_us: int = 200) -> DotTruth:
    """Fit the circle and the uniform turn to the window midpoints of ``events``."""
    m = midpoints(events, window_us)
    tm, x, y = m[:, 0], m[:, 1], m[:, 2]
    # circle: x^2 + y^2 = 2 a x + 2 b y + c (Kasa), r^2 = c + a^2 + b^2
    A = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    a, b, c = np.linalg.lstsq(A, x * x + y * y, rcond=None)[0]
    r = float(np.sqrt(c + a * a + b * b))
    rad = np.hypot(x - a, y - b) - r
    ang = np.unwrap(np.arctan2(y - b, x - a))
    t0 = int(events["t"][0])
    omega, phase = np.polyfit(tm - t0, ang, 1)
    along = (ang - (phase + omega * (tm - t0))) * r
    return DotTruth(float(a), float(b), r, float(omega), float(phase), t0,
                    float(np.sqrt(np.mean(rad * rad))), float(np.median(np.abs(rad))),
                    float(np.median(np.abs(along))), len(m))


def track_errors(truth: DotTruth, t_us, x, y) -> np.ndarray:
    """Distance in px of the positions (x, y) at times t_us to the dot's centre."""
    tx, ty = truth.at(t_us)
    return np.hypot(np.asarray(x) - tx, np.asarray(y) - ty)


def dot_model_toml(truth: DotTruth) -> str:
    """A one-tracker model (TOML) placed on the dot at the recording's start, on its
    640 x 480 sensor, 6 px standard deviation (the dot is about 22 px across)."""
    x, y = (float(v[0]) for v in truth.at([truth.t0]))
    return (f'name = "dot"\n[sensor]\nwidth = 640\nheight = 480\n[[trackers]]\n'
            f'id = "dot"\nx = {x:.1f}\ny = {y:.1f}\nsigma = [36.0, 0.0, 36.0]\n')
