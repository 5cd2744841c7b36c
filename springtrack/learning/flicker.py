"""Mains flicker in a learning window: lamps on 50 or 60 Hz mains make every edge they
light fire at 100 or 120 Hz, so a still scene gives events -- and a learner parts -- with
nothing moving (``springtrack learn`` says so; the model's ``[learned]`` table keeps it).

The event rate in 1 ms bins, its power spectrum, and the share of the power (above 5 Hz)
within a few Hz of the first three harmonics of 100 Hz and of 120 Hz, over the window's
first second: the larger share,
when the window is long enough to tell (``MIN_SPAN_US``), is the flicker's."""
from __future__ import annotations

import numpy as np

MAINS_HZ = (100.0, 120.0)     # twice the mains frequency: what a lamp's light does
HARMONICS = 3
MIN_SPAN_US = 100_000         # shorter windows cannot tell 100 Hz from a motion's own rhythm
MAX_SPAN_US = 1_000_000       # the rate is looked at over the window's first second at most
                              # (flicker is steady; the memory stays 1000 bins whatever the
                              # window's span, pauses included)
FLICKER_SHARE = 0.5           # at least this share of the rate's power: flicker


def mains_flicker(t_us: np.ndarray) -> tuple[float, float]:
    """(frequency Hz, share of the event rate's power) of the stronger mains flicker in
    the events' times ``t_us`` (sorted); (0, 0) for a window shorter than MIN_SPAN_US."""
    if len(t_us) < 2 or int(t_us[-1]) - int(t_us[0]) < MIN_SPAN_US:
        return 0.0, 0.0
    t_us = t_us[:int(np.searchsorted(t_us, t_us[0] + MAX_SPAN_US))]
    bins = ((t_us - t_us[0]) // 1000).astype(np.int64)
    rate = np.bincount(bins).astype(float)
    rate -= rate.mean()
    f = np.fft.rfftfreq(len(rate), 1e-3)
    power = np.abs(np.fft.rfft(rate)) ** 2
    above = f > 5.0
    total = float(power[above].sum())
    if total <= 0.0:
        return 0.0, 0.0
    width = max(2.0, 1.5 * float(f[1]))
    best = (0.0, 0.0)
    for hz in MAINS_HZ:
        near = np.zeros(len(f), bool)
        for k in range(1, HARMONICS + 1):
            near |= np.abs(f - k * hz) <= width
        share = float(power[near & above].sum()) / total
        best = max(best, (share, hz))
    return best[1], best[0]
