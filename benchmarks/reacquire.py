"""Loss and re-acquisition measured: the targets of docs/acquisition.md on the simulated
sensor (springtrack.sim), tracked through ``springtrack.Tracker(..., acquire=True)`` as
``springtrack track --acquire`` does, scored as ``springtrack score`` does (mean error over
the scored parts, % of the object's length).

Rows, each against the same model placed by hand (exactly where the scene starts) on the
same scene without the disruption:

* placed wrong: the model written 20 deg / 15 % / 30 px off its object (5 s scenes);
* jump: the face jumps 60 px at t = 3 s (5 s, hand passes from 4 s); error from the jump;
* occlusion: the face fully hidden for 300 ms from t = 3 s; error from its return;
* exit and return: the face leaves the sensor (0.1 s) at 2.5 s and comes back at 3 s;
* two objects side by side: a face and a grid (--model face --model grid, backend
  reference: several instances run there), each scored against its own truth.

Also: when each instance was lost and re-acquired, relative to the object's return.

Run: .venv/bin/python benchmarks/reacquire.py [--seconds S] [--no-write]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine, write_section  # noqa: E402

import springtrack  # noqa: E402
from springtrack.acquire import Pose, model_pose, place  # noqa: E402
from springtrack.metrics import tracking_error, truth_from_array  # noqa: E402
from springtrack.sim.scenes import Disrupted, Placed, Together, make_scene  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402

WRONG = dict(angle=20.0, scale=1.15, dx=30.0)


def placed_wrong(model):
    p = model_pose(model)
    return place(model, Pose(p.tx + WRONG["dx"], p.ty, p.angle_deg + WRONG["angle"],
                             p.scale * WRONG["scale"]))


def score(truth, track, parts=slice(None), ids=None, since_us=0):
    """Mean error (%) of ``track``'s trackers ``ids`` (default: as the truth's) at or
    after ``since_us``."""
    tr = truth_from_array(truth)
    pid = tr.ids[parts]
    xy = tr.xy[:, parts]
    from springtrack.metrics import Truth
    sub = Truth(tr.t_us, list(pid), xy)
    ids = ids or list(pid)
    cols = [track.ids.index(i) for i in ids]
    err = tracking_error(sub, track.t_us, list(pid), track.x[:, cols], track.y[:, cols])
    return float(np.nanmean(err.pct[err.t_us >= since_us]))


def run(scene, model, seconds, backend="cython", acquire=True, **kw):
    ev, truth = simulate_all(scene, seconds)
    c0 = time.process_time()
    tr = springtrack.Tracker(model, backend=backend, acquire=acquire, **kw)
    track = tr.run(ev, 1000)
    cpu = time.process_time() - c0
    return tr, track, truth, len(ev), cpu


def changes_text(tr, ret_us=None):
    out = []
    for t, label, kind in tr.changes:
        rel = "" if ret_us is None else f" ({(t - ret_us) / 1000:+.0f} ms)"
        out.append(f"{kind} {t / 1000:.0f} ms{rel}")
    return "; ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    S = args.seconds
    rows = []

    # placed wrong
    for name in ("face_occlusion", "grid_pull", "grid_rot_y", "grid_inplane"):
        sc = make_scene(name)
        m = sc.initial_model()
        _, hand, truth, n, _ = run(sc, m, S, acquire=False)
        e_hand = score(truth, hand)
        tr, tk, truth, n, cpu = run(sc, placed_wrong(m), S)
        e_acq = score(truth, tk)
        _, off, _, _, _ = run(sc, placed_wrong(m), S, acquire=False)
        e_off = score(truth, off)
        rows.append((f"{name}, model placed 20°/15 %/30 px off", e_hand, e_acq, 1.25,
                     f"without --acquire {e_off:.2f} %; {changes_text(tr)}"))
        print(rows[-1], flush=True)

    # jump, occlusion, exit and return (the face, hand passes from 4 s)
    base = make_scene("face_occlusion")
    m = base.initial_model()
    _, hand, truth0, _, _ = run(base, m, S, acquire=False)
    cases = [("jump of 60 px at 3 s", Disrupted(base, at_s=3.0, dx=60.0)),
             ("full occlusion 3.0-3.3 s", Disrupted(base, hide_s=(3.0, 3.3))),
             ("exit at 2.5 s, back at 3.0 s", Disrupted(base, at_s=2.5, dx=330.0, move_s=0.1,
                                                         back_s=2.9))]
    for what, sc in cases:
        ret = int(sc.returned() * 1e6)
        e_hand = score(truth0, hand, since_us=ret)
        tr, tk, truth, n, cpu = run(sc, m, S)
        e_acq = score(truth, tk, since_us=ret)
        _, nt, _, _, _ = run(sc, m, S, acquire=False)
        e_no = score(truth, nt, since_us=ret)
        rows.append((f"face, {what} (error from {ret / 1e6:g} s)", e_hand, e_acq, 1.5,
                     f"without --acquire {e_no:.2f} %; {changes_text(tr, ret)}"))
        print(rows[-1], flush=True)

    # two objects side by side: several instances run on the reference backend
    S2 = min(S, 2.0)
    face = Placed(make_scene("face_occlusion", hand_first=100.0, motion=0.5), 0.0, 0.6, -75, 0)
    grid = Placed(make_scene("grid_inplane"), 0.0, 0.6, 75, 0)
    both = Together(face, grid)
    mf, mg = face.initial_model(), grid.initial_model()
    for k, (sc, mm) in enumerate([(face, mf), (grid, mg)]):
        _, alone, truth, _, _ = run(sc, mm, S2, backend="reference", acquire=False)
        e_hand = score(truth, alone)
        if k == 0:
            tr, tk, truth2, n, cpu = run(both, [placed_wrong(mf), placed_wrong(mg)], S2,
                                         backend="reference")
        e_acq = score(truth2, tk, parts=both.parts[k])
        rows.append((f"two objects side by side ({S2:g} s): the {('face', 'grid')[k]}",
                     e_hand, e_acq, 1.5, changes_text(tr)))
        print(rows[-1], flush=True)

    lines = ["| scene | by hand % | --acquire % | ratio (target) | notes |", "|---|---:|---:|---|---|"]
    for what, h, a, target, note in rows:
        ok = "met" if a <= target * h else "**not met**"
        lines.append(f"| {what} | {h:.2f} | {a:.2f} | {a / h:.2f} (≤ {target:g}: {ok}) | {note} |")
    body = (f"Machine: {machine()}.  Command: `.venv/bin/python benchmarks/reacquire.py "
            f"--seconds {S:g}`.\n\n" + "\n".join(lines))
    print(body)
    if not args.no_write:
        write_section("Loss and re-acquisition (measured targets)", body)


if __name__ == "__main__":
    main()
