"""springtrack experiments: the loss-of-track criterion on a hand-made case, and the whole
pipeline (simulate, dask tasks, report with plots) on a tiny plan with an in-process
dask cluster."""
import math

import numpy as np
import pytest

from springtrack.sim.scenes import make_scene
from springtrack.sim.sensor import truth_between
from springtrack.commands.experiments import plan as xp
from springtrack.commands.experiments import report, runs
from springtrack.metrics import ErrorSeries, truth_from_array


def test_max_tracking_angle_is_the_angle_reached_before_the_first_loss():
    sc = make_scene("grid_rot_y")
    truth = truth_from_array(truth_between(sc, 0, 6_000_000)[::1])
    t = truth.t_us[::10]                                   # 10 ms samples
    err = np.zeros((len(t), 9))
    err[t >= 4_000_000, 4] = 30.0                          # r1c1 lost at t = 4 s
    es = ErrorSeries("grid", t, list(truth.ids), err, np.full(len(t), 100.0),
                     np.zeros(len(t)))
    # 15 deg/s from 0: the last sample before the loss is t = 3.99 s
    assert runs.max_tracking_angle(sc, truth, es) == pytest.approx(15.0 * 3.99, abs=1e-6)
    # a small error that stays below half the neighbour distance is not a loss
    err[:] = 0.0
    err[:, 0] = 5.0
    assert runs.max_tracking_angle(sc, truth, es) == pytest.approx(75.0)


def test_plan_covers_every_experiment():
    plan = xp.Plan.quick()
    cs = xp.cases(plan)
    by = {e: [c for c in cs if c["exp"] == e] for e in ("fig11b", "fig14", "table1", "fig16",
                                                          "face", "fig24")}
    assert len(by["fig11b"]) == len(plan.rot_alphas)
    assert len(by["fig14"]) == len(plan.s_values) and any(c["s"] >= 1e5 for c in by["fig14"])
    assert len(by["table1"]) == len(by["fig16"]) == 2 * len(plan.alphas) * len(plan.table_s)
    assert {c["model"]["springs"] for c in by["table1"]} == {("cartesian",), ("euclidean", "torsional")}
    assert len(by["face"]) == len(plan.face_s) * len(plan.face_seeds)
    # the frames' comparison: the sweeps of Figs. 14-16 once more in the other frame, and
    # every scene in both
    extra = cs
    other = [e for e in ("image", "similarity") if e != xp.default_frame()]
    for e in ("fig14", "table1", "fig16"):
        again = [c for c in extra if c["exp"] == f"{e}@{other[0]}"]
        assert len(again) == len(by[e]) and all(c["params"]["pull_frame"] == other[0]
                                                for c in again)
    scenes = [c for c in extra if c["exp"] == "scenes"]
    assert {c["scene"] for c in scenes} >= {"grid_rot_y", "grid_pull", "grid_inplane",
                                            "grid_spin", "grid_scale", "face_occlusion"}
    assert {c["frame"] for c in scenes} == {"image", "similarity"}


@pytest.mark.slow
def test_tiny_plan_end_to_end_with_dask(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    plan = xp.Plan(grid_seconds=1.0, face_seconds=1.0, rot_alphas=(0.004,), s_values=(4.5, 1e6),
                   alphas=(0.001,), table_s=(4.5, 1e6), face_s=(2.5,), spring_periods=(55,),
                   face_seeds=(0,), hand_sizes=(0.12,))
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2,
                            dashboard_address=None) as client:
        results = runs.run_all(plan, client)
    assert len(results) == len(xp.cases(plan)) + 2 * len(xp.hand_cases(plan))
    for r in results:
        assert math.isfinite(r["mean_pct"]) and r["wall_s"] > 0
    g = [r for r in results if r["exp"] == "fig14"]
    assert all(r["mean_pct"] < 5.0 for r in g)             # 1 s of grid_pull, before the pull
    out = report.write_report(results, plan, tmp_path, quick=True, elapsed=1.0, where="test")
    text = out.read_text()
    for title in ("Fig. 11b", "Fig. 13", "Fig. 14", "Table I", "Fig. 16", "Figs. 20-21",
                  "Fig. 24", "size of the hand", "Fig. 14 in both frames",
                  "Table I / Fig. 15 in both frames", "Fig. 16 in both frames",
                  "Every scene with the paper's per-experiment values"):
        assert title in text
    for scene in ("grid_spin", "grid_scale", "face_occlusion"):
        assert f"| {scene} |" in text
    for png in ("fig11b_max_angle", "fig13_pulled_element", "fig14_error_vs_s", "fig15_min_error", "fig16_inplane",
                "fig20_face_error", "fig21_face_energy", "fig24_spring_period", "fig14_frames",
                "fig15_frames", "fig16_frames"):
        assert (tmp_path / "img" / f"{png}.png").stat().st_size > 1000
