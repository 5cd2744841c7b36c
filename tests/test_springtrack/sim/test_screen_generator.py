"""The independent screen generator (springtrack.sim.screen): its events, its pixel
model's assumptions (held images, dark-slow photoreceptors, refractory bursts), its
scenes' truth, the generator registry and the simulate CLI."""
import math

import numpy as np
import pytest

from springtrack.cli import main
from springtrack.events import EVENT_DTYPE
from springtrack.metrics import read_truth_csv
from springtrack.sim.generators import GENERATORS, generator
from springtrack.sim.screen import ScreenConfig, make_scene, simulate_all, truth_between
from springtrack.sim.screen.render import render
from springtrack.sim.screen.scenes import SCENES


def test_registry_names_both_generators_and_refuses_others():
    assert set(GENERATORS) == {"sensor", "screen"}
    assert "grid_pull" in generator("screen").scenes and "grid_pull" in generator("sensor").scenes
    with pytest.raises(ValueError, match="known: sensor, screen"):
        generator("esim")


@pytest.mark.parametrize("name", sorted(SCENES))
def test_short_run_events_are_valid_and_deterministic(name):
    ev, tr = simulate_all(name, 0.12, seed=4, chunk_us=30_000)
    assert ev.dtype == EVENT_DTYPE and len(ev) > 500
    assert np.all(np.diff(ev["t"]) >= 0) and ev["t"][-1] < 120_000
    assert ev["x"].max() < 304 and ev["y"].max() < 240
    assert set(np.unique(ev["p"])) == {0, 1}
    sc = make_scene(name)
    assert len(tr) == 120 * len(sc.part_ids) and list(tr["part"][:len(sc.part_ids)]) == sc.part_ids
    again, _ = simulate_all(name, 0.12, seed=4, chunk_us=70_000)     # chunking changes nothing
    assert np.array_equal(ev, again)
    other, _ = simulate_all(name, 0.12, seed=5)
    assert not np.array_equal(ev, other)


def test_initial_models_match_the_presets_ids():
    for name in ("grid_pull", "grid_inplane", "grid_rot_y", "face_occlusion", "dots"):
        sc = make_scene(name)
        m = sc.initial_model()
        assert m.ids == sc.part_ids
        xy = np.array([(t.x, t.y) for t in m.trackers])
        assert np.abs(xy - sc.truth(0.0)).max() < 1e-9


def test_grid_pull_truth_is_the_unpulled_disc_and_the_disc_moves_1_5_spacings():
    sc = make_scene("grid_pull")
    k = sc.k_pulled
    assert sc.part_ids[k] == "r1c2"
    for t, amount in ((1.0, 0.0), (4.5, 1.0), (12.5, 1.0), (7.5, 0.0)):
        assert sc.pull_amount(t) == pytest.approx(amount)
    # at rest pose the plane is the image: the pulled disc is drawn 67.5 px right of its truth
    sc0 = make_scene("grid_pull")
    sc0.pose = lambda t: (0.0, 0.0, 0.0, 0.0, 0.0)
    drawn = sc0.shapes(4.5)[:, :2]
    assert drawn[k] - sc0.truth(4.5)[k] == pytest.approx([67.5, 0.0])
    others = np.delete(np.arange(9), k)
    assert np.abs(drawn[others] - sc0.truth(4.5)[others]).max() < 1e-9


def test_truth_is_the_image_on_the_screen_until_the_next_refresh():
    sc = make_scene("grid_inplane")
    tr = truth_between(sc, 0, 30_000, 100.0)
    xy = np.stack([tr["x"], tr["y"]], -1).reshape(30, 9, 2)
    assert np.array_equal(xy[10], xy[19]) and not np.array_equal(xy[19], xy[20])
    assert np.allclose(xy[25], sc.truth(0.02))


