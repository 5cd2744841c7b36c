"""Host-side smoothing of tracker telemetry: one constant-velocity Kalman filter per tracker
(``filterpy.kalman.KalmanFilter``), giving smoothed positions and velocities.

Model, per tracker, state ``[x, vx, y, vy]`` (px, px/s), the two axes independent:

* transition ``F = [[1, dt], [0, 1]]`` per axis, ``dt`` from the telemetry's event-time
  stamps (not host time, so link jitter does not enter);
* process noise: piecewise-white acceleration, ``Q = Q_discrete_white_noise(2, dt,
  accel_std**2)`` per axis; default ``accel_std`` = 30 px/s^2 (the face scene's parts
  accelerate by at most ~45 px/s^2; higher values follow faster but pass more jitter);
* measurement ``z = [x, y]`` with ``R = meas_std**2 I``; default ``meas_std`` = 1 px
  (tracker jitter on the simulated sensor, well above the 1/16 px telemetry quantum);
* start: position from the first measurement, velocity 0, ``P0 = diag(meas_std^2,
  v0_std^2)`` per axis, ``v0_std`` = 100 px/s.

A filterpy step costs ~27 µs, so filtering 26 trackers at the full 1 kHz telemetry rate
would take ~0.7 s of CPU per second; the filter therefore runs at ``rate_hz`` (default
100 Hz): it takes the first snapshot at or after each period boundary and skips the rest.
"""
from __future__ import annotations

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

SMOOTH_FIELDS = ("x_s", "y_s", "vx", "vy")


def _filter(x0: float, y0: float, meas_std: float, v0_std: float) -> KalmanFilter:
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.x = np.array([[x0], [0.0], [y0], [0.0]])
    kf.H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    kf.R = np.eye(2) * meas_std ** 2
    kf.P = np.diag([meas_std ** 2, v0_std ** 2, meas_std ** 2, v0_std ** 2])
    return kf


class Smoother:
    """Constant-velocity Kalman filters for ``n`` trackers (see the module docstring)."""

    def __init__(self, n: int, rate_hz: float = 100.0, meas_std: float = 1.0,
                 accel_std: float = 30.0, v0_std: float = 100.0):
        if rate_hz <= 0 or meas_std <= 0 or accel_std <= 0:
            raise ValueError("smoothing: rate_hz, meas_std and accel_std must be positive")
        self.n, self.period_us = n, 1e6 / rate_hz
        self.meas_std, self.accel_std, self.v0_std = meas_std, accel_std, v0_std
        self.filters: list[KalmanFilter] | None = None
        self.t_us: int | None = None
        self.updates = 0

    def update(self, t_us: int, x, y) -> bool:
        """Feed one snapshot; returns True if it was filtered (False: skipped by rate)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        if len(x) != self.n:
            raise ValueError(f"smoothing: snapshot has {len(x)} trackers, expected {self.n}")
        if self.filters is None:
            self.filters = [_filter(a, b, self.meas_std, self.v0_std) for a, b in zip(x, y)]
            self.t_us = int(t_us)
            return True
        dt_us = int(t_us) - self.t_us
        if dt_us < self.period_us:
            return False
        dt = dt_us * 1e-6
        F = np.array([[1.0, dt, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, dt], [0, 0, 0, 1.0]])
        Q = Q_discrete_white_noise(dim=2, dt=dt, var=self.accel_std ** 2, block_size=2)
        for kf, a, b in zip(self.filters, x, y):
            kf.predict(F=F, Q=Q)
            kf.update(np.array([a, b]))
        self.t_us = int(t_us)
        self.updates += 1
        return True

    def state(self) -> dict:
        """Current estimates: arrays x_s, y_s (px), vx, vy (px/s)."""
        if self.filters is None:
            return {k: np.full(self.n, np.nan) for k in SMOOTH_FIELDS}
        s = np.array([kf.x[:, 0] for kf in self.filters])
        return {"x_s": s[:, 0], "y_s": s[:, 2], "vx": s[:, 1], "vy": s[:, 3]}


def smooth_track(t_us, x, y, **kw) -> dict:
    """Filter a whole recording ((T,) times, (T, K) positions); returns the filtered times
    ``t_us`` and (T', K) arrays x_s, y_s, vx, vy at those times."""
    t_us = np.asarray(t_us)
    sm = Smoother(np.asarray(x).shape[1], **kw)
    rows, times = [], []
    for t, a, b in zip(t_us, x, y):
        if sm.update(t, a, b):
            times.append(int(t))
            rows.append(sm.state())
    out = {"t_us": np.array(times, np.int64)}
    for k in SMOOTH_FIELDS:
        out[k] = np.array([r[k] for r in rows]).reshape(len(rows), sm.n)
    return out
