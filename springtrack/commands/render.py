"""``springtrack render INPUT [--model M.toml [--track T.csv]] --out OUT``: events with the
trackers drawn over them (2-sigma ellipses, springs, state colours, time stamp); without a
model, one picture of the events alone with pixel axes and a grid, to read positions off
when writing a model."""
from __future__ import annotations

import sys

from . import options

EPILOG = """\
colours: events ON red, OFF blue (last --window-us of events); ellipses are 2-sigma:
green = active, black = inactive, orange dashed = insensitive (eq. 21); grey lines are the
springs; yellow + marks the ground truth when --truth is given; a lost model instance is
drawn grey and dotted, one not found yet not at all; --show-acquisition marks with purple x
where each acquisition placed an instance (tracking on the fly with --acquire).
OUT: .gif or .mp4 (video, MP4 needs imageio and imageio-ffmpeg), .png (the middle frame), or a
directory (one PNG per frame). Times in µs of event time; a frame's header counts seconds
from the recording's first event (its own clock at the end of the header).
without --model: one picture (.png, .svg, .pdf, ...) of the events of --start-us .. --end-us
(default: the whole recording) with axes in sensor pixels (x right, y down, as in a model's
[[trackers]]) and a grid every --grid px.
"""


def add_arguments(p):
    p.epilog = EPILOG
    p.add_argument("input", help="event file (any format springtrack reads), or a live "
                                 "source URL (dv://HOST:PORT, dv:camera, udp://HOST:PORT; docs/live.md)")
    p.add_argument("--model", action="append",
                   help="shape model TOML or preset name (default: events only); repeat it for "
                        "several models, as for track")
    options.add_sensor_from(p)
    p.add_argument("--track", help="track CSV (springtrack track / hostctl record); "
                                   "default: track on the fly")
    p.add_argument("--params", help="parameter TOML for tracking on the fly")
    options.add_acquire_arguments(p)
    p.add_argument("--show-acquisition", action="store_true",
                   help="mark where each acquisition placed an instance (needs --acquire, "
                        "tracking on the fly)")
    p.add_argument("--truth", help="ground truth CSV t_us,part,x,y to overlay")
    p.add_argument("--out", required=True, help="output .gif, .mp4, .png or directory; "
                                                "without --model a picture (.png, .svg, ...)")
    p.add_argument("--window-us", type=int, default=10_000, metavar="US",
                   help="events accumulated per frame, µs (default 10000 = 10 ms)")
    p.add_argument("--every-us", type=int, default=None, metavar="US",
                   help="time between frames, µs (default: --window-us)")
    p.add_argument("--max-frames", type=int, default=2000, metavar="N",
                   help="refuse to render more than N frames (default 2000)")
    p.add_argument("--scale", type=float, default=2.0, metavar="F",
                   help="output pixels per sensor pixel (default 2)")
    p.add_argument("--grid", type=int, metavar="PX",
                   help="without --model: labelled grid lines every PX pixels (default: at most "
                        "16 across the sensor)")
    options.add_prep_arguments(p)


def load_events(path):
    """(events, width, height, known) of a file; the size from its header, else the
    events' (springtrack.commands.inputs; the decoder's drops are warned about)."""
    from .inputs import read_input
    src = read_input(path)
    return src.events, src.width, src.height, src.known


def prepared(args, events, width, height):
    """The events through the recording-quirk options, if any was given (springtrack.prep)."""
    import numpy as np
    prep = options.preparer(args, width, height)
    if prep is None:
        return events, None
    return np.concatenate([events[:0]] + list(options.prepared([events], prep))), prep.stats


def run(args) -> int:
    if args.window_us <= 0 or (args.every_us is not None and args.every_us <= 0):
        raise ValueError("--window-us and --every-us must be positive µs")
    if args.grid is not None and args.grid < 1:
        raise ValueError(f"--grid must be a positive number of px, got {args.grid}")
    if not args.model:
        return events_only(args)
    events, width, height, known = load_events(args.input)
    origin = int(events["t"][0]) if len(events) else 0       # frame times count from it
    events, stats = prepared(args, events, width, height)
    return overlay(args, events, width if known else None, height if known else None, origin)


