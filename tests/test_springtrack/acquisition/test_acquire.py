"""Acquisition (springtrack.acquisition.acquire): the pose of a model found in tens of ms of events of the
project's simulated sensor, from every start pose of the search range; noise alone is not
found; occluders, partial views and noise do not mislead it; `track --acquire` with a model
placed 20 deg / 15 % / 30 px off reaches the error of the model placed by hand."""
import math
import subprocess
import sys

import numpy as np
import pytest

from springtrack.acquisition.acquire import (Acquisition, Pose, acquire, fit_pose, model_pose, place,
                                             place_checked)
from springtrack.events import make
from springtrack.metrics import read_truth_csv, score_track
from springtrack.model import ShapeModel, TrackerSpec, face26, grid3x3, load
from springtrack.sim.scenes import Placed, make_scene
from springtrack.sim.sensor import SensorConfig, simulate_all
from springtrack.tracker import Tracker

WINDOW_S = 0.05
TOL_PX, TOL_DEG, TOL_SCALE = 2.0, 3.0, 0.03

# start poses across the default bounds (+-45 deg, 0.6-1.6x, the whole sensor), the
# object kept in view: rotations x scales, each with a shift taken in turn
ANGLES = (-45.0, -25.0, 0.0, 20.0, 44.0)
SCALES = (0.6, 0.8, 1.0, 1.25, 1.6)
SHIFTS = ((0, 0), (-60, 30), (70, -40), (-30, -35), (45, 40))
# the scenes: a static object (frozen, on a mount shaken by 1 px so that it fires) and a
# moving one (the scene's own motion: translation, scaling, rolling or in-plane rotation)
SCENES = {"face static": ("face_occlusion", dict(freeze=True, jitter_px=1.0)),
          "face moving": ("face_occlusion", {}),
          "grid static": ("grid_inplane", dict(freeze=True, jitter_px=1.0)),
          "grid moving": ("grid_inplane", {})}


def window(scene, t0=0.0, seconds=WINDOW_S, **config):
    """Events of [t0, t0 + seconds) and the object's true pose at the window's middle
    (relative to the model the base scene starts from)."""
    ev, _ = simulate_all(scene, t0 + seconds, config=SensorConfig(**config))
    ev = ev[ev["t"] >= int(t0 * 1e6)]
    model = scene.base.initial_model()
    xy = scene.truth(t0 + seconds / 2)
    return ev, model, fit_pose(model, xy[:, 0], xy[:, 1])


def pose_error(found: Pose, truth: Pose, symmetry_deg: float = 360.0):
    """(px, deg, relative scale) errors; angles compared modulo the model's symmetry."""
    da = (found.angle_deg - truth.angle_deg + symmetry_deg / 2) % symmetry_deg - symmetry_deg / 2
    return (math.hypot(found.tx - truth.tx, found.ty - truth.ty), abs(da),
            abs(found.scale / truth.scale - 1.0))


def symmetry(scene) -> float:
    # the 3x3 grid looks the same turned by 90 deg: +45 and -45 deg are one placement
    return 90.0 if scene.preset == "grid3x3" else 360.0


def check(pose, truth, sym=360.0):
    e_px, e_deg, e_scale = pose_error(pose, truth, sym)
    ok = pose.found and e_px <= TOL_PX and e_deg <= TOL_DEG and e_scale <= TOL_SCALE
    return ok, (f"found={pose.found} conf={pose.confidence:.2f} error {e_px:.2f} px "
                f"{e_deg:.2f} deg {100 * e_scale:.2f} %")


@pytest.mark.parametrize("name", list(SCENES))
def test_pose_recovered_from_every_start_pose_in_the_range(name):
    base, kw = SCENES[name]
    failures = []
    for i, angle in enumerate(ANGLES):
        for j, scale in enumerate(SCALES):
            dx, dy = SHIFTS[(i + j) % len(SHIFTS)] if scale <= 1.0 else (0, 0)
            scene = Placed(make_scene(base), angle, scale, dx, dy, **kw)
            ev, model, truth = window(scene)
            pose = acquire(model, ev)
            ok, msg = check(pose, truth, symmetry(scene))
            if not ok:
                failures.append(f"angle {angle} scale {scale} shift ({dx}, {dy}): {msg}")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("model", ["face26", "grid3x3"])
