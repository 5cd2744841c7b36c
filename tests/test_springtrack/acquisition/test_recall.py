"""Trackers left behind recalled to their place in the frame of the active ones
(springtrack.acquisition.recall), searches about the instance's tracked pose (springtrack.acquisition.recovery.about),
and the real biplane found, followed and turned with for the whole second."""
from __future__ import annotations

import math

import numpy as np
import pytest

from springtrack.commands.track import DOUBTFUL_EXIT

import springtrack
from springtrack.acquisition.acquire import Pose, fit_pose, model_pose, place
from springtrack.cli import main as cli
from springtrack.model import grid3x3
from springtrack.params import Params
from springtrack.acquisition.recovery import about
from springtrack.acquisition.recall import left_behind, recalled

GATE_D2 = Params().gate_d2
A_UP = Params().activity_threshold


def _snap(model, moved, active, stay):
    """The trackers of ``model`` at ``moved`` (a placed model), but those of ``stay``
    where the model has them; ``active`` flags."""
    a, m = model.arrays(), moved.arrays()
    snap = {k: m[k].copy() for k in ("x", "y", "sxx", "sxy", "syy")}
    for k in stay:
        for f in ("x", "y"):
            snap[f][k] = a[f][k]
    snap["active"] = np.asarray(active, bool)
    return snap


def _blob(x, y, n=30, seed=0):
    rng = np.random.default_rng(seed)
    return {"x": np.round(x + rng.normal(0, 2, n)), "y": np.round(y + rng.normal(0, 2, n))}


def _join(*evs):
    return {k: np.concatenate([e[k] for e in evs]) for k in ("x", "y")}


def test_the_trackers_left_behind_where_their_part_fires_are_recalled_there():
    model = grid3x3()
    p = model_pose(model)
    pose = Pose(p.tx + 40, p.ty - 10, 30.0, 1.0)
    moved = place(model, pose)
    mv = moved.arrays()
    active = np.ones(9, bool)
    active[[0, 1, 2]] = False
    snap = _snap(model, moved, active, stay=[0, 1, 2])
    # parts 0 and 1 fire where they moved to; part 2 is silent (occluded, or stopped)
    ev = _join(_blob(mv["x"][0], mv["y"][0]), _blob(mv["x"][1], mv["y"][1], seed=1))
    idx, placed = left_behind(model, snap, GATE_D2, lambda: ev, A_UP)
    assert sorted(idx.tolist()) == [0, 1]
    pa = placed.arrays()
    assert np.allclose(pa["x"], mv["x"], atol=1e-6) and np.allclose(pa["y"], mv["y"], atol=1e-6)
    out = recalled(model, snap, idx, placed).arrays()
    for k in range(9):              # 0, 1 at their place in the frame; the others as they were
        want = (mv["x"][k], mv["y"][k]) if k in (0, 1) else (snap["x"][k], snap["y"][k])
        assert (out["x"][k], out["y"][k]) == pytest.approx(want, abs=1e-9)


def test_nothing_is_recalled_without_a_frame_or_within_the_gate():
    model = grid3x3()
    p = model_pose(model)
    moved = place(model, Pose(p.tx + 40, p.ty, 0.0, 1.0))
    mv = moved.arrays()
    ev = _join(*(_blob(mv["x"][k], mv["y"][k], seed=k) for k in range(9)))
    # fewer than a third active (a jump, an exit): the loss rule decides, not the recall
    active = np.zeros(9, bool)
    active[:2] = True
    idx, placed = left_behind(model, _snap(model, moved, active, stay=range(2, 9)),
                              GATE_D2, lambda: ev, A_UP)
    assert len(idx) == 0 and placed is None
    # an inactive tracker still within its gate of its place stays where it is
    near = place(model, Pose(p.tx + 37, p.ty, 0.0, 1.0))      # 3 px from its place
    active = np.ones(9, bool)
    active[4] = False
    snap = _snap(model, moved, active, stay=[])
    snap["x"][4], snap["y"][4] = near.arrays()["x"][4], near.arrays()["y"][4]
    idx, _ = left_behind(model, snap, GATE_D2, lambda: ev, A_UP)
    assert len(idx) == 0


def test_a_pose_found_about_a_placement_is_a_pose_of_the_model():
    model = grid3x3()
    p = model_pose(model)
    base = Pose(p.tx + 20, p.ty + 5, 150.0, 0.8)
    rel = Pose(p.tx - 10, p.ty + 30, 60.0, 1.2)
    direct = place(place(model, base), rel).arrays()
    via = place(model, about(rel, base)).arrays()
    for k in ("x", "y", "sxx", "sxy", "syy"):
        assert np.allclose(direct[k], via[k], atol=1e-9), k
    assert -180.0 <= about(rel, base).angle_deg < 180.0


