"""Recordings with coarse timestamp ticks (as dvs.es: events in row order inside a tick)."""
from __future__ import annotations

import numpy as np
from springtrack.events import make


def ticked(n_ticks=50, per_tick=30, tick=1000, t0=0, seed=0):
    """Events in ``tick``-µs ticks, each tick's events in row order (as dvs.es)."""
    rng = np.random.default_rng(seed)
    t = np.repeat(t0 + tick * np.arange(n_ticks), per_tick)
    x = rng.integers(0, 100, len(t))
    y = np.concatenate([np.sort(rng.integers(0, 80, per_tick)) for _ in range(n_ticks)])
    return make(t, x, y, rng.integers(0, 2, len(t)))
