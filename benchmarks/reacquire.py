"""Loss and re-acquisition measured: the targets of docs/acquisition.md on the simulated
sensor (springtrack.sim), tracked through ``springtrack.Tracker(..., acquire=True)`` as
``springtrack track --acquire`` does, scored as ``springtrack score`` does (mean error over
the scored parts, % of the object's length).

Rows, each against the same model placed by hand on the same scene without the
disruption: exactly where the scene starts, and (a steadier reference) 0.1 px or 0.1 deg
off it (the mean of four such placements; the face of face_occlusion ends at about
1.3 % or 3.7 % depending on such a nudge):

* placed wrong: the model written 20 deg / 15 % / 30 px off its object (5 s scenes);
* jump: the face jumps 60 px at t = 3 s (5 s, hand passes from 4 s); error from the jump;
* occlusion: the face fully hidden for 300 ms from t = 3 s; error from its return;
* exit and return: the face leaves the sensor (0.1 s) at 2.5 s and comes back at 3 s;
* two objects side by side: a face and a grid (--model face --model grid, the float
  kernel holding both), each scored against its own truth.

Placed by hand with the model's covariances the face is bistable (a 0.1 px nudge moves it
between about 1.3 % and 3.7 %; --acquire starts from covariances measured on the window,
springtrack.acquisition.spread, docs/acquisition.md "Placement"): its rows are means over ``--seeds``
scene seeds (the scene's texture, noise and hand), each against the same seed placed by
hand.  Also: when each instance was lost and
re-acquired, relative to the object's return, and the losses on the scenes without any
disruption (placed wrong), which must be 0.

Run: .venv/bin/python benchmarks/reacquire.py [--seconds S] [--seeds N] [--no-write]
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
from springtrack.acquisition.acquire import Pose, model_pose, place  # noqa: E402
from springtrack.metrics import tracking_error, truth_from_array  # noqa: E402
from springtrack.sim.scenes import Disrupted, Placed, Together, make_scene  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402

WRONG = dict(angle=20.0, scale=1.15, dx=30.0)


def placed_wrong(model):
    p = model_pose(model)
    return place(model, Pose(p.tx + WRONG["dx"], p.ty, p.angle_deg + WRONG["angle"],
                             p.scale * WRONG["scale"]))


NUDGES = [(0.1, 0.0, 0.0), (-0.1, 0.0, 0.0), (0.0, 0.0, 0.1), (0.0, 0.0, -0.1)]


def nudged(model, dx, dy, da):
    p = model_pose(model)
    return place(model, Pose(p.tx + dx, p.ty + dy, p.angle_deg + da, p.scale))


def by_hand(scene, model, seconds, since_us=0, parts=slice(None), backend="cython"):
    """(exact, mean of the nudged) errors of ``model`` placed by hand."""
    _, tk, truth, _, _ = run(scene, model, seconds, backend=backend, acquire=False)
    exact = score(truth, tk, parts, since_us=since_us)
    nudges = []
    for d in NUDGES:
        _, tk, truth, _, _ = run(scene, nudged(model, *d), seconds, backend=backend, acquire=False)
        nudges.append(score(truth, tk, parts, since_us=since_us))
    return exact, float(np.mean(nudges))


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


def changes_text(tr, ret_us=None, labels=False):
    out = []
    for t, label, kind in tr.changes:
        rel = "" if ret_us is None else f" ({(t - ret_us) / 1000:+.0f} ms)"
        out.append(f"{label + ' ' if labels else ''}{kind} {t / 1000:.0f} ms{rel}")
    return "; ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--seeds", type=int, default=3, help="face scenes: seeds averaged")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    S = args.seconds
    rows = []
    false_losses = 0

    # placed wrong
    for name in ("face_occlusion", "grid_pull", "grid_rot_y", "grid_inplane"):
        seeds = range(args.seeds) if name == "face_occlusion" else [0]
        hand, acq, off, notes = [], [], [], []
        for seed in seeds:
            sc = make_scene(name, seed=seed)
            m = sc.initial_model()
            hand.append(by_hand(sc, m, S))
            tr, tk, truth, n, cpu = run(sc, placed_wrong(m), S)
            acq.append(score(truth, tk))
            _, tk_off, _, _, _ = run(sc, placed_wrong(m), S, acquire=False)
            off.append(score(truth, tk_off))
            false_losses += tr.counters["lost"]
            notes.append(f"seed {seed}: {acq[-1]:.2f} % ({changes_text(tr)}; "
                         f"{tr.counters['losses_refuted']} refuted)")
        rows.append((f"{name}, model placed 20°/15 %/30 px off"
                     + (f", mean of {len(seeds)} seeds" if len(seeds) > 1 else ""),
                     tuple(np.mean(hand, axis=0)), float(np.mean(acq)), 1.25,
                     f"without --acquire {np.mean(off):.2f} %; " + "; ".join(notes)))
        print(rows[-1], flush=True)

    # jump, occlusion, exit and return (the face, hand passes from 4 s)
    def cases(base):
        return [("jump of 60 px at 3 s", Disrupted(base, at_s=3.0, dx=60.0)),
                ("full occlusion 3.0-3.3 s", Disrupted(base, hide_s=(3.0, 3.3))),
                ("exit at 2.5 s, back at 3.0 s", Disrupted(base, at_s=2.5, dx=330.0,
                                                            move_s=0.1, back_s=2.9))]
    for k, what in enumerate(w for w, _ in cases(make_scene("face_occlusion"))):
        hand, acq, no, notes = [], [], [], []
        for seed in range(args.seeds):
            base = make_scene("face_occlusion", seed=seed)
            m = base.initial_model()
            sc = cases(base)[k][1]
            ret = int(sc.returned() * 1e6)
            hand.append(by_hand(base, m, S, since_us=ret))
            tr, tk, truth, n, cpu = run(sc, m, S)
            acq.append(score(truth, tk, since_us=ret))
            _, nt, _, _, _ = run(sc, m, S, acquire=False)
            no.append(score(truth, nt, since_us=ret))
            notes.append(f"seed {seed}: {acq[-1]:.2f} % ({changes_text(tr, ret)})")
        rows.append((f"face, {what} (error from {ret / 1e6:g} s), mean of {args.seeds} seeds",
                     tuple(np.mean(hand, axis=0)), float(np.mean(acq)), 1.5,
                     f"without --acquire {np.mean(no):.2f} %; " + "; ".join(notes)))
        print(rows[-1], flush=True)

    # two objects side by side: one tracker holding both (the float kernel)
    S2 = min(S, 2.0)
    face = Placed(make_scene("face_occlusion", hand_first=100.0, motion=0.5), 0.0, 0.6, -75, 0)
    grid = Placed(make_scene("grid_inplane"), 0.0, 0.6, 75, 0)
    both = Together(face, grid)
    mf, mg = face.initial_model(), grid.initial_model()
    for k, (sc, mm) in enumerate([(face, mf), (grid, mg)]):
        e_hand = by_hand(sc, mm, S2)
        if k == 0:
            tr, tk, truth2, n, cpu = run(both, [placed_wrong(mf), placed_wrong(mg)], S2)
        e_acq = score(truth2, tk, parts=both.parts[k])
        rows.append((f"two objects side by side ({S2:g} s): the {('face', 'grid')[k]}",
                     e_hand, e_acq, 1.5, changes_text(tr, labels=True)))
        print(rows[-1], flush=True)

    # jumps of other sizes and directions, other scenes (seed 1, jump at 2 s)
    S3 = min(S, 4.0)
    jumps = []
    for name, kw in [("face_occlusion", dict(dy=60.0)), ("face_occlusion", dict(dx=-40.0)),
                     ("face_occlusion", dict(dx=150.0)), ("face_occlusion", dict(dx=-80.0, dy=-50.0)),
                     ("grid_inplane", dict(dx=80.0)), ("grid_pull", dict(dx=-60.0)),
                     ("grid_rot_y", dict(dy=40.0))]:
        base = make_scene(name, seed=1)
        sc = Disrupted(base, at_s=2.0, **kw)
        tr, tk, truth, n, cpu = run(sc, base.initial_model(), S3)
        jumps.append(f"| {name}, jump {kw} | {score(truth, tk, since_us=2_000_000):.2f} | "
                     f"{changes_text(tr, 2_000_000)} | {tr.counters['verifications']} |")
        print(jumps[-1], flush=True)

    lines = ["| scene | by hand: exact / nudged % | --acquire % | ratio to exact, nudged "
             "(target) | notes |", "|---|---:|---:|---|---|"]
    for what, (h, hn), a, target, note in rows:
        ok = ["met" if a <= target * v else "**not met**" for v in (h, hn)]
        lines.append(f"| {what} | {h:.2f} / {hn:.2f} | {a:.2f} | {a / h:.2f} ({ok[0]}), "
                     f"{a / hn:.2f} ({ok[1]}) (≤ {target:g}) | {note} |")
    body = (f"Machine: {machine()}.  Command: `.venv/bin/python benchmarks/reacquire.py "
            f"--seconds {S:g} --seeds {args.seeds}`.\n\n" + "\n".join(lines)
            + f"\n\nLosses on the scenes placed wrong (no disruption): {false_losses}.\n\n"
            f"Jumps at 2 s ({S3:g} s scenes, seed 1; error from the jump, changes relative "
            "to it):\n\n| scene | --acquire % | changes | verifications |\n|---|---:|---|---:|\n"
            + "\n".join(jumps))
    print(body)
    if not args.no_write:
        write_section("Loss and re-acquisition (measured targets)", body)


if __name__ == "__main__":
    main()
