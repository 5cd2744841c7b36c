"""Learned models against the hand-made ones, on both scene generators.

Run: .venv/bin/python benchmarks/learned_models.py [--seeds 3] [--scenes grid_pull,face_occlusion]
                                                   [--generators sensor,screen]
                                                   [--learn-param NAME=VALUE ...]

For each generator's scene and seed (the whole scene, its generator's default length): a
model learned with the defaults (plus ``--learn-param``) from the first second
(grid_pull) or 0.8 s (face_occlusion), its trackers named after their nearest true parts
(nearest pairs first), tracks the rest of the scene (``Tracker(model).run(rest, 1000)``);
the scene's hand-made model tracks the whole scene, scored over the same span.  Prints
the trackers, the parts with a tracker nearest to them, the farthest tracker from its
part at the window's end, and both errors (springtrack.metrics, % of the object's length;
"missing" when a part has no tracker to score).  docs/learning.md holds the numbers.
"""
from __future__ import annotations

import argparse
import numpy as np

from springtrack import Tracker
from springtrack.learning.learner import learn_model
from springtrack.learning.settings import LearnParams, parse_assignments
from springtrack.metrics import named_after_parts, score_track, truth_from_array
from springtrack.sim import screen, sensor
from springtrack.sim.scenes import make_scene

WINDOW_US = {"grid_pull": 1_000_000, "face_occlusion": 800_000}


def scene(gen: str, name: str, seed: int):
    """(events, truth, hand-made model) of one whole scene."""
    if gen == "screen":
        ev, tr = screen.simulate_all(name, seed=seed)
        hand = screen.make_scene(name).initial_model()
    else:
        ev, tr = sensor.simulate_all(name, make_scene(name).default_seconds, seed=seed)
        hand = make_scene(name).initial_model()
    return ev, truth_from_array(tr), hand


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--scenes", default="grid_pull,face_occlusion")
    ap.add_argument("--generators", default="sensor,screen")
    ap.add_argument("--learn-param", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args()
    lp = LearnParams(**parse_assignments(a.learn_param))
    print("| generator | scene | seed | trackers | parts with a tracker | farthest (px) "
          "| learned model | hand-made model |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for gen in a.generators.split(","):
        for name in a.scenes.split(","):
            window = WINDOW_US[name]
            for seed in range(a.seeds):
                ev, truth, hand = scene(gen, name, seed)
                model, d = named_after_parts(learn_model(ev[ev["t"] < window], width=304, height=240,
                                             params=lp).model, truth, window)
                try:
                    ours = "%.2f %%" % score_track(
                        truth, Tracker(model).run(ev[ev["t"] >= window], 1000)).mean_pct
                except ValueError:
                    ours = "missing"
                h = score_track(truth, Tracker(hand).run(ev, 1000))
                hp = float(np.nanmean(h.pct[h.t_us >= window]))
                print(f"| {gen} | {name} | {seed} | {len(model.trackers)} | "
                      f"{len(set(d.argmin(axis=1).tolist()))} of {len(truth.ids)} | "
                      f"{d.min(axis=1).max():.1f} | {ours} | {hp:.2f} % |", flush=True)


if __name__ == "__main__":
    main()
