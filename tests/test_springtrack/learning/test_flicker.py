"""Mains flicker in a learning window (springtrack.learning.flicker)."""
import numpy as np
import pytest

from springtrack.learning.flicker import FLICKER_SHARE, mains_flicker


def pulsed(hz: float, seconds: float = 0.2, seed: int = 0, depth: float = 1.0):
    """Event times (µs) of a Poisson process whose rate is modulated at ``hz``."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0, seconds * 1e6, 200_000))
    keep = rng.uniform(0, 1, len(t)) < 0.5 * (1 + depth * np.cos(2 * np.pi * hz * t / 1e6))
    return t[keep].astype(np.int64)


@pytest.mark.parametrize("hz", [100.0, 120.0])
def test_a_lamp_on_mains_is_found_at_its_frequency(hz):
    f, share = mains_flicker(pulsed(hz))
    assert f == hz and share > 0.9


def test_a_steady_rate_or_another_rhythm_is_no_flicker():
    assert mains_flicker(pulsed(100.0, depth=0.0))[1] < FLICKER_SHARE
    assert mains_flicker(pulsed(19.4))[1] < FLICKER_SHARE          # the dot's turns


def test_a_short_window_cannot_tell():
    assert mains_flicker(pulsed(100.0, seconds=0.05)) == (0.0, 0.0)
    assert mains_flicker(np.zeros(0, np.int64)) == (0.0, 0.0)


def test_memory_is_bounded_by_a_second_of_bins_not_the_span():
    """A 28-hour pause after a flickering second: the same answer as the second alone."""
    t = pulsed(100.0, seconds=1.2)
    paused = np.concatenate([t, t[-1] + 28 * 3600 * 1_000_000 + t])
    assert mains_flicker(paused) == mains_flicker(t[t < t[0] + 1_000_000])
