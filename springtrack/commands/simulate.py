"""``springtrack simulate SCENE --out EVENTS --truth TRUTH.csv``: run a scene generator
(springtrack.sim.generators: the simulated ATIS sensor by default, or the independent
screen generator) on a scene and write its events, ground truth and the matching initial
shape model."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

EVENT_SUFFIXES = (".npy", ".raw", ".es")


EPILOG = """\
--generator sensor (default; springtrack/sim/scenes.py, paper section IV):
  grid_rot_y      3x3 grid rotating about the vertical axis, +-75 deg at 15 deg/s (Figs. 9-11)
  grid_pull       rotations about x and y, motion, disturbances, one element pulled away
                  and returned every 10 s; its truth is the unpulled position (Figs. 12-14)
  grid_inplane    in-plane rotation +-45 deg while translating (Fig. 16)
  grid_spin       in-plane rotation +-90 deg while translating
  grid_scale      the grid scaling 0.7 to 1.3 times while translating
  face_occlusion  face26 parts moving, scaling, rolling; a hand passes 3 times (Figs. 17-21)
  moving_blob     one blob moving right (sensor tests)
--generator screen (springtrack/sim/screen: a 100 Hz screen, its own pixel model):
  grid_pull       3x3 dark discs (spacing 45 px, radius 10 px) turning about x and y,
                  drifting with ~1.5 px jitter; r1c2 pulled 1.5 spacings along the grid's
                  X axis every 8 s (out 1.5 s, held 2 s, back 1.5 s); truth unpulled
  grid_inplane    in-plane rotation +-45 deg at 15 deg/s while drifting
  grid_rot_y      rotation about the vertical axis +-60 deg at 15 deg/s
  face_occlusion  a bright face with dark features before a dark wall; a hand passes 3 times
  dots            a dark and a bright disc back and forth at --speed px/s (--radius px)
  shapes_handheld eight dark shapes on a wall filmed by a hand-held camera moving at
                  --speed px/s RMS (default 150; use --refresh-hz 1000)
truth CSV: t_us,part,x,y every 1 ms; part = the tracker ids of the matching preset
(grid3x3 / face26); --model-out writes that preset placed at the scene's start.
"""


def add_arguments(p):
    from springtrack.sim.generators import DEFAULT, GENERATORS, generator
    p.epilog = EPILOG
    names = sorted({n for g in GENERATORS for n in generator(g).scenes})
    p.add_argument("scene", choices=names, help="scene name (of the chosen --generator)")
    p.add_argument("--generator", choices=sorted(GENERATORS), default=DEFAULT,
                   help=f"scene generator (default {DEFAULT}; see below)")
    p.add_argument("--out", required=True,
                   help="event file: .npy, .raw (EVT 2.0) or .es (Event Stream)")
    p.add_argument("--truth", required=True, help="ground-truth CSV (t_us,part,x,y every 1 ms)")
    p.add_argument("--model-out", help="write the initial shape model (TOML) here")
    p.add_argument("--seconds", type=float, help="duration (default: the scene's, e.g. 20 s)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--noise-rate", type=float,
                   help="background events per pixel per second (default: the generator's, "
                        "sensor 0.1, screen 0.2)")
    p.add_argument("--refresh-hz", type=float,
                   help="screen refresh rate in Hz, --generator screen only (default 100)")
    p.add_argument("--speed", type=float,
                   help="dots: speed of the discs in px/s (default 100); shapes_handheld: "
                        "RMS speed of the camera's image motion in px/s (default 150)")
    p.add_argument("--radius", type=float, help="dots: radius of the discs in px (default 6)")
    p.add_argument("--hot-pixels", type=int,
                   help="number of hot pixels (default: the generator's, sensor 0, screen 2)")
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
    from springtrack.sim.generators import generator
    from springtrack.sim.sensor import write_truth_csv

    out = Path(args.out)
    if out.suffix not in EVENT_SUFFIXES:
        raise ValueError(f"{out}: unknown event file type {out.suffix!r}; "
                         f"use one of {', '.join(EVENT_SUFFIXES)}")
    write_events = _writer(out)
    gen = generator(args.generator)
    if args.scene not in gen.scenes:
        raise ValueError(f"scene {args.scene!r} is not one of --generator {gen.name}'s: "
                         f"{', '.join(gen.scenes)}")
    extra = {}
    if args.refresh_hz is not None:
        if gen.name != "screen":
            raise ValueError("--refresh-hz applies to --generator screen only")
        extra["refresh_hz"] = args.refresh_hz
    scene_params = {k: v for k, v in (("speed", args.speed), ("radius", args.radius))
                    if v is not None}
    if args.radius is not None and args.scene != "dots":
        raise ValueError("--radius applies to the dots scene only")
    if args.speed is not None and args.scene not in ("dots", "shapes_handheld"):
        raise ValueError("--speed applies to the dots and shapes_handheld scenes only")
    cfg = gen.config(args.noise_rate, args.hot_pixels, **extra)
    scene = gen.make_scene(args.scene, seed=args.seed, **scene_params)
    if args.model_out:
        scene.initial_model().save(args.model_out)
    stats, chunks, truth = {}, [], []
    t0 = time.perf_counter()
    for ev, tr in gen.simulate(scene, args.seconds, args.seed, chunk_us=int(args.chunk_ms * 1000),
                           config=cfg, stats=stats):
        chunks.append(ev)
        truth.append(tr)
    wall = time.perf_counter() - t0
    events = np.concatenate(chunks) if chunks else np.zeros(0)
    write_events(events, cfg.width, cfg.height)
    rows = write_truth_csv(args.truth, truth)
    dur = (args.seconds if args.seconds else scene.default_seconds)
    counts = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in stats.items() if k != "steps"
                       and k != "periods" and k != "pixels_processed")
    print(f"{args.scene} ({gen.name}): {len(events)} events in {dur:g} s "
          f"({len(events) / dur:.0f} ev/s; {counts}), simulated in {wall:.2f} s "
          f"({dur / wall:.1f}x real time)", file=sys.stderr)
    print(f"wrote {out}, {args.truth} ({rows} rows)"
          + (f", {args.model_out}" if args.model_out else ""), file=sys.stderr)
    return 0
