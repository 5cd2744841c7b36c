"""``springtrack simulate SCENE --out EVENTS --truth TRUTH.csv``: run the simulated ATIS
sensor (springtrack.sim.sensor) on a scene and write its events, ground truth and the
matching initial shape model."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

EVENT_SUFFIXES = (".npy", ".raw", ".es")


EPILOG = """\
scenes (springtrack/sim/scenes.py; paper section IV):
  grid_rot_y      3x3 grid rotating about the vertical axis, +-75 deg at 15 deg/s (Figs. 9-11)
  grid_pull       rotations about x and y, motion, disturbances, one element pulled away
                  and returned every 10 s; its truth is the unpulled position (Figs. 12-14)
  grid_inplane    in-plane rotation +-45 deg while translating (Fig. 16)
  grid_spin       in-plane rotation +-90 deg while translating
  grid_scale      the grid scaling 0.7 to 1.3 times while translating
  face_occlusion  face26 parts moving, scaling, rolling; a hand passes 3 times (Figs. 17-21)
  moving_blob     one blob moving right (sensor tests)
truth CSV: t_us,part,x,y every 1 ms; part = the tracker ids of the matching preset
(grid3x3 / face26); --model-out writes that preset placed at the scene's start.
"""


def add_arguments(p):
    from springtrack.sim.scenes import SCENES
    p.epilog = EPILOG
    p.add_argument("scene", choices=sorted(SCENES), help="scene name")
    p.add_argument("--out", required=True,
                   help="event file: .npy, .raw (EVT 2.0) or .es (Event Stream)")
    p.add_argument("--truth", required=True, help="ground-truth CSV (t_us,part,x,y every 1 ms)")
    p.add_argument("--model-out", help="write the initial shape model (TOML) here")
    p.add_argument("--seconds", type=float, help="duration (default: the scene's, e.g. 20 s)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--noise-rate", type=float, default=0.1,
                   help="background events per pixel per second (default 0.1)")
    p.add_argument("--hot-pixels", type=int, default=0, help="number of hot pixels (default 0)")
    p.add_argument("--chunk-ms", type=float, default=100.0,
                   help="simulation chunk length in ms (memory vs overhead; default 100)")


def _writer(path: Path):
    if path.suffix == ".npy":
        return lambda ev, w, h: np.save(path, ev)
    try:
        from springtrack.io import write
    except ImportError:
        raise ValueError(f"{path}: writing {path.suffix} needs springtrack.io.write, which this "
                         f"checkout does not have; use .npy") from None
    return lambda ev, w, h: write(str(path), ev, w, h)


def run(args) -> int:
    from springtrack.sim.scenes import make_scene
    from springtrack.sim.sensor import SensorConfig, simulate, write_truth_csv

    out = Path(args.out)
    if out.suffix not in EVENT_SUFFIXES:
        raise ValueError(f"{out}: unknown event file type {out.suffix!r}; "
                         f"use one of {', '.join(EVENT_SUFFIXES)}")
    write_events = _writer(out)
    cfg = SensorConfig(noise_rate_hz=args.noise_rate, hot_pixels=args.hot_pixels)
    scene = make_scene(args.scene, seed=args.seed)
    if args.model_out:
        scene.initial_model().save(args.model_out)
    stats, chunks, truth = {}, [], []
    t0 = time.perf_counter()
    for ev, tr in simulate(scene, args.seconds, args.seed, chunk_us=int(args.chunk_ms * 1000),
                           config=cfg, stats=stats):
        chunks.append(ev)
        truth.append(tr)
    wall = time.perf_counter() - t0
    events = np.concatenate(chunks) if chunks else np.zeros(0)
    write_events(events, cfg.width, cfg.height)
    rows = write_truth_csv(args.truth, truth)
    dur = (args.seconds if args.seconds else scene.default_seconds)
    print(f"{args.scene}: {len(events)} events in {dur:g} s ({len(events) / dur:.0f} ev/s; "
          f"signal {stats['signal_events']}, noise {stats['noise_events']}, hot {stats['hot_events']}, "
          f"refractory-suppressed {stats['refractory_suppressed']}), simulated in {wall:.2f} s "
          f"({dur / wall:.1f}x real time)", file=sys.stderr)
    print(f"wrote {out}, {args.truth} ({rows} rows)"
          + (f", {args.model_out}" if args.model_out else ""), file=sys.stderr)
    return 0