def events_only(args) -> int:
    """The picture of the events, counted per pixel chunk by chunk as they are read: memory
    is the sensor's pixels and a chunk, not the recording (docs/benchmarks.md, "Render
    memory")."""
    from pathlib import Path
    from ..render import EventCounts, plot_events
    from .inputs import checked, stream_input
    for opt in ("track", "truth", "params", "acquire", "show_acquisition"):
        if getattr(args, opt):
            raise ValueError(f"--{opt.replace('_', '-')} needs --model")
    if Path(args.out).suffix.lower() in (".gif", ".mp4", "") or Path(args.out).is_dir():
        raise ValueError(f"{args.out}: without --model, render writes one picture "
                         f"(.png, .svg, .pdf, ...)")
    chunks, width, height, reader = stream_input(args.input)
    prep = options.preparer(args, width, height)
    counts = EventCounts(width, height)
    n, first, last = 0, None, None
    for chunk in options.prepared(chunks, prep):
        counts.add(chunk)
        n += len(chunk)
        first = int(chunk["t"][0]) if first is None else first
        last = int(chunk["t"][-1])
    checked(reader, args.input)
    span = f"t = {first:,} .. {last:,} us" if n else "no events"
    title = (f"{Path(args.input).name}: {width}x{height}, {n:,} events, {span}"
             + (f" ({prep.stats.summary()})" if prep is not None else ""))
    plot_events(None, width, height, args.out, title=title, scale=args.scale, grid=args.grid,
                image=counts.image())
    print(f"wrote {args.out}: {n:,} events on the {width}x{height} sensor", file=sys.stderr)
    return 0


def overlay(args, events, width, height, origin: int = 0) -> int:
    from ..sensor_fit import fit_model
    from ..instances import ModelSet
    from ..model import load_model
    from ..render import render
    from ..track import TRACK_FIELDS, read_csv
    from .options import tracker_from_args
    from .probe import motion_params
    models = [fit_model(load_model(m), width, height, args.sensor_from,
                        what=f"{args.input}'s sensor") for m in args.model]
    if args.show_acquisition and (args.track or not args.acquire):
        raise ValueError("--show-acquisition needs --acquire and tracking on the fly (no --track)")
    acquisitions = None
    if args.track:
        mset = ModelSet(models, instances=args.instances)
        track = read_csv(args.track)
        missing = [i for i in mset.ids if i not in track.ids]
        if missing:
            raise ValueError(f"{args.track}: no rows for tracker(s) {', '.join(missing[:5])} of the model")
        order = [track.ids.index(i) for i in mset.ids]
        for f in TRACK_FIELDS:
            setattr(track, f, getattr(track, f)[:, order])
        track.ids = list(mset.ids)
        if args.start_us is not None or args.end_us is not None:
            # the frames follow the track's samples: those of the events' span only
            track = track.between(args.start_us, args.end_us)
            if not len(track):
                raise ValueError(f"{args.track}: no samples between --start-us and --end-us")
    else:
        model = models if len(models) > 1 else models[0]
        # as track does: a fast model's motion model and acquisition window (docs/motion.md)
        params, _ = motion_params(args, model, [(events, len(events))], who="render")
        tr = tracker_from_args(args, model, params)
        tr.record(1000)
        tr.process(events)
        tr.flush()
        track = tr.samples()
        mset = tr.models
        if args.acquire and tr.acquisition is not None and not tr.acquisition.done:
            raise ValueError(f"no model instance was found in {args.input}")
        if args.show_acquisition:
            acquisitions = [(t, xy) for t, _, xy in tr.recovery.placements]
    truth = None
    if args.truth:
        from ..metrics import read_truth_csv
        truth = read_truth_csv(args.truth)
    title = ", ".join(i.label if len(mset) > 1 else i.model.name for i in mset)
    n = render(events, mset, track, args.out, window_us=args.window_us, every_us=args.every_us,
               truth=truth, title=title, max_frames=args.max_frames, scale=args.scale,
               acquisitions=acquisitions, origin_us=origin)
    print(f"wrote {args.out}: {n} frame(s)", file=sys.stderr)
    return 0