@pytest.mark.parametrize("noise_hz, hot, seconds",
                         [(0.1, 0, 0.02), (0.1, 30, 0.05), (1.0, 0, 0.05), (5.0, 100, 0.05),
                          (20.0, 0, 0.2)])
def test_noise_only_is_not_found(model, noise_hz, hot, seconds):
    # a static scene without a shaking mount: the sensor sees nothing but its own noise
    scene = Placed(make_scene("face_occlusion"), freeze=True)
    ev, _ = simulate_all(scene, seconds, config=SensorConfig(noise_rate_hz=noise_hz,
                                                              hot_pixels=hot, hot_rate_hz=500))
    assert len(ev) > 0
    pose = acquire(model, ev)
    assert not pose.found, pose


def test_too_few_events_is_not_found_and_no_events_is_no_error():
    assert not acquire("face26", make([], [], [], [])).found
    ev = make(np.arange(30), np.full(30, 40), np.full(30, 50), np.zeros(30))
    assert not acquire("grid3x3", ev).found


@pytest.mark.parametrize("row", [0.35, 0.2])
@pytest.mark.parametrize("into_pass", [0.6, 1.0, 1.4, 1.8])
def test_found_while_a_hand_passes_over_the_face(row, into_pass):
    # the hand (opaque, moving fast) covers the lower or the middle part of the face and
    # fires many events of its own; its pass starts at 0.3 s
    hand_first = 0.3
    scene = Placed(make_scene("face_occlusion", hand_first=hand_first, hand_rows=(row,)),
                   10.0, 1.0, 0, 0)
    ev, model, truth = window(scene, hand_first + into_pass)
    ok, msg = check(acquire(model, ev), truth)
    assert ok, msg


@pytest.mark.parametrize("base, shift", [("face_occlusion", (-120, 0)), ("face_occlusion", (0, 100)),
                                         ("grid_inplane", (130, 0)), ("grid_inplane", (0, -90))])
def test_found_partly_outside_the_sensor(base, shift):
    scene = Placed(make_scene(base), 0.0, 1.0, *shift)
    ev, model, truth = window(scene)
    pose = acquire(model, ev)
    ok, msg = check(pose, truth, symmetry(scene))
    assert ok, msg
    assert pose.in_view < len(model.trackers)


@pytest.mark.parametrize("base", ["face_occlusion", "grid_inplane"])
def test_found_in_a_noisy_sensor_with_hot_pixels(base):
    scene = Placed(make_scene(base, seed=3), -15.0, 0.9, 20, -10)
    ev, model, truth = window(scene, noise_rate_hz=5.0, hot_pixels=100, hot_rate_hz=1000.0)
    ok, msg = check(acquire(model, ev), truth, symmetry(scene))
    assert ok, msg


def test_bounds_are_honoured_and_checked():
    scene = Placed(make_scene("face_occlusion"), 30.0, 1.0, 40, 0)
    ev, model, truth = window(scene)
    # the object is at +30 deg: a search limited to +-10 deg stays within it
    pose = acquire(model, ev, angle_deg=(-10, 10))
    assert -10 <= pose.angle_deg <= 10
    # the region confines the centre of mass
    pose = acquire(model, ev, region=(0, 0, 120, 239))
    assert pose.tx <= 120
    assert check(acquire(model, ev, region=(150, 80, 250, 160)), truth)[0]
    for bad in (dict(angle_deg=(10, -10)), dict(scale=(0, 1)), dict(scale=(1.5, 1.2)),
                dict(region=(10, 10, 5, 20))):
        with pytest.raises(ValueError):
            acquire(model, ev, **bad)


