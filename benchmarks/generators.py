"""The tracker's defaults on both scene generators, in both frames of eq. (22).

Run: .venv/bin/python benchmarks/generators.py [--generator sensor screen] [--scene grid_pull ...]
     [--seconds S] [--seed N] [--backend cython] [--frame similarity] [--param NAME=VALUE ...]

For each generator (springtrack.sim.generators) and scene: simulate once, track with the
scene's initial model and the paper's per-experiment values (grids: Cartesian springs,
stiffness 0.001 and the grid3x3 preset's s = 4.5, alpha1 0.02, alpha2 5e-5; face: s = 2.5)
in the image and the similarity frame, and print the paper's error (% of the object
length) and, for grid_pull, the pulled part's mean / max distance (px) from where it
belongs while the pull is full.  docs/simulators.md holds the numbers.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from springtrack import Tracker
from springtrack.metrics import score_track, truth_from_array
from springtrack.params import from_mapping
from springtrack.sim.generators import GENERATORS, generator

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _params import parse_params  # noqa: E402

SCENES = ("grid_pull", "grid_inplane", "grid_rot_y", "face_occlusion")
FRAMES = ("image", "similarity")


def pulled_part(scene, es) -> str:
    """Mean / max distance of the pulled part's tracker from its truth while fully pulled."""
    if not hasattr(scene, "PULLED"):
        return ""
    full = np.array([scene.pull_amount(t * 1e-6) for t in es.t_us]) > 0.99
    e = es.err_px[full, es.parts.index(scene.PULLED)]
    return f"  pulled part {np.nanmean(e):.1f} / {np.nanmax(e):.1f} px"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--generator", nargs="+", default=list(GENERATORS), choices=list(GENERATORS))
    ap.add_argument("--scene", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--seconds", type=float, help="scene length in s (default: the scene's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--backend", default="cython")
    ap.add_argument("--frame", nargs="+", default=list(FRAMES), choices=FRAMES,
                    help="frames of eq. (22) to track in (default: both)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="a tracking parameter over the defaults and the paper's values "
                         "(springtrack.params names, e.g. polarity_gain=1)")
    a = ap.parse_args(argv)
    given = parse_params(a.param)
    extra = {k: from_mapping(given).as_dict()[k] for k in given}     # validated
    for gname in a.generator:
        gen = generator(gname)
        for sname in a.scene:
            scene = gen.make_scene(sname, seed=a.seed)
            ev, tr = zip(*gen.simulate(scene, a.seconds, a.seed))
            ev, truth = np.concatenate(ev), truth_from_array(np.concatenate(tr))
            face = sname.startswith("face")
            model = scene.initial_model(**({} if face else
                                           dict(stiffness=0.001, springs=("cartesian",))))
            for frame in a.frame:
                params = dict(pull_frame=frame, cartesian_frame=frame)
                if face:
                    params["energy_scale"] = 2.5
                params.update(extra)
                track = Tracker(model, params=params, backend=a.backend).run(ev, sample_us=1000)
                es = score_track(truth, track)
                print(f"{gname:7s} {sname:15s} {frame:10s} {es.mean_pct:6.2f} %"
                      f"{pulled_part(scene, es)}", flush=True)


if __name__ == "__main__":
    main()
