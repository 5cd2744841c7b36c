"""What ``track --model`` measures before it switches the motion model on.

Run: .venv/bin/python benchmarks/motion_probe.py [--seeds 3] [--models DIR]

For each scene generator's four paper scenes (seeds 0..N-1, the scene's initial model),
the real dot of evt2_sample.raw with a one-tracker model placed on it (its truth from its
own events: tests/support/dot_truth.py), and optionally every ``NAME.toml`` in DIR (models
learned from the recordings of $SPRINGTRACK_DATA named NAME, their motion parameters
removed): the probe's figure (part sizes per ms, median over the trackers) placed
(the first 10 ms) and with --acquire (the 50 ms window and 10 ms).  docs/motion.md holds
the numbers; above motion_sigmas_per_ms = 1 the motion model is switched on
(springtrack.learning.motion).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

import springtrack.io
from springtrack.model import load_model
from springtrack.learning.motion import MOTION_ON, probe, probe_window_us
from springtrack.sim.generators import GENERATORS, generator

ROOT = Path(__file__).resolve().parent.parent
SCENES = ("grid_pull", "grid_inplane", "grid_rot_y", "face_occlusion")


def both(model, ev) -> str:
    out = []
    for acq in (False, True):
        sel = ev[ev["t"] < ev["t"][0] + probe_window_us(acq, 50.0)]
        p = probe(model, sel, acquire=acq)
        out.append(f"{p.sizes_per_ms:6.3f} ({p.parts:2d} trackers)")
    return "   ".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--models", help="a directory of NAME.toml models learned from NAME")
    a = ap.parse_args(argv)
    data = Path(os.environ.get("SPRINGTRACK_DATA", ROOT.parent / "shared" / "data"))
    print(f"{'source':40s} placed                 --acquire")
    for gname in GENERATORS:
        gen = generator(gname)
        for sname in SCENES:
            for seed in range(a.seeds):
                scene = gen.make_scene(sname, seed=seed)
                ev = np.concatenate([e for e, _ in gen.simulate(scene, 0.1, seed)])
                face = sname.startswith("face")
                model = scene.initial_model(**({} if face else dict(stiffness=0.001,
                                                                     springs=("cartesian",))))
                print(f"{gname + ' ' + sname + ' seed ' + str(seed):40s} {both(model, ev)}",
                      flush=True)
    dot = data / "evt2_sample.raw"
    if dot.exists():
        sys.path.insert(0, str(ROOT / "tests"))
        from support.dot_truth import dot_model_toml, dot_truth
        ev = springtrack.io.open(str(dot)).read()
        path = Path("/tmp/motion_probe_dot.toml")
        path.write_text(dot_model_toml(dot_truth(ev)))
        print(f"{'real dot, one tracker placed on it':40s} {both(load_model(str(path)), ev)}")
    for f in sorted(Path(a.models).glob("*.toml")) if a.models else []:
        m = load_model(str(f))
        for k in MOTION_ON:
            m.params.pop(k, None)
        ev = springtrack.io.open(str(data / f.stem)).read()
        print(f"{f.stem + ' (learned)':40s} {both(m, ev)}", flush=True)


if __name__ == "__main__":
    main()