def test_renderer_antialiases_a_disc_to_its_area():
    img = render(np.array([[50.3, 40.7, 10.0, 0.0, 0.0, 10.0, 0.0]]), 1.0, 100, 80, None)
    assert (1.0 - img).sum() == pytest.approx(math.pi * 100.0, rel=2e-3)
    assert 0.0 < img[40, 60] < 1.0 or 0.0 < img[40, 61] < 1.0       # a rim pixel is mixed


def _first_delays(ev, mask):
    """Delay (us) after its refresh of each pixel's first event of each refresh period."""
    e = ev[mask]
    key = (e["t"] // 10_000) * (1 << 20) + e["y"].astype(np.int64) * 304 + e["x"]
    order = np.lexsort((e["t"], key))
    first = np.r_[True, np.diff(key[order]) != 0]
    return (e["t"][order][first] % 10_000).astype(float)


def test_a_dark_parts_trailing_edge_fires_on_later_than_its_leading_edge_fires_off():
    """The photoreceptor is slow where it was dark: the dark dot's trailing edge (dark ->
    bright: ON) lags its leading edge (bright -> dark: OFF)."""
    cfg = ScreenConfig(leak_rate_hz=0.0, hot_pixels=0, shot_sigma=0.0, jitter_us=0.0)
    ev, _ = simulate_all("dots", 0.5, config=cfg, speed=200.0)
    rows = np.abs(ev["y"].astype(int) - 80) <= 3                       # the dark dot's rows
    on = _first_delays(ev, rows & (ev["p"] == 1))
    off = _first_delays(ev, rows & (ev["p"] == 0))
    assert len(on) > 100 and len(off) > 100
    assert np.median(on) > 2 * np.median(off)


def test_a_step_fires_a_burst_spaced_by_the_refractory_period():
    cfg = ScreenConfig(leak_rate_hz=0.0, hot_pixels=0, shot_sigma=0.0, jitter_us=0.0,
                       refractory_us=500.0)
    ev, _ = simulate_all("dots", 0.3, config=cfg, speed=300.0)
    px = ev["y"].astype(np.int64) * 304 + ev["x"]
    order = np.lexsort((ev["t"], px))
    same = np.diff(px[order]) == 0
    gaps = np.diff(ev["t"][order])[same]
    assert len(gaps) > 100 and gaps.min() >= 499          # floor() of the readout time


def test_config_errors_name_the_field():
    with pytest.raises(ValueError, match="refresh_hz"):
        ScreenConfig(refresh_hz=0)
    with pytest.raises(ValueError, match="leak_on_share"):
        ScreenConfig(leak_on_share=2.0)
    with pytest.raises(ValueError, match="unknown screen scene 'x'"):
        make_scene("x")


def test_cli_simulate_with_the_screen_generator(tmp_path, capsys):
    ev, tru, mod = tmp_path / "d.npy", tmp_path / "d.csv", tmp_path / "d.toml"
    assert main(["simulate", "--generator", "screen", "dots", "--speed", "400",
                 "--refresh-hz", "500", "--out", str(ev), "--truth", str(tru),
                 "--model-out", str(mod), "--seconds", "0.1"]) == 0
    events = np.load(ev)
    assert len(events) > 1000 and np.all(np.diff(events["t"]) >= 0)
    truth = read_truth_csv(tru)
    assert truth.ids == ["dark", "bright"] and len(truth.t_us) == 100
    # at 500 Hz the truth steps every 2 ms; 400 px/s: 0.8 px per step
    dx = np.diff(truth.xy[:, 0, 0])
    assert set(np.round(dx, 6)) == {0.0, 0.8}
    assert "(screen)" in capsys.readouterr().err
    rc = main(["simulate", "--generator", "screen", "moving_blob", "--out", str(ev),
               "--truth", str(tru)])
    assert rc == 2 and "not one of --generator screen's" in capsys.readouterr().err
    rc = main(["simulate", "grid_pull", "--refresh-hz", "60", "--out", str(ev),
               "--truth", str(tru)])
    assert rc == 2 and "--refresh-hz applies to --generator screen only" in capsys.readouterr().err