def test_place_and_fit_pose_are_inverse():
    m = face26()
    pose = Pose(100.0, 90.0, -33.0, 1.3)
    placed = place(m, pose)
    assert placed.ids == m.ids and placed.connections == m.connections
    assert [t.mass for t in placed.trackers] == [t.mass for t in m.trackers]
    a = placed.arrays()
    back = fit_pose(m, a["x"], a["y"])
    assert back.tx == pytest.approx(100.0) and back.ty == pytest.approx(90.0)
    assert back.angle_deg == pytest.approx(-33.0) and back.scale == pytest.approx(1.3)
    # covariances turn and grow with the model: sqrt(det) scales by s^2
    a0 = m.arrays()
    det = lambda d: d["sxx"] * d["syy"] - d["sxy"] ** 2  # noqa: E731
    assert np.allclose(np.sqrt(det(a)), 1.3 ** 2 * np.sqrt(det(a0)))
    # spring rest lengths scale, angles turn
    assert np.allclose(a["l0"], 1.3 * a0["l0"])
    g = model_pose(m)
    assert (g.angle_deg, g.scale) == (0.0, 1.0)
    with pytest.raises(ValueError):
        fit_pose(m, a["x"][:5], a["y"][:5])
    with pytest.raises(ValueError):
        fit_pose(m, a["x"], a["y"], weights=np.zeros(len(a["x"])))


def test_one_part_has_a_translation_only_pose():
    """One tracker shows no turn or scale: its fitted pose is a translation (scale 1,
    angle 0), and placing the model there keeps its covariance."""
    m = ShapeModel("dot", 128, 128, [TrackerSpec("p00", 40.0, 50.0, (20.0, 3.0, 15.0), 1.0)],
                   [], {})
    pose = fit_pose(m, [70.0], [20.0])
    assert (pose.tx, pose.ty, pose.angle_deg, pose.scale) == (70.0, 20.0, 0.0, 1.0)
    assert place(m, pose).trackers[0].sigma == pytest.approx((20.0, 3.0, 15.0))


def test_a_pose_beyond_the_sensor_margin_is_not_placed():
    """A pose that puts a tracker beyond one sensor size around the sensor (which no
    model may hold) gives None, not an error that ends the run."""
    m = face26()
    assert place_checked(m, Pose(100.0, 90.0, 0.0, 1.0)) is not None
    assert place_checked(m, Pose(100.0, 2.2 * m.height, 0.0, 1.0)) is None


def test_placed_scene_moves_truth_and_initial_model_together():
    base = make_scene("grid_inplane")
    sc = Placed(base, 30.0, 1.2, 15, -10)
    xy = sc.truth(0.0)
    m = sc.initial_model()
    assert np.allclose([[t.x, t.y] for t in m.trackers], xy, atol=1e-9)
    # distances between parts grow by the scale
    b = base.truth(0.0)
    assert np.hypot(*(xy[0] - xy[8])) == pytest.approx(1.2 * np.hypot(*(b[0] - b[8])))
    assert np.allclose(sc.frame(0.0).blobs[:, :2], xy)


def test_stream_acquisition_in_small_chunks_slides_until_found():
    # 120 ms of sensor noise, then the face: the first windows find nothing and slide
    noise, _ = simulate_all(Placed(make_scene("face_occlusion"), freeze=True), 0.12,
                            config=SensorConfig(noise_rate_hz=1.0))
    face, _ = simulate_all(Placed(make_scene("face_occlusion"), 15.0, 0.9, 10, 0), 0.1)
    face["t"] += 120_000
    ev = np.concatenate([noise, face])
    acq = Acquisition(face26(), window_us=50_000)
    ready = None
    for s in range(0, len(ev), 997):
        ready = acq.feed(ev[s:s + 997])
        if ready is not None:
            break
    assert ready is not None and acq.done and acq.attempts >= 3
    assert acq.events_dropped > 0
    # what is handed back starts where the successful window started, and nothing
    # after it was lost
    assert ready["t"][0] >= 120_000 - 50_000
    assert ready["t"][-1] == ev["t"][s + len(ev[s:s + 997]) - 1]
    assert acq.events_dropped + len(ready) == s + len(ev[s:s + 997])


