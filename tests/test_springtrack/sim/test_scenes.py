"""Scenes of the simulated sensor (springtrack.sim.scenes): ids and initial models match the
presets, ground truth is exact, motions follow the paper's section IV description."""
import math

import numpy as np
import pytest

from springtrack.sim.scenes import SCENES, make_scene
from springtrack.sim.sensor import SensorConfig, simulate, simulate_all, truth_between, write_truth_csv
from springtrack.metrics import read_truth_csv
from springtrack.model import face26, grid3x3

PAPER_SCENES = ["grid_rot_y", "grid_pull", "grid_inplane", "face_occlusion"]
FRAME_SCENES = ["grid_spin", "grid_scale"]          # beyond the paper: the similarity frame


def test_registry_has_the_paper_scenes():
    assert set(PAPER_SCENES + FRAME_SCENES) <= set(SCENES)


@pytest.mark.parametrize("name", PAPER_SCENES + FRAME_SCENES)
def test_parts_and_initial_model_match_the_preset(name):
    sc = make_scene(name)
    preset = grid3x3() if sc.preset == "grid3x3" else face26()
    assert sc.part_ids == preset.ids
    m = sc.initial_model()
    xy0 = sc.truth(0.0)
    assert np.allclose([[t.x, t.y] for t in m.trackers], xy0, atol=1e-9)
    # at rest the rendered blobs sit on the truth, with the preset's covariance
    blobs = sc.frame(0.0).blobs
    assert np.allclose(blobs[:, :2], xy0, atol=1e-9)
    assert np.allclose(blobs[:, 2:5], [t.sigma for t in m.trackers], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("name", PAPER_SCENES + FRAME_SCENES)
def test_short_run_events_are_valid(name):
    ev, tr = simulate_all(name, 0.1, seed=2)
    assert len(ev) > 1000
    assert np.all(np.diff(ev["t"]) >= 0) and ev["t"].max() < 100_000
    assert ev["x"].max() < 304 and ev["y"].max() < 240
    assert len(tr) == 100 * len(make_scene(name).part_ids)


def test_grid_rot_y_sweeps_75_degrees_at_15_per_second():
    sc = make_scene("grid_rot_y")
    # at t = 5 s the screen is at 75 deg: row width 100 px * cos(75) (perspective aside)
    xy = sc.truth(5.0)
    width = xy[2, 0] - xy[0, 0]
    assert 0.8 * 100 * math.cos(math.radians(75)) < width < 1.4 * 100 * math.cos(math.radians(75))
    # at t = 15 s it is at -75 deg, at 10 s back at 0 deg (facing the camera)
    assert abs((sc.truth(10.0)[2, 0] - sc.truth(10.0)[0, 0]) - 100.0) < 1e-6
    assert sc.pose(15.0)[1] == pytest.approx(math.radians(-75.0))


def test_grid_pull_truth_is_the_unpulled_position():
    sc = make_scene("grid_pull")
    k = sc.part_ids.index(sc.PULLED)
    for t in (1.0, 2.5, 9.0):                         # not pulled
        assert np.allclose(sc.frame(t).blobs[:, :2], sc.truth(t))
    for t in (5.0, 15.5):                             # fully pulled, in two cycles
        d = sc.frame(t).blobs[:, :2] - sc.truth(t)
        assert np.linalg.norm(d[k]) == pytest.approx(sc.PULL_PX)
        assert np.allclose(np.delete(d, k, axis=0), 0.0)


def test_grid_inplane_rotates_within_45_degrees():
    sc = make_scene("grid_inplane")
    angles = []
    for t in np.arange(0, 13, 0.25):
        xy = sc.truth(t)
        d = xy[2] - xy[0]                                  # r0c0 -> r0c2
        angles.append(math.degrees(math.atan2(d[1], d[0])))
        assert np.hypot(*d) == pytest.approx(100.0)        # rigid in the image plane
    assert max(angles) == pytest.approx(45.0, abs=0.5) and min(angles) == pytest.approx(-45.0, abs=0.5)


def test_grid_spin_rotates_within_90_degrees():
    sc = make_scene("grid_spin")
    angles = []
    for t in np.arange(0, 25, 0.25):
        d = sc.truth(t)[2] - sc.truth(t)[0]                # r0c0 -> r0c2
        angles.append(math.degrees(math.atan2(d[1], d[0])))
        assert np.hypot(*d) == pytest.approx(100.0)
    assert max(angles) == pytest.approx(90.0, abs=0.5) and min(angles) == pytest.approx(-90.0, abs=0.5)
    assert sc.truth(6.0)[2, 1] - sc.truth(6.0)[0, 1] == pytest.approx(100.0)   # 90 deg at 6 s


def test_grid_scale_scales_by_30_percent_rigidly():
    sc = make_scene("grid_scale")
    sides = []
    for t in np.arange(0, 25, 0.25):
        xy = sc.truth(t)
        d = xy[2] - xy[0]
        assert d[1] == pytest.approx(0.0, abs=1e-9)        # no turn
        assert xy[8] - xy[6] == pytest.approx(d)           # no perspective: a similarity
        sides.append(d[0])
        blobs = sc.frame(t).blobs                          # blobs scale with the grid
        assert blobs[0, 2] == pytest.approx((sc.sigma * d[0] / 100.0) ** 2)
    assert max(sides) == pytest.approx(130.0, abs=0.5) and min(sides) == pytest.approx(70.0, abs=0.5)
    assert sides[0] == pytest.approx(100.0)


def test_face_hand_passes_three_times_in_20_s_and_crosses_the_face():
    sc = make_scene("face_occlusion")
    ts = np.arange(0, 20, 0.05)
    present = np.array([len(sc.frame(t).occluders) > 0 for t in ts])
    starts = np.flatnonzero(np.diff(present.astype(int)) == 1)
    assert len(starts) == 3
    # mid-pass the palm covers the face centre
    t_mid = sc.hand_first + sc.hand_duration / 2
    palm = sc.frame(t_mid).occluders[0]
    x, y, s, _ = sc.pose(t_mid)
    assert abs(palm[0] - x) < 0.3 * s


def test_face_moves_scales_and_rolls():
    sc = make_scene("face_occlusion")
    poses = np.array([sc.pose(t) for t in np.arange(0, 20, 0.1)])
    assert np.ptp(poses[:, 0]) > 40 and np.ptp(poses[:, 1]) > 20
    assert poses[:, 2].max() > 1.15 * 120                   # approaches the camera
    assert np.degrees(np.abs(poses[:, 3]).max()) == pytest.approx(12.0, abs=0.5)
    xy = sc.truth(3.0)                                      # parts move rigidly with the pose
    e_l, e_r = sc.part_ids.index("eye_l"), sc.part_ids.index("eye_r")
    assert np.hypot(*(xy[e_r] - xy[e_l])) == pytest.approx(0.32 * sc.pose(3.0)[2])


def test_face_event_rate_is_like_the_paper_recording():
    ev, _ = simulate_all("face_occlusion", 1.5, seed=0, config=SensorConfig())
    rate = len(ev) / 1.5
    assert 100_000 < rate < 600_000       # paper: ~300 k ev/s (20 s average here ~290 k)


def test_truth_csv_roundtrip(tmp_path):
    sc = make_scene("grid_pull")
    tr = truth_between(sc, 0, 5000)
    assert np.array_equal(np.unique(tr["t"]), [0, 1000, 2000, 3000, 4000])
    p = tmp_path / "truth.csv"
    assert write_truth_csv(p, [tr]) == 45
    assert p.read_text().splitlines()[0] == "t_us,part,x,y"
    back = read_truth_csv(p)
    assert back.ids == sc.part_ids
    assert np.allclose(back.xy[3], sc.truth(0.003), atol=1e-4)


def test_scene_seed_changes_only_the_random_parts():
    a, b = make_scene("grid_pull", seed=1), make_scene("grid_pull", seed=2)
    assert np.allclose(a.truth(0.0), b.truth(0.0))
    assert not np.allclose(a.truth(2.0), b.truth(2.0))
    assert np.allclose(a.truth(2.0), make_scene("grid_pull", seed=1).truth(2.0))
