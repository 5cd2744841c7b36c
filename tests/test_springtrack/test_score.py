"""The paper's error metric (springtrack.metrics) on hand-made cases, the simulate/score
CLI, and a short end-to-end grid_pull run of the tracker."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from springtrack.sim.scenes import make_scene
from springtrack.sim.sensor import truth_between
from springtrack.cli import main
from springtrack.metrics import (Truth, match_times, object_length, read_truth_csv,
                                 tracking_error, truth_from_array)
from springtrack.model import FACE_INTERNAL, face26, grid3x3


def scene_truth(name, t0=0, t1=200_000):
    return truth_from_array(truth_between(make_scene(name), t0, t1))


def as_track(truth, dx=0.0, dy=0.0):
    return truth.t_us, truth.ids, truth.xy[..., 0] + dx, truth.xy[..., 1] + dy


def write_track(path, t, ids, x, y):
    with open(path, "w") as f:
        f.write("t_us,tracker,x,y,sxx,sxy,syy,activity,active,sensitive\n")
        for i, ti in enumerate(t):
            for k, name in enumerate(ids):
                f.write(f"{ti},{name},{x[i, k]:.6f},{y[i, k]:.6f},25,0,25,1,1,1\n")


def test_grid_length_is_twice_the_spacing_at_rest():
    m = grid3x3(spacing=50.0)
    xy = np.array([[[t.x, t.y] for t in m.trackers]])
    assert object_length("grid", m.ids, xy) == pytest.approx([100.0])


def test_face_mask_length_is_the_outline_height():
    m = face26(scale=120.0)
    xy = np.array([[[t.x, t.y] for t in m.trackers]])
    # outline00 at the top (y = -0.5); the lowest of 19 points is at 0.5 cos(pi / 19)
    assert object_length("face", m.ids, xy) == pytest.approx([120 * (0.5 + 0.5 * math.cos(math.pi / 19))])
    # internal: brows (-0.21) to mouth (0.27)
    assert object_length("face", m.ids, xy, "internal") == pytest.approx([120 * 0.48])


@pytest.mark.parametrize("name", ["grid_pull", "face_occlusion"])
def test_truth_as_track_scores_zero(name):
    tr = scene_truth(name)
    es = tracking_error(tr, *as_track(tr))
    assert es.mean_pct == 0.0 and es.unmatched == 0 and es.missing == 0


@pytest.mark.parametrize("name", ["grid_pull", "grid_rot_y", "face_occlusion"])
def test_shift_by_3px_scores_3_over_length(name):
    tr = scene_truth(name)
    es = tracking_error(tr, *as_track(tr, dx=3.0))
    L = object_length(es.kind, tr.ids, tr.xy)
    assert np.allclose(es.pct, 300.0 / L)
    assert es.mean_pct == pytest.approx(np.mean(300.0 / L))


def test_face_scores_only_the_internal_parts():
    tr = scene_truth("face_occlusion")
    t, ids, x, y = as_track(tr)
    x = x.copy()
    outline = [k for k, p in enumerate(ids) if p not in FACE_INTERNAL]
    x[:, outline] += 50.0
    assert tracking_error(tr, t, ids, x, y).mean_pct == 0.0
    eye = ids.index("eye_l")
    x[:, eye] += 7.0
    es = tracking_error(tr, t, ids, x, y)
    assert np.allclose(es.pct, 100.0 * 7.0 / 7 / es.length)


@settings(max_examples=25, deadline=None)
@given(dx=st.floats(-20, 20), dy=st.floats(-20, 20))
def test_property_uniform_shift_gives_its_norm(dx, dy):
    tr = scene_truth("grid_inplane", 0, 20_000)
    es = tracking_error(tr, *as_track(tr, dx, dy))
    assert np.allclose(es.pct, 100.0 * math.hypot(dx, dy) / es.length)


def test_nearest_time_matching_ties_to_the_earlier_and_gaps_are_counted():
    truth_t = np.array([0, 1000, 2000], np.int64)
    assert match_times(truth_t, np.array([400, 500, 501, 1499, 1500, 1501, 2600])).tolist() == \
        [0, 0, 1, 1, 1, 2, 2]
    xy = np.zeros((3, 9, 2))
    xy[:, :, 0] = np.arange(3)[:, None] * 10 + np.arange(9) % 3 * 50
    xy[:, :, 1] = np.arange(9)[None, :] // 3 * 50
    tr = Truth(truth_t, [f"r{r}c{c}" for r in range(3) for c in range(3)], xy)
    t = np.array([1500, 1501, 5000])
    x = np.stack([xy[1, :, 0], xy[2, :, 0], xy[2, :, 0]])
    y = np.stack([xy[1, :, 1], xy[2, :, 1], xy[2, :, 1]])
    es = tracking_error(tr, t, tr.ids, x, y)
    assert es.pct.tolist() == [0.0, 0.0] and es.unmatched == 1


def test_missing_trackers_and_bad_files_are_named(tmp_path):
    tr = scene_truth("grid_pull", 0, 3000)
    t, ids, x, y = as_track(tr)
    with pytest.raises(ValueError, match="r1c1"):
        tracking_error(tr, t, [i if i != "r1c1" else "zz" for i in ids], x, y)
    bad = tmp_path / "bad.csv"
    bad.write_text("time,part,x,y\n0,a,1,2\n")
    with pytest.raises(ValueError, match="bad.csv"):
        read_truth_csv(bad)


def test_cli_simulate_then_score_truth_as_track(tmp_path, capsys):
    ev, tru, mod = tmp_path / "g.npy", tmp_path / "g.csv", tmp_path / "g.toml"
    assert main(["simulate", "grid_pull", "--out", str(ev), "--truth", str(tru),
                 "--model-out", str(mod), "--seconds", "0.2", "--seed", "3"]) == 0
    events = np.load(ev)
    assert len(events) > 1000 and np.all(np.diff(events["t"]) >= 0)
    assert mod.read_text().startswith('name = "grid3x3"')
    truth = read_truth_csv(tru)
    assert len(truth.t_us) == 200
    track = tmp_path / "track.csv"
    t, ids, x, y = as_track(truth, dy=-4.0)
    write_track(track, t[::10], ids, x[::10], y[::10])
    capsys.readouterr()
    assert main(["score", str(tru), str(track)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    L = object_length("grid", truth.ids, truth.xy[::10])
    assert last.startswith("mean_error_pct=")
    assert float(last.split("=")[1]) == pytest.approx(np.mean(400.0 / L), abs=1e-3)


def test_cli_rejects_unknown_event_suffix(tmp_path, capsys):
    rc = main(["simulate", "grid_pull", "--out", str(tmp_path / "e.txt"),
               "--truth", str(tmp_path / "t.csv"), "--seconds", "0.1"])
    assert rc == 2 and "e.txt" in capsys.readouterr().err


def test_tracker_follows_a_short_grid_pull_run():
    """End to end: simulated grid_pull (6 s, one pull of r0c2) tracked with the preset
    grid model; the paper's error must stay below a bound (paper best: 2.74 %)."""
    import springtrack
    from springtrack.sim.sensor import simulate_all
    sc = make_scene("grid_pull", seed=0)
    ev, tr = simulate_all(sc, 6.0, seed=0)
    truth = truth_from_array(tr)
    track = springtrack.Tracker(sc.initial_model()).run(ev, sample_us=1000)
    es = tracking_error(truth, track.t_us, track.ids, track.x, track.y)
    assert es.mean_pct < 2.5
    assert np.nanpercentile(es.pct, 90) < 5.0
    # the energy criteria (s = 4.5) must beat s so large they never act (paper Fig. 14)
    off = springtrack.Tracker(sc.initial_model(), params={"energy_scale": 1e6}).run(ev, 1000)
    es_off = tracking_error(truth, off.t_us, off.ids, off.x, off.y)
    assert es_off.mean_pct > es.mean_pct + 1.0


