"""Running the experiments: scenes simulated once in the driver, every case a dask task.

:func:`run_case` is one tracker run on a worker; :func:`run_all` simulates the scenes,
scatters them to the workers, submits every case of the plan and prints progress as
tasks complete.
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np

from .plan import PAPER, S_OFF, Plan, cases, hand_cases


def run_case(events, truth, case: dict) -> dict:
    """Track ``events`` with the case's model and params; score against ``truth``."""
    from springtrack.sim.scenes import make_scene
    from springtrack import Tracker
    from springtrack.metrics import score_track

    scene = make_scene(case["scene"], seed=case["seed"], **case.get("scene_params", {}))
    model = scene.initial_model(**case.get("model", {}))
    tracker = Tracker(model, params=case.get("params") or None)
    t0 = time.perf_counter()
    track = tracker.run(events, sample_us=1000)
    wall = time.perf_counter() - t0
    es = score_track(truth, track)
    out = dict(case, mean_pct=es.mean_pct, wall_s=wall, n_events=len(events),
               duration_s=(int(events["t"][-1]) - int(events["t"][0])) / 1e6 if len(events) else 0.0)
    if case.get("series"):
        out.update(t_us=es.t_us, pct=es.pct, energy=track.energy)
    if case.get("trace"):                   # Fig. 13: the pulled element's tracker
        k = track.ids.index(scene.PULLED)
        out["trace"] = dict(t_us=track.t_us, x=track.x[:, k], y=track.y[:, k],
                            sensitive=track.sensitive[:, k], active=track.active[:, k])
    if case.get("angle"):
        out["max_angle_deg"] = max_tracking_angle(scene, truth, es)
    return out


def simulate_and_run(case: dict, s_values) -> list[dict]:
    """Simulate the case's scene (with its scene_params) on the worker, then track it once
    per s in ``s_values``."""
    from springtrack.sim.scenes import make_scene
    from springtrack.sim.sensor import simulate_all
    from springtrack.metrics import truth_from_array

    scene = make_scene(case["scene"], seed=case["seed"], **case.get("scene_params", {}))
    ev, tr = simulate_all(scene, case["seconds"], seed=case["seed"])
    truth = truth_from_array(tr)
    return [run_case(ev, truth, dict(case, s=s, params=dict(case.get("params", {}),
                                                             energy_scale=s)))
            for s in s_values]


def max_tracking_angle(scene, truth, es) -> float:
    """Largest |rotation about y| reached before the first loss of track on grid_rot_y.

    Lost = some tracker farther from its element than half the current distance between
    horizontally neighbouring elements (it can no longer be told from its neighbour's).
    """
    xy = truth.xy[np.searchsorted(truth.t_us, es.t_us).clip(0, len(truth.t_us) - 1)]
    neighbour = np.hypot(*(xy[:, 1] - xy[:, 0]).T)            # r0c0 -> r0c1
    lost = (es.err_px > 0.5 * neighbour[:, None]).any(axis=1)
    end = int(np.argmax(lost)) if lost.any() else len(lost)
    if end == 0:
        return 0.0
    return max(abs(math.degrees(scene.pose(t / 1e6)[1])) for t in es.t_us[:end])


def simulate_scenes(plan: Plan, keys) -> dict:
    """(scene, seed) -> (events, Truth), simulated in this process."""
    from springtrack.sim.sensor import simulate_all
    from springtrack.metrics import truth_from_array
    data = {}
    for name, seed in keys:
        secs = plan.face_seconds if name.startswith("face") else plan.grid_seconds
        t0 = time.perf_counter()
        ev, tr = simulate_all(name, secs, seed=seed)
        print(f"simulated {name} (seed {seed}): {secs:g} s, {len(ev)} events "
              f"({len(ev) / secs:.0f} ev/s) in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        data[name, seed] = (ev, truth_from_array(tr))
        plan.scenes[name, seed] = (secs, len(ev), time.perf_counter() - t0)
    return data


def run_all(plan: Plan, client) -> list[dict]:
    """Every case of ``plan`` on the dask ``client``: the result dicts of :func:`run_case`."""
    from dask.distributed import as_completed
    todo = cases(plan)
    data = simulate_scenes(plan, sorted({(c["scene"], c["seed"]) for c in todo}))
    shared = {key: (client.scatter(ev, broadcast=True), client.scatter(tr, broadcast=True))
              for key, (ev, tr) in data.items()}
    futures = [client.submit(run_case, *shared[c["scene"], c["seed"]], c, pure=False)
               for c in todo]
    futures += [client.submit(simulate_and_run, c, (PAPER["face_s"], S_OFF), pure=False)
                for c in hand_cases(plan)]
    results, t0, n = [], time.perf_counter(), len(futures)
    tty = sys.stderr.isatty()
    for k, fut in enumerate(as_completed(futures), 1):
        got = fut.result()
        results.extend(got if isinstance(got, list) else [got])
        r = results[-1]
        if tty or k == n or k % max(1, n // 20) == 0:       # a line per 5 % when not a tty
            print(f"{chr(13) if tty else ''}[{k}/{n}] {time.perf_counter() - t0:6.1f} s  "
                  f"{r['exp']:<7} {r['scene']:<15} error {r['mean_pct']:7.2f} %",
                  end="" if tty else "\n", file=sys.stderr)
    if tty:
        print(file=sys.stderr)
    return results