# ---- the real biplane --------------------------------------------------------------------
def _biplane(data_file):
    import springtrack.io as stio
    from springtrack.prep import prepare
    ev, _ = prepare(stio.open(data_file("dvs.es")).read(), 320, 240, start_us=1000,
                    dequantize=True)
    return ev


def _on_plane(ev, x, y, t_us):
    """The share of trackers with an event of the last 10 ms within 6 px."""
    last = ev[(ev["t"] >= t_us - 10_000) & (ev["t"] < t_us)]
    d = np.hypot(x[:, None] - last["x"][None].astype(float),
                 y[:, None] - last["y"][None].astype(float)).min(axis=1)
    return float(np.mean(d < 6.0))


def _plane_turn(ev, times):
    """The plane's own turn (degrees) at ``times`` since the first: the principal axis of
    its last 10 ms of events, unwrapped every 10 ms (an axis: known modulo 180 deg)."""
    axis, t_axis = [], range(times[0], times[-1] + 1, 10_000)
    for t in t_axis:
        w = ev[(ev["t"] >= t - 10_000) & (ev["t"] < t)]
        p = np.unique(np.column_stack([w["x"], w["y"]]).astype(float), axis=0)
        _, vec = np.linalg.eigh(np.cov(p.T))
        a = math.degrees(math.atan2(vec[1, 1], vec[0, 1])) % 180.0
        axis.append(a if not axis else axis[-1] + (a - axis[-1] + 90.0) % 180.0 - 90.0)
    return np.interp(times, list(t_axis), axis) - axis[0]


@pytest.mark.slow
def test_biplane_learned_is_found_followed_and_turned_with_for_the_whole_second(data_file, tmp_path):
    """Learned from 1-200 ms, then ``track --acquire`` from the start (default bounds):
    found at once, tracking at every 50 ms, its trackers on the plane (measured: 93-100 %),
    and the similarity fitted to them turns with the plane: measured 363 deg against the
    350 deg of the plane's principal axis, at most 36 deg from it."""
    es = str(data_file("dvs.es"))
    model = tmp_path / "plane.toml"
    assert cli(["learn", es, "--out", str(model), "--start-us", "1000", "--end-us", "200000",
                "--dequantize"]) == 0
    csv = tmp_path / "plane.csv"
    # found at the -45 deg bound of the default search: a doubtful find (exit 4), which
    # still holds the plane as measured below
    assert cli(["track", es, "--model", str(model), "--acquire", "--dequantize", "--out",
                str(csv), "--no-progress"]) == DOUBTFUL_EXIT
    from springtrack.track import read_csv
    track = read_csv(csv)
    ev = _biplane(data_file)
    m = springtrack.model.load(model)
    angles, times = [], list(range(50_000, 1_000_000, 50_000))
    for t_us in times:
        k = int(np.searchsorted(track.t_us, t_us))
        assert (track.state[k] == 1).all(), t_us                # tracking
        assert _on_plane(ev, track.x[k], track.y[k], t_us) >= 0.75, t_us
        angles.append(fit_pose(m, track.x[k], track.y[k]).angle_deg)
    turn = np.concatenate([[0.0], np.cumsum([(b - a + 180.0) % 360.0 - 180.0
                                             for a, b in zip(angles, angles[1:])])])
    plane = _plane_turn(ev, times)
    assert plane[-1] > 300.0                  # the plane turns nearly a full turn
    assert abs(turn[-1] - plane[-1]) < 45.0 and np.abs(turn - plane).max() < 90.0, (turn, plane)


def test_biplane_learned_then_tracked_with_acquire_stays_on_the_plane(data_file):
    """Learned from 1-200 ms, tracked from 200 ms with acquisition (default bounds): the
    trackers left behind are recalled (measured: 86-100 % on the plane, mean 98 %, against
    54 % from 600 ms on without the acquisition's driver)."""
    from springtrack.learning.learner import learn
    ev = _biplane(data_file)
    m = learn(ev[ev["t"] < 200_000], width=320, height=240)
    tr = springtrack.Tracker(m, acquire=True)
    track = tr.run(ev[ev["t"] >= 200_000], 1000)
    tr.flush()
    assert tr.counters["recalled"] > 0
    shares = []
    for t_us in range(300_000, 1_000_000, 50_000):
        k = int(np.searchsorted(track.t_us, t_us))
        shares.append(_on_plane(ev, track.x[k], track.y[k], t_us))
    assert min(shares) >= 0.5 and np.mean(shares) >= 0.85, shares
    assert not math.isnan(np.mean(shares))