@pytest.mark.parametrize("suffix", [".raw", ".es"])
def test_cli_simulate_writes_camera_formats_that_read_back_identically(tmp_path, suffix):
    from springtrack.events import as_events
    from springtrack.io import open as open_events
    ref, out = tmp_path / "e.npy", tmp_path / f"e{suffix}"
    for path in (ref, out):
        assert main(["simulate", "grid_inplane", "--out", str(path), "--truth",
                     str(tmp_path / "t.csv"), "--seconds", "0.2", "--seed", "5"]) == 0
    a = np.load(ref)
    b = np.concatenate([as_events(c) for c in open_events(str(out))])
    assert len(a) > 1000 and np.array_equal(a, b)


def test_a_learned_model_is_named_after_the_parts_nearest_its_trackers():
    """named_after_parts: nearest pairs first, each part's id to one tracker; a tracker no
    part is left for keeps its id, and a part without a tracker stays unnamed."""
    from springtrack.metrics import named_after_parts
    from springtrack.model import ShapeModel, TrackerSpec, Connection
    truth = Truth(np.array([0, 1000]), ["a", "b", "c"],
                  np.array([[[10.0, 10.0], [50.0, 10.0], [90.0, 90.0]]] * 2))
    trackers = [TrackerSpec("p00", 11.0, 10.0, (4.0, 0.0, 4.0), 1.0),
                TrackerSpec("p01", 14.0, 10.0, (4.0, 0.0, 4.0), 1.0),
                TrackerSpec("p02", 49.0, 12.0, (4.0, 0.0, 4.0), 1.0)]
    m = ShapeModel("m", 100, 100, trackers, [Connection("p00", "p02", ("euclidean",), 0.01)], {})
    named, d = named_after_parts(m, truth, 1000)
    assert [t.id for t in named.trackers] == ["a", "p01", "b"]
    assert (named.connections[0].a, named.connections[0].b) == ("a", "b")
    assert d.shape == (3, 3) and abs(d[1, 0] - 4.0) < 1e-12
