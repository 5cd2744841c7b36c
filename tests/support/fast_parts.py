"""Fast parts on the project's simulated sensor (springtrack.sim), with edge latency.

A disk ``diameter_px`` across circles the sensor's centre at ``speed_px_s``, bright on a
dark background or dark on a bright one, rendered by the simulated sensor (its
contrast-threshold model, per-pixel mismatch, refractory period and noise); each event is
then delayed by a latency drawn per polarity (exponential, mean ``latency_us`` =
(ON, OFF)), as a real sensor's pixels answer brightening and darkening with different
delays, and the stream re-sorted in time.  The truth is the disk's centre at each time.
"""
from __future__ import annotations

import math

import numpy as np

from springtrack.model import ShapeModel, TrackerSpec
from springtrack.sim.scenes import HEIGHT, WIDTH, Frame, Scene, NO_OCCLUDERS
from springtrack.sim.sensor import simulate_all

CX, CY = WIDTH / 2.0, HEIGHT / 2.0
RADIUS = 80.0                 # px, the circle the disk's centre runs on
EDGE = 4.0                    # the disk's logistic edge sharpness (springtrack.sim.scenes)


class CirclingDisk(Scene):
    name = "circling_disk"
    part_ids = ["disk"]

    def __init__(self, seed=0, speed_px_s=5000.0, diameter_px=22.0, dark=True):
        super().__init__(seed)
        self.omega = float(speed_px_s) / RADIUS          # rad/s
        self.r2 = (float(diameter_px) / 2.0) ** 2 / 2.0  # disk of Mahalanobis radius sqrt 2
        self.dark = bool(dark)
        self.background = 1.0 if dark else 0.15

    def truth(self, t):
        a = self.omega * t
        return np.array([[CX + RADIUS * math.cos(a), CY + RADIUS * math.sin(a)]])

    def frame(self, t):
        (x, y), = self.truth(t)
        disk = np.array([[x, y, self.r2, 0.0, self.r2, 0.15 if self.dark else 1.0, EDGE]])
        if self.dark:            # an opaque dark disk over the bright background
            return Frame(np.zeros((0, 7)), disk)
        return Frame(disk, NO_OCCLUDERS)


def fast_disk(speed_px_s: float, dark: bool, seconds: float | None = None,
              latency_us=(40.0, 20.0), diameter_px: float = 22.0, seed: int = 0):
    """(events, scene, model): the events of a CirclingDisk with per-polarity latency
    (``seconds`` default: two turns, at most 0.5 s), the scene (``truth(t_s)``) and a
    one-tracker model placed on the disk at t = 0."""
    scene = CirclingDisk(seed, speed_px_s, diameter_px, dark)
    if seconds is None:
        seconds = min(0.5, 2 * 2 * math.pi * RADIUS / speed_px_s)
    ev, _ = simulate_all(scene, seconds=seconds, seed=seed)
    rng = np.random.default_rng(seed)
    mean = np.where(ev["p"] == 1, latency_us[0], latency_us[1])
    ev = ev.copy()
    ev["t"] = ev["t"] + np.round(rng.exponential(1.0, len(ev)) * mean).astype(np.int64)
    ev = ev[np.argsort(ev["t"], kind="stable")]
    (x, y), = scene.truth(0.0)
    s2 = (diameter_px / 2.0) ** 2 / 2.0
    model = ShapeModel("disk", WIDTH, HEIGHT, [TrackerSpec("disk", x, y, (s2, 0.0, s2))], [])
    return ev, scene, model


def errors(scene: CirclingDisk, track) -> np.ndarray:
    """Distance (px) of a one-tracker track's positions to the disk's centre."""
    a = scene.omega * track.t_us * 1e-6
    return np.hypot(track.x[:, 0] - (CX + RADIUS * np.cos(a)),
                    track.y[:, 0] - (CY + RADIUS * np.sin(a)))
