"""The motion model (eqs. M1-M8, docs/motion.md) measured on every scene source:

* the real dot of evt2_sample.raw (truth: tests/support/dot_truth.py): a one-tracker model placed
  on the dot, and found by --acquire, with the motion model off (the paper) and on;
* fast disks on the simulated sensor with edge latency (tests/support/fast_parts.py), dark and
  bright, 1,000-30,000 px/s: the median error and the highest speed tracked within 2 px;
* the paper's scenes (springtrack.sim.scenes, seed 0, their default length) tracked by
  their preset models placed where they start, scored as ``springtrack score`` does: the
  error with the motion model off and on;
* the second generator's scenes (springtrack.sim.screen: grids, face, the dark and bright
  dots at 100-3,000 px/s on 100 Hz-3 kHz screens), initial models, default parameters;
* each part of the model alone (velocity, both edges, a slower filter) on the screen's
  dots and the real dot;
* the cost per event on every backend is benchmarks/motion_cost.py's.

Run: .venv/bin/python benchmarks/motion.py [--no-write] [--quick] [--screen-seconds S]
Writes the "Motion model" section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import springtrack                                        # noqa: E402
import springtrack.io                                     # noqa: E402
from springtrack.learning.motion import MOTION_OFF, MOTION_ON         # noqa: E402
from springtrack.metrics import match_times, score_track, truth_from_array   # noqa: E402
from springtrack.model import ShapeModel, TrackerSpec     # noqa: E402
from springtrack.sim.scenes import make_scene             # noqa: E402
from springtrack.sim.screen import ScreenConfig                          # noqa: E402
from springtrack.sim.screen import make_scene as screen_scene             # noqa: E402
from springtrack.sim.screen import simulate_all as screen_simulate        # noqa: E402
from springtrack.sim.sensor import simulate_all           # noqa: E402

from _report import machine, write_section                # noqa: E402
from support.dot_truth import dot_truth, track_errors             # noqa: E402
from support.fast_parts import errors, fast_disk                  # noqa: E402

MOTION, OFF = MOTION_ON, MOTION_OFF
# both edges without the velocity (eq. M6b)
EDGES = dict(OFF, polarity_gain=1.0)
# the columns of every table: the paper's step (the defaults), both edges, the whole model
COLUMNS = (OFF, EDGES, MOTION)
HEAD = "paper (motion off) | both edges (eq. M6b) | motion model"
SCENES = ("grid_rot_y", "grid_pull", "grid_inplane", "face_occlusion")
DATA = ROOT.parent / "shared" / "data" / "evt2_sample.raw"


def dot_rows():
    ev = springtrack.io.open(DATA).read()
    truth = dot_truth(ev)
    x, y = (float(v[0]) for v in truth.at([truth.t0]))
    m = ShapeModel("dot", 640, 480, [TrackerSpec("dot", round(x, 1), round(y, 1),
                                                 (36.0, 0.0, 36.0))], [])
    rows = []
    for acquire in (False, True):
        out = []
        for p in COLUMNS:
            tr = springtrack.Tracker(m, p, acquire=acquire).run(ev, sample_us=1000)
            e = track_errors(truth, tr.t_us, tr.x[:, 0], tr.y[:, 0])
            out.append(f"{np.median(e):.2f} px ({100 * np.mean(e <= 2):.0f} % within 2 px)")
        rows.append(f"| {'--acquire' if acquire else 'placed on the dot'} | " + " | ".join(out) + " |")
    head = (f"Truth: radius {truth.radius:.2f} px, {truth.turns_per_s:.2f} turns/s, "
            f"{truth.speed_px_s:,.0f} px/s, radial residual {truth.radial_rms:.2f} px RMS "
            f"({truth.windows} windows of 200 us).\n\n"
            f"| one-tracker model | {HEAD} |\n|---|---|---|---|\n")
    return head + "\n".join(rows)


def disk_rows(speeds):
    lines = ["| disk | " + " | ".join(f"{s:,} px/s" for s in speeds) + " |",
             "|---|" + "---|" * len(speeds)]
    for dark in (True, False):
        for name, p in (("paper", OFF), ("edges", EDGES), ("motion", MOTION)):
            cells = []
            for s in speeds:
                ev, scene, model = fast_disk(s, dark)
                e = np.median(errors(scene, springtrack.Tracker(model, p).run(ev, sample_us=200))[5:])
                cells.append(f"{e:.2f}")
            lines.append(f"| {'dark' if dark else 'bright'}, {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def scene_rows(seconds):
    lines = [f"| scene | events | {HEAD} |", "|---|---|---|---|---|"]
    face = None
    for name in SCENES:
        scene = make_scene(name, seed=0)
        ev, truth = simulate_all(scene, seconds=seconds, seed=0)
        model = scene.initial_model()
        t = truth_from_array(truth)
        out = []
        for p in COLUMNS:
            tr = springtrack.Tracker(model, p).run(ev, sample_us=10_000)
            out.append(f"{score_track(t, tr).mean_pct:.2f} %")
        lines.append(f"| {name} | {len(ev):,} | " + " | ".join(out) + " |")
        if name == "face_occlusion":
            face = (model, ev)
    return "\n".join(lines), face


# the second generator's scenes (springtrack.sim.screen): name, scene keywords, refresh Hz
SCREEN = (("grid_pull", {}, 100), ("grid_inplane", {}, 100), ("grid_rot_y", {}, 100),
          ("face_occlusion", {}, 100), ("dots", {}, 100),
          ("dots", dict(speed=800.0), 1000), ("dots", dict(speed=3000.0), 3000))


def screen_rows(seconds):
    """The screen generator's scenes with their initial models and the default parameters,
    motion model off and on: mean error (% of the object's length) and the median
    per-part error in px; the dots: the dark and the bright disc's median error in px
    (the model's ids are the truth's, in its order)."""
    lines = [f"| scene | events | {HEAD} |", "|---|---|---|---|---|"]
    for name, kw, hz in SCREEN:
        ev, truth = screen_simulate(name, seconds, 0, config=ScreenConfig(refresh_hz=hz), **kw)
        model = screen_scene(name, **kw).initial_model()
        t = truth_from_array(truth)
        out = []
        for p in COLUMNS:
            tr = springtrack.Tracker(model, p).run(ev, sample_us=1000)
            if name == "dots":          # no object length: the dark and the bright disc, px
                out.append(dots_error(t, tr) + " px")
            else:
                es = score_track(t, tr)
                out.append(f"{es.mean_pct:.2f} % ({np.nanmedian(es.err_px):.2f} px)")
        label = name + "".join(f", {k} {v:g} px/s" for k, v in kw.items()) + f", {hz} Hz"
        lines.append(f"| {label} | {len(ev):,} | " + " | ".join(out) + " |")
    return "\n".join(lines)


# each part of the model alone: (label, params); the real dot and the screen's dots
PARTS = (("off", OFF), ("tau_m 1000, c_h 1 (the model)", MOTION),
         ("tau_m 1000, c_h 0 (velocity only)", dict(OFF, motion_tau_us=1000.0)),
         ("tau_m 0, c_h 1 (both edges only, eq. M6b)", EDGES),
         ("tau_m 10000, c_h 1", dict(MOTION, motion_tau_us=10000.0)))
PART_DOTS = (("dots", {}, 100, 4.0), ("dots", dict(speed=3000.0), 3000, 2.0))


def dots_error(t, tr) -> str:
    """Median error of the dark and the bright disc, px."""
    j = match_times(t.t_us, tr.t_us)
    e = np.hypot(tr.x - t.xy[j, :, 0], tr.y - t.xy[j, :, 1])
    return " / ".join(f"{np.median(e[:, k]):.2f}" for k in range(2))


def parts_rows():
    """Median errors with each part of the model alone: the screen's dots (100 px/s on a
    100 Hz screen, 4 s; 3,000 px/s on a 3 kHz screen, 2 s; dark / bright disc) and the
    real dot (one tracker placed on it)."""
    ev = springtrack.io.open(DATA).read()
    truth = dot_truth(ev)
    x, y = (float(v[0]) for v in truth.at([truth.t0]))
    dot = ShapeModel("dot", 640, 480, [TrackerSpec("dot", round(x, 1), round(y, 1),
                                                   (36.0, 0.0, 36.0))], [])
    scenes = []
    for name, kw, hz, seconds in PART_DOTS:
        sev, st = screen_simulate(name, seconds, 0, config=ScreenConfig(refresh_hz=hz), **kw)
        scenes.append((screen_scene(name, **kw).initial_model(), sev, truth_from_array(st)))
    lines = ["| setting | screen dots, 100 Hz | screen dots, 3,000 px/s | real dot |",
             "|---|---|---|---|"]
    for label, p in PARTS:
        cells = [dots_error(t, springtrack.Tracker(m, p).run(sev, sample_us=1000)) + " px"
                 for m, sev, t in scenes]
        tr = springtrack.Tracker(dot, p).run(ev, sample_us=1000)
        cells.append(f"{np.median(track_errors(truth, tr.t_us, tr.x[:, 0], tr.y[:, 0])):.2f} px")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--quick", action="store_true", help="5 s scenes instead of their length")
    ap.add_argument("--screen-seconds", type=float, default=8.0,
                    help="length of the second generator's scenes in s (default 8: it "
                         "simulates 5-10x slower than real time)")
    a = ap.parse_args(argv)
    t0 = time.time()
    dot = dot_rows()
    disks = disk_rows([1000, 3000, 5000, 10000, 13000, 20000, 30000])
    scenes, _ = scene_rows(5.0 if a.quick else None)
    screen = screen_rows(a.screen_seconds)
    parts = parts_rows()
    flags = " --quick" if a.quick else ""
    body = (f"`.venv/bin/python benchmarks/motion.py{flags}` "
            f"({time.time() - t0:.0f} s), {machine()}.  Motion model on: "
            + ", ".join(f"{k} = {v:g}" for k, v in MOTION.items()) + "; both edges: "
            "motion_tau_us = 0, polarity_gain = 1 (eq. M6b); the paper (motion off, the "
            "defaults): both 0.\n\n"
            "### The real dot (evt2_sample.raw), median error\n\n" + dot + "\n\n"
            "### Fast disks on the simulated sensor (ON latency 40 us, OFF 20 us mean), "
            "median error, px\n\n" + disks + "\n\n"
            "### The paper's scenes (seed 0, models placed where they start), mean error, "
            "% of the object's length\n\n" + scenes + "\n\n"
            f"### The second generator's scenes (springtrack.sim.screen, {a.screen_seconds:g} s, "
            "seed 0, initial models, default parameters), mean error, % of the object's "
            "length (median per-part error)\n\n" + screen + "\n\n"
            "### Each part of the model alone, median error (dark / bright disc)\n\n"
            + parts + "\n\n"
            "The cost per event, float, fixed and Cortex-M: \"Motion model: cost per event\" "
            "(benchmarks/motion_cost.py).\n")
    print(body)
    if not a.no_write:
        write_section("Motion model", body)


if __name__ == "__main__":
    main()
