"""Preparing a recording's events (springtrack.prep): tick detection, time window, burst
filter, de-quantisation, streaming equal to whole, the real dvs.es."""
from __future__ import annotations

import numpy as np
import pytest

from springtrack.events import make
from springtrack.prep import Preparer, dequantize, prepare, tick_us
from support.ticks import ticked


def test_tick_detection():
    assert tick_us(ticked(tick=1000)["t"]) == 1000
    assert tick_us(ticked(tick=250, t0=77)["t"]) == 250
    assert tick_us(np.array([5, 6, 9, 30])) == 1
    assert tick_us(np.array([3, 3, 3])) == 1 and tick_us(np.array([], np.int64)) == 1


def test_dequantize_spreads_each_tick_evenly_in_a_seeded_order():
    ev = ticked(per_tick=40)
    out = dequantize(ev, 1000, seed=1)
    assert len(out) == len(ev) and np.all(np.diff(out["t"]) >= 0)
    for T in (0, 1000, 49000):
        src, got = ev[ev["t"] == T], out[(out["t"] >= T) & (out["t"] < T + 1000)]
        assert np.array_equal(got["t"], T + (np.arange(40) * 1000) // 40)      # evenly
        key = lambda e: sorted(zip(e["x"].tolist(), e["y"].tolist(), e["p"].tolist()))
        assert key(got) == key(src)                                             # same events
        assert not np.array_equal(got["y"], src["y"])                           # not row order
    assert np.array_equal(dequantize(ev, 1000, seed=1), out)
    assert not np.array_equal(dequantize(ev, 1000, seed=2), out)


def test_window_is_half_open_and_counted():
    ev = ticked(n_ticks=10)
    out, st = prepare(ev, 100, 80, start_us=2000, end_us=5000)
    assert out["t"].min() == 2000 and out["t"].max() == 4000
    assert st.outside_window == len(ev) - len(out) == 7 * 30


def test_full_frame_burst_is_dropped_and_counted():
    ev = ticked(n_ticks=20, per_tick=30, tick=1000, t0=1000)
    ys, xs = np.divmod(np.arange(100 * 80), 100)
    burst = make(np.zeros(len(xs), np.int64), xs, ys, np.ones(len(xs)))
    out, st = prepare(np.concatenate([burst, ev]), 100, 80)
    assert st.burst_bins == 1 and st.burst_events == 100 * 80
    assert np.array_equal(out, ev)
    _, kept = prepare(np.concatenate([burst, ev]), 100, 80, burst_fraction=None)
    assert kept.burst_events == 0


@pytest.mark.parametrize("pieces", [1, 7, 113])
def test_streaming_equals_whole(pieces):
    ev = ticked(n_ticks=60, per_tick=25)
    whole, _ = prepare(ev, 100, 80, start_us=3000, dequantize=True, seed=4)
    p = Preparer(100, 80, start_us=3000, dequantize=True, seed=4)
    parts = [p.feed(c) for c in np.array_split(ev, pieces)] + [p.finish()]
    assert np.array_equal(np.concatenate(parts), whole)
    assert p.stats.tick_us == 1000 and p.stats.events_out == len(whole)


def test_fine_timestamps_pass_unchanged():
    rng = np.random.default_rng(3)
    t = np.sort(rng.integers(0, 100_000, 5000))
    ev = make(t, rng.integers(0, 100, 5000), rng.integers(0, 80, 5000), 1)
    out, st = prepare(ev, 100, 80, dequantize=True)
    assert st.tick_us == 1 and np.array_equal(out, ev)


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="end_us"):
        Preparer(10, 10, start_us=5, end_us=5)
    with pytest.raises(ValueError, match="burst_fraction"):
        Preparer(10, 10, burst_fraction=1.5)


def test_dvs_es_as_delivered(data_file):
    """The real quirks: 1 ms ticks in row order and a full-frame burst of ON events at 0."""
    import springtrack.io as stio
    ev = stio.open(data_file("dvs.es")).read()
    out, st = prepare(ev, 320, 240, dequantize=True)
    assert st.tick_us == 1000
    assert st.burst_bins == 1 and st.burst_events == int(np.sum(ev["t"] == 0)) == 76_785
    assert len(out) == len(ev) - 76_785 and np.all(np.diff(out["t"]) >= 0)
    assert len(np.unique(out["t"])) > 100 * len(np.unique(ev["t"][ev["t"] > 0])) // 2
