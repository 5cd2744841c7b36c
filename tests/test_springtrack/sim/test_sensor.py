"""The simulated ATIS sensor (springtrack.sim.sensor): event statistics against hand-computed
values of the contrast-threshold model, determinism, chunking, noise and refractory."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from springtrack.sim.sensor import SensorConfig, simulate, simulate_all
from springtrack.events import EVENT_DTYPE

BG = 0.15           # moving_blob background (Scene.background)
C = 0.2             # default threshold
CLEAN = SensorConfig(noise_rate_hz=0.0, c_sigma=0.0, refractory_us=0)


def blob(seconds=2.0, config=CLEAN, seed=0, **kw):
    return simulate_all("moving_blob", seconds, seed=seed, config=config, **kw)[0]


@pytest.fixture(scope="module")
def clean_run():
    # blob sigma 4 px, amplitude 1, from x = 60 at 40 px/s along y = 120, 2 s
    return blob()


def test_static_scene_without_noise_gives_no_events():
    assert len(blob(speed=0.0)) == 0


def test_events_have_project_dtype_and_are_sorted(clean_run):
    ev = clean_run
    assert ev.dtype == EVENT_DTYPE
    assert np.all(np.diff(ev["t"]) >= 0)
    assert ev["t"].min() >= 0 and ev["t"].max() < 2_000_000


def test_events_only_where_the_blob_passes(clean_run):
    ev = clean_run
    # intensity changes only within the 3.5-sigma support of the blob's path
    assert np.all(np.abs(ev["y"].astype(int) - 120) <= 14)
    assert ev["x"].min() >= 60 - 15 and ev["x"].max() <= 60 + 80 + 15


def test_polarity_matches_the_sign_of_the_change(clean_run):
    ev = clean_run
    cx = 60.0 + 40.0 * ev["t"] / 1e6
    on = ev["p"] == 1
    # a bright blob moving right brightens pixels ahead of its centre, darkens behind
    assert np.all(ev["x"][on] > cx[on] - 0.5)
    assert np.all(ev["x"][~on] < cx[~on] + 0.5)


def test_event_count_per_pixel_is_log_contrast_over_threshold(clean_run):
    ev = clean_run
    x = 100   # the blob passes fully over this column
    for dy in range(0, 14):
        e = ev[(ev["x"] == x) & (ev["y"] == 120 + dy)]
        n_exp = math.log(1 + math.exp(-dy * dy / 32.0) / BG) / C
        n_on, n_off = int((e["p"] == 1).sum()), int((e["p"] == 0).sum())
        allowed = {math.floor(n_exp)} | ({math.floor(n_exp) - 1} if n_exp % 1 < 0.05 else set())
        assert n_on in allowed, (dy, n_on, n_exp)
        assert n_off == n_on    # the pixel returns to the background level


def test_first_event_time_is_the_interpolated_threshold_crossing(clean_run):
    ev = clean_run
    # first ON when ln(1 + g/BG) = C, g = exp(-dx^2 / 2 sigma^2)  =>  blob centre dx px away
    dx = 4.0 * math.sqrt(-2 * math.log(BG * (math.exp(C) - 1)))
    for x in (80, 100, 120):
        e = ev[(ev["x"] == x) & (ev["y"] == 120) & (ev["p"] == 1)]
        t_exp = (x - dx - 60.0) / 40.0
        assert abs(e["t"][0] / 1e6 - t_exp) < 200e-6


def test_disk_blob_fires_on_its_rim():
    # a disk of Mahalanobis radius sqrt(2): rim at R = sqrt(2) sigma from the centre
    ev = blob(1.0, sigma=5.0, edge=15.0)
    R = math.sqrt(2) * 5.0
    cx = 60.0 + 40.0 * ev["t"] / 1e6
    row = (ev["y"] == 120) & (ev["t"] > 100_000)
    on, off = row & (ev["p"] == 1), row & (ev["p"] == 0)
    assert abs(np.median(ev["x"][on] - cx[on]) - R) < 1.0
    assert abs(np.median(ev["x"][off] - cx[off]) + R) < 1.0
    # on the centre row the rim is crossed once each way: ln(1 + 1/BG)/C events
    e = ev[(ev["y"] == 120) & (ev["x"] == 80)]
    assert (e["p"] == 1).sum() == (e["p"] == 0).sum() == math.floor(math.log(1 + 1 / BG) / C)


def test_rate_scales_with_speed_and_contrast():
    base = len(blob(1.0, speed=40.0))
    fast = len(blob(1.0, speed=80.0))
    assert 1.8 < fast / base < 2.2                       # twice the path in the same time
    bright = len(blob(1.0, speed=40.0, amplitude=3.0))
    expect = math.log(1 + 3.0 / BG) / math.log(1 + 1.0 / BG)   # ~1.49 on the centre row
    assert 1.2 < bright / base < expect * 1.25
    dim = len(blob(1.0, speed=40.0, amplitude=0.3))
    assert dim < base / 2


def test_deterministic_for_a_seed_and_independent_of_chunking():
    cfg = SensorConfig(noise_rate_hz=2.0, hot_pixels=3, c_sigma=0.05)
    a = simulate_all("moving_blob", 0.503, seed=7, config=cfg, chunk_us=8_000)[0]
    b = simulate_all("moving_blob", 0.503, seed=7, config=cfg, chunk_us=200_000)[0]
    c = simulate_all("moving_blob", 0.5, seed=8, config=cfg)[0]
    assert np.array_equal(a, b)
    assert not (len(a) == len(c) and np.array_equal(a, c))


def test_chunks_are_sorted_across_boundaries_and_cover_the_duration():
    cfg = SensorConfig(noise_rate_hz=1.0)
    last, t_truth = -1, []
    for ev, tr in simulate("moving_blob", 0.3, seed=1, config=cfg, chunk_us=50_000):
        if len(ev):
            assert ev["t"][0] >= last and np.all(np.diff(ev["t"]) >= 0)
            last = ev["t"][-1]
        t_truth.append(tr["t"])
    t_truth = np.concatenate(t_truth)
    assert np.array_equal(t_truth, np.arange(0, 300_000, 1000))
    assert last < 300_000


def test_endless_stream_matches_a_finite_run():
    gen = simulate("moving_blob", math.inf, seed=2, chunk_us=20_000)
    chunks = [next(gen) for _ in range(10)]
    gen.close()
    ev = np.concatenate([c[0] for c in chunks])
    assert np.array_equal(ev, simulate_all("moving_blob", 0.2, seed=2)[0])
    assert chunks[-1][1]["t"].max() == 199_000


def test_background_noise_rate_and_hot_pixels():
    cfg = SensorConfig(noise_rate_hz=0.5, hot_pixels=5, hot_rate_hz=300.0)
    st_ = {}
    ev = np.concatenate([e for e, _ in simulate("moving_blob", 2.0, seed=3, config=cfg,
                                                speed=0.0, stats=st_)])
    npix = 304 * 240
    expected = 0.5 * npix * 2.0 + 5 * 300.0 * 2.0
    assert abs(len(ev) - expected) < 5 * math.sqrt(expected)
    assert st_["signal_events"] == 0 and st_["hot_events"] > 0
    pix, counts = np.unique(ev["y"].astype(int) * 304 + ev["x"], return_counts=True)
    assert np.sum(counts > 100) == 5         # the hot pixels stand out
    assert 0.45 < ev["p"].mean() < 0.55


def test_refractory_period_suppresses_and_counts():
    cfg = SensorConfig(noise_rate_hz=0.0, c_sigma=0.0, refractory_us=20_000)
    st_ = {}
    ev = simulate_all("moving_blob", 1.0, seed=0, config=cfg, stats=st_, speed=80.0)[0]
    assert st_["refractory_suppressed"] > 0
    key = ev["y"].astype(np.int64) * 304 + ev["x"]
    order = np.lexsort((ev["t"], key))
    same = np.diff(key[order]) == 0
    assert np.all(np.diff(ev["t"][order])[same] >= 20_000)


def test_threshold_mismatch_varies_counts_between_pixels():
    cfg = SensorConfig(noise_rate_hz=0.0, c_sigma=0.1, refractory_us=0)
    ev = blob(2.0, config=cfg)
    row = ev[(ev["y"] == 120) & (ev["x"] >= 80) & (ev["x"] <= 120)]
    counts = np.bincount(row["x"] - 80, minlength=41)
    assert len(set(counts.tolist())) > 1         # identical pixels would all give 20


@settings(max_examples=8, deadline=None)
@given(speed=st.floats(10.0, 120.0), y0=st.floats(30.0, 210.0), seed=st.integers(0, 1000))
def test_property_polarity_and_support(speed, y0, seed):
    cfg = SensorConfig(noise_rate_hz=0.0, c_sigma=0.05)
    ev = simulate_all("moving_blob", 0.25, seed=seed, config=cfg, speed=speed, y0=y0)[0]
    assert len(ev) > 0
    cx = 60.0 + speed * ev["t"] / 1e6
    on = ev["p"] == 1
    assert np.all(ev["x"][on] > cx[on] - 0.5) and np.all(ev["x"][~on] < cx[~on] + 0.5)
    assert np.all(np.abs(ev["y"] - y0) <= 15)
    assert ev["t"].max() < 250_000          # nothing beyond the requested duration


def test_config_errors_name_the_problem():
    with pytest.raises(ValueError, match="thresholds"):
        SensorConfig(c_on=0.0)
    with pytest.raises(ValueError, match="min_step_us"):
        SensorConfig(step_us=100, min_step_us=200)
    with pytest.raises(ValueError, match="unknown scene"):
        next(simulate("nope", 1.0))
