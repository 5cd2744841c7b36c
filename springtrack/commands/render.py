"""``springtrack render INPUT --model M.toml [--track T.csv] --out OUT``: events with the
trackers drawn over them (2-sigma ellipses, springs, state colours, time stamp)."""
from __future__ import annotations

import sys

EPILOG = """\
colours: events ON red, OFF blue (last --window-us of events); ellipses are 2-sigma:
green = active, black = inactive, orange dashed = insensitive (eq. 21); grey lines are the
springs; yellow + marks the ground truth when --truth is given.
OUT: .gif or .mp4 (video, MP4 needs imageio-ffmpeg), .png (the middle frame), or a
directory (one PNG per frame). Times in µs of event time.
"""


def add_arguments(p):
    p.epilog = EPILOG
    p.add_argument("input", help="event file (any format springtrack reads)")
    p.add_argument("--model", required=True, help="shape model TOML or preset name")
    p.add_argument("--track", help="track CSV (springtrack track / hostctl record); "
                                   "default: track on the fly")
    p.add_argument("--params", help="parameter TOML for tracking on the fly")
    p.add_argument("--truth", help="ground truth CSV t_us,part,x,y to overlay")
    p.add_argument("--out", required=True, help="output .gif, .mp4, .png or directory")
    p.add_argument("--window-us", type=int, default=10_000,
                   help="events accumulated per frame, µs (default 10000 = 10 ms)")
    p.add_argument("--every-us", type=int, default=None,
                   help="time between frames, µs (default: --window-us)")
    p.add_argument("--max-frames", type=int, default=2000, help="refuse to render more frames")
    p.add_argument("--scale", type=float, default=2.0, help="output pixels per sensor pixel")


def load_events(path):
    from .. import io as stio
    return stio.open(path).read()


def run(args) -> int:
    from ..model import load_model
    from ..render import render
    from ..track import TRACK_FIELDS, read_csv
    from ..tracker import Tracker
    if args.window_us <= 0 or (args.every_us is not None and args.every_us <= 0):
        raise ValueError("--window-us and --every-us must be positive µs")
    model = load_model(args.model)
    events = load_events(args.input)
    if args.track:
        track = read_csv(args.track)
        missing = [i for i in model.ids if i not in track.ids]
        if missing:
            raise ValueError(f"{args.track}: no rows for tracker(s) {', '.join(missing[:5])} of the model")
        order = [track.ids.index(i) for i in model.ids]
        for f in TRACK_FIELDS:
            setattr(track, f, getattr(track, f)[:, order])
        track.ids = list(model.ids)
    else:
        track = Tracker(model, params=args.params).run(events, sample_us=1000)
    truth = None
    if args.truth:
        from ..metrics import read_truth_csv
        truth = read_truth_csv(args.truth)
    n = render(events, model, track, args.out, window_us=args.window_us, every_us=args.every_us,
               truth=truth, title=model.name, max_frames=args.max_frames, scale=args.scale)
    print(f"wrote {args.out}: {n} frame(s)", file=sys.stderr)
    return 0