def test_tracker_api_acquires_then_tracks():
    scene = Placed(make_scene("face_occlusion"), -20.0, 0.85, 25, 10)
    ev, _ = simulate_all(scene, 0.6)

    def mean_error(track):
        xy = np.stack([scene.truth(t * 1e-6) for t in track.t_us])
        return float(np.mean(np.hypot(track.x - xy[..., 0], track.y - xy[..., 1])))

    tr = Tracker(face26(), acquire=True)              # as written: at the sensor centre
    tr.record(1000)
    for s in range(0, len(ev), 5000):                 # fed in chunks of any size
        tr.process(ev[s:s + 5000])
    tr.flush()
    track = tr.samples()
    assert tr.acquisition.done and tr.counters["acquire_attempts"] == 1
    assert tr.counters["events_valid"] == len(ev)
    assert track.t_us[0] == -(-int(ev["t"][0]) // 1000) * 1000   # from the first event
    by_hand = mean_error(Tracker(scene.initial_model()).run(ev, 1000))
    assert mean_error(track) <= 1.25 * by_hand
    # without acquire the model stays where it was written, far from the face
    assert mean_error(Tracker(face26()).run(ev, 1000)) > 5 * by_hand


def test_tracker_flush_acquires_on_a_short_input():
    scene = Placed(make_scene("grid_inplane"), 10.0, 1.1, -20, 15)
    ev, _ = simulate_all(scene, 0.03)                 # shorter than the 50 ms window
    tr = Tracker(grid3x3(), acquire=True)
    tr.process(ev)
    assert not tr.acquisition.done
    tr.flush()
    assert tr.acquisition.done
    assert tr.counters["events_valid"] == len(ev)


def _run(*args):
    r = subprocess.run([sys.executable, "-m", "springtrack.cli", *map(str, args)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.mark.slow
@pytest.mark.parametrize("scene, seconds", [("face_occlusion", 3.0), ("grid_pull", 3.0)])
def test_track_acquire_model_placed_off_reaches_the_error_placed_by_hand(tmp_path, scene,
                                                                       seconds):
    ev, truth, good = tmp_path / "ev.npy", tmp_path / "truth.csv", tmp_path / "good.toml"
    _run("simulate", scene, "--seconds", seconds, "--out", ev, "--truth", truth,
         "--model-out", good)
    m = load(good)
    g = model_pose(m)
    off = tmp_path / "off.toml"                       # 20 deg, 15 %, 30 px off
    place(m, Pose(g.tx + 24.0, g.ty + 18.0, 20.0, 1.15)).save(off)
    errors = {}
    for frame in ("image", "similarity"):
        prm = tmp_path / f"{frame}.toml"
        prm.write_text(f'pull_frame = "{frame}"\ncartesian_frame = "{frame}"\n')
        for name, model, extra in (("hand", good, []), ("off", off, []),
                                   ("acquire", off, ["--acquire"])):
            out = tmp_path / f"{name}.csv"
            stdout = _run("track", ev, "--model", model, "--out", out, "--params", prm, *extra)
            if extra:
                assert "acquisition: found" in stdout
            errors[frame, name] = score_track(read_truth_csv(truth), _read(out)).mean_pct
    # the paper's frame: placed off, it does not recover; acquired, as placed by hand
    assert errors["image", "off"] > 2 * errors["image", "hand"], errors
    assert errors["image", "acquire"] <= 1.25 * errors["image", "hand"], errors
    # the structure's own frame (the default) recovers more of a placement 20 deg, 15 % off
    # by itself and tracks the face better by hand (3 s of face_occlusion: 1.28 % against
    # 2.46 %); acquired, with the covariances measured at the placement (springtrack.acquisition.spread),
    # it tracks as placed by hand (1.28 %; with the model's covariances it settled on the
    # parts' near edges: 2.22 %)
    assert errors["similarity", "acquire"] <= 1.25 * errors["similarity", "hand"], errors
    assert errors["similarity", "off"] > errors["similarity", "hand"], errors


def _read(path):
    from springtrack.track import read_csv
    return read_csv(path)


def test_track_acquire_not_found_is_reported(tmp_path):
    ev, _ = simulate_all(Placed(make_scene("face_occlusion"), freeze=True), 0.2,
                         config=SensorConfig(noise_rate_hz=1.0))
    src = tmp_path / "noise.npy"
    np.save(src, ev)
    r = subprocess.run([sys.executable, "-m", "springtrack.cli", "track", str(src), "--model",
                        "face26", "--acquire", "--out", str(tmp_path / "t.csv")],
                       capture_output=True, text=True)
    assert r.returncode == 1
    assert "not found" in r.stderr and "acquisition: NOT found" in r.stdout
    r = subprocess.run([sys.executable, "-m", "springtrack.cli", "track", str(src), "--model",
                        "face26", "--acquire", "--acquire-scale", "2", "--out",
                        str(tmp_path / "t.csv")], capture_output=True, text=True)
    assert r.returncode == 2 and "--acquire-scale" in r.stderr
