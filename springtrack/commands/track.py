"""``springtrack track INPUT --model M.toml --out OUT.csv``: run the tracker over an event file."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ..io.outputs import text_output
from ..track import CSV_HEADER
from ..tracker import profile
from ..view import add_arguments as add_view_arguments
from ..watch import TrackWatch
from . import options
from .options import read_events, tracker_from_args
from .probe import motion_params

EPILOG = """\
units: event times are microseconds; positions px; covariances px^2.
input: .npy structured arrays (fields t, x, y, p), CSV with header t,x,y,p, and every
camera format springtrack.io reads (EVT 2.0/2.1/3.0 RAW, Event Stream .es, DAT, AEDAT 4);
- reads an event stream (RAW EVT 2.0/2.1/3.0 with its % header, or .es, .dat, .aedat4) from
standard input as it arrives, e.g. another stack's live output piped in.
live sources (docs/live.md): dv://HOST:PORT a DV network event stream, dv:camera[:SERIAL]
an attached iniVation camera (both: pip install 'springtrack[dv]'), udp://HOST:PORT events
in aestream's UDP layout (?geometry=WxH, ?timeout=S); the sensor size from the stream; the
run ends with the stream, and prints its counts (events, batches, gaps) on stderr.
output CSV header: t_us,tracker,x,y,sxx,sxy,syy,activity,vx,vy,active,sensitive,state (px, px^2,
vx and vy in px/s: eq. M7, 0 with the motion model off) — one row
per tracker at every multiple of --sample-us between the first and the last event, holding
the state after all events with t < t_us; a stretch without events is sampled for its first
64 periods only, then from its next event on (docs/algorithm.md, Sampling).  Rows are
written as they are taken: memory does not grow with the input's time span.  state: the
tracker's model instance searching, tracking or lost.
several objects: --model A --model B tracks both at once (one event assignment, springs
and energies per instance; on every backend); --instances N holds N instances of each
model (with --acquire: each found in turn, the ones found explaining their events away).
Tracker ids stay as written when unique across the instances, else become NAME#K/ID.
--acquire: the models' positions are not used; each instance is found (translation,
rotation, isotropic scale within the --acquire-* bounds) in the first --acquire-ms of
events, placed there and tracked from that window's first event; while none is found the
window slides by half its length (rows start once one is found).  Then an instance whose
trackers fall inactive (fewer than a third active for 3 activity time constants) is lost
and searched for again every --acquire-ms / 2 in the last --acquire-ms of events; an
instance not found at the start is searched for the same way.  See docs/acquisition.md.
fast parts: with --model (a model given by hand; a learned one carries the learner's
measure), the model is first tracked over the stream's first 10 ms (after --acquire-ms
with --acquire); if its parts cross more than motion_sigmas_per_ms (--learn-param, default
1) of their sizes (sigma) per ms, the motion model (velocity and both edges per tracker,
docs/motion.md) is switched on and stderr says so (with --acquire and no --acquire-ms, the
search's window is shortened to the time in which the parts cross 4 of their sizes, at
least 1 ms); --params with motion_tau_us = 0 (or any motion parameter given) decides
instead.
exit status: 0 tracked, 4 tracked but --acquire's find was doubtful (at a search bound or
confidence below 0.7: a warning says which), 1 --acquire found no model, 2 bad input, 3
--learn-first-ms found no object (noise or too few events), 141 standard output closed
early (a pipe's reader went away), 143 SIGTERM (the CSV's last line then says '# INCOMPLETE').
"""


DOUBTFUL_EXIT = 4        # tracked, but an acquisition's find was doubtful


def add_arguments(p):
    p.epilog = EPILOG
    p.add_argument("input", help="event file (.npy, .csv, .raw, .es, .dat, .aedat4), or - for "
                                 "an event stream (e.g. RAW) on standard input, or a live source URL "
                                 "(dv://HOST:PORT, dv:camera[:SERIAL], udp://HOST:PORT; "
                                 "docs/live.md)")
    p.add_argument("--model", action="append",
                   help="shape model: TOML file or preset name (grid3x3, face26); repeat it "
                        "to track several models at once; or --learn-first-ms")
    p.add_argument("--learn-first-ms", type=float, metavar="MS",
                   help="learn the model from the stream's first MS ms (springtrack learn), "
                        "then track the rest with it")
    p.add_argument("--params", help="TOML file of parameter overrides (see docs/algorithm.md); "
                                    "with --learn-first-ms its [learn] table sets the learner's")
    p.add_argument("--model-out", metavar="M.toml",
                   help="with --learn-first-ms: write the learned model there (for render "
                        "--model M.toml --track OUT, or to track other recordings with it)")
    options.add_learn_arguments(p)
    options.add_backend_argument(p)
    p.add_argument("--mcu-target", default="cortex-m4", metavar="CORE",
                   help="with --backend mcu: cortex-m4 (default), cortex-m7 or rv32imac")
    p.add_argument("--sample-us", type=int, default=1000, metavar="US",
                   help="state sampling period in µs of event time (default 1000)")
    p.add_argument("--out", required=True, help="output track CSV ('-': standard output; "
                                                 "the summary then goes to standard error)")
    options.add_acquire_arguments(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--profile", metavar="OUT.csv|OUT.png",
                   help="time the kernel per 10 ms bin of events (paper Figs. 22-23): a CSV "
                        "t_us,events,proc_us or a plot")
    options.add_sensor_from(p)
    add_view_arguments(p)
    options.add_prep_arguments(p)


def open_stream(args):
    """The models and the stream of (chunk, total) to track: the input's events, prepared
    when asked (springtrack.prep); the models --model (a list), each checked against the
    input's sensor (springtrack.sensor_fit: a mismatch or trackers off the sensor is an
    error, unless --sensor-from), or one learned from the stream's first --learn-first-ms
    (the tracking then starts where the learning window ends); and the Preparer (None
    without a preparation option), whose counts say what it dropped; and the reader, whose
    ``stats`` say what its decoder dropped."""
    from .. import io as stio
    from ..live import is_live
    from ..sensor_fit import fit_model
    from ..model import load_model
    if (not args.model) == (args.learn_first_ms is None):
        raise ValueError("give either --model or --learn-first-ms")
    if args.model_out and args.learn_first_ms is None:
        raise ValueError("--model-out writes the model --learn-first-ms learns; with --model "
                         "the model is already a file")
    reader = stio.open(args.input)
    width, height = reader.width, reader.height
    if args.model:
        fitted = [fit_model(load_model(m), width, height, args.sensor_from,
                            what=f"{args.input}'s sensor") for m in args.model]
        model = fitted if len(fitted) > 1 else fitted[0]
        width, height = fitted[0].width, fitted[0].height
    else:
        model = None
        if args.input == "-" or is_live(args.input):     # one pass over a stream
            if not width or not height:
                raise ValueError("--learn-first-ms on a stream needs one that gives the "
                                 "sensor size (a header, or udp://...?geometry=WxH)")
        elif not width or not height:               # .npy, .csv: the events' extent
            ev = reader.read()
            width = int(ev["x"].max()) + 1 if len(ev) else 1
            height = int(ev["y"].max()) + 1 if len(ev) else 1
    source = read_events(reader)
    prep = options.preparer(args, width, height)
    if prep is not None:
        source = _prepared(source, prep)
    if model is None:
        from .learn import learn_first
        model, source = learn_first(source, args.learn_first_ms, width, height,
                                    name=Path(args.input).stem, params=args.params,
                                    learner=options.learn_params(args))
        if args.model_out:
            model.save(args.model_out)
            print(f"wrote the learned model to {args.model_out}", file=sys.stderr)
    return model, source, prep, reader


def _prepared(source, prep):
    """(chunk, total) pairs through ``prep``, with the source's total."""
    total = None

    def chunks():
        nonlocal total
        for chunk, total in source:
            yield chunk
    for out in options.prepared(chunks(), prep):
        yield out, total


class Progress:
    def __init__(self, enabled: bool):
        self.enabled = enabled and sys.stderr.isatty()
        self.last = 0.0

    def update(self, done: int, total, t_us: int):
        now = time.perf_counter()
        if not self.enabled or now - self.last < 0.2:
            return
        self.last = now
        if total:
            frac = min(done / total, 1.0)
            bar = "#" * int(30 * frac)
            sys.stderr.write(f"\r[{bar:<30}] {100 * frac:5.1f}% {done:,} events, t={t_us / 1e6:.3f} s")
        else:
            sys.stderr.write(f"\r{done:,} events, t={t_us / 1e6:.3f} s")
        sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write("\n")


def run(args) -> int:
    if args.sample_us <= 0:
        raise ValueError(f"--sample-us must be a positive number of µs, got {args.sample_us}")
    from ..learning.learner import NoObjectFound
    if args.view:
        from ..view import check_target
        check_target(args.view)
    try:
        model, stream, prep, reader = open_stream(args)
    except NoObjectFound as e:
        print(f"springtrack track: {e}", file=sys.stderr)
        return NoObjectFound.exit_code
    tr = tracker_from_args(args, model)
    if args.model:      # given (one learned by --learn-first-ms carries the learner's measure)
        params, stream = motion_params(args, model, stream)
        if params is not None:
            tr = tracker_from_args(args, model, params)
    tr.record(args.sample_us)
    watch = TrackWatch(tr.models)
    view = None
    if args.view:
        from .. import view as live_view
        view = live_view.open(args.view, tr.models, name=f"springtrack track {args.input}",
                              every_us=args.view_every_us)
    prog = Progress(not args.no_progress)
    start = time.perf_counter()
    n = 0
    t_first = t_last = None
    with text_output(args.out, "track CSV") as out:
        out.write(",".join(CSV_HEADER) + "\n")
        bins = []
        for chunk, total in stream:
            reader.stats.check_decodable(args.input)     # random bytes: refused, not tracked
            if len(chunk) == 0:
                continue
            # the rows are written as the kernel takes them: memory bounded by one call's
            # SAMPLE_CAP rows, however many samples a chunk produces
            if view is not None:
                view.events(chunk)
            if args.profile:
                bins.append(profile(tr, chunk, PROFILE_BIN_US,
                                    sink=lambda rows: _write_rows(rows, tr, watch, out, view)))
            else:
                for part in tr.stream(chunk):
                    _write_rows(part, tr, watch, out, view)
            t_first = int(chunk["t"][0]) if t_first is None else t_first
            t_last = int(chunk["t"][-1])
            n += len(chunk)
            prog.update(n, total, t_last)
        reader.stats.check_decodable(args.input)
        if args.acquire:
            tr.flush()
            _write_rows(tr.samples(), tr, watch, out, view)
    prog.close()
    if view is not None:
        view.close()
        print(f"view: {view.frames} frames -> {args.view}")
    wall = time.perf_counter() - start
    if args.profile:
        write_profile(args.profile, bins)
    span = (t_last - t_first) / 1e6 if n else 0.0
    c = tr.counters
    rate = n / wall if wall > 0 else float("inf")
    rtf = span / wall if wall > 0 else float("inf")
    skipped = c["skipped_back_in_time"] + c["skipped_outside_sensor"]
    print(f"events={n} assigned={c['events_assigned']} skipped={skipped} "
          f"(back_in_time={c['skipped_back_in_time']} outside={c['skipped_outside_sensor']}) "
          f"samples_skipped={c.get('samples_skipped', 0)} "
          f"wall_s={wall:.3f} events_per_s={rate:.3g} realtime_factor={rtf:.1f} out={args.out} "
          f"decoder_{reader.stats.summary()}")
    warn = reader.stats.warning(args.input)
    if warn:
        print(warn, file=sys.stderr)
    if prep is not None:
        print(f"prepared: {prep.stats.summary()}")
    if args.acquire:
        acq = tr.acquisition
        for g, pose in enumerate(acq.poses):
            name = "" if len(acq.poses) == 1 else f"{tr.models[g].label} "
            print(f"acquisition: {name}{pose} after {acq.attempts} window(s) of "
                  f"{args.acquire_ms:g} ms, {acq.events_dropped} events dropped before it")
        if not acq.done:
            what = "the model was" if len(acq.poses) == 1 else "no model instance was"
            print(f"springtrack track: {what} not found in {args.input}; the rows of "
                  f"{args.out} say where it was searched ('searching', then 'not found')",
                  file=sys.stderr)
            return 1
        doubtful = [p for p in acq.poses if p is not None and p.doubtful]
        for p in doubtful:
            print(f"springtrack track: warning: the acquisition is doubtful: {p.doubt}; "
                  f"check the overlay (springtrack render --track), or widen the search "
                  f"(--acquire-scale, --acquire-angle)", file=sys.stderr)
        for t, label, kind in tr.changes:
            print(f"instance {label}: {kind} at t={t} us ({(t - t_first) / 1e3:.1f} ms after the "
                  f"first event tracked)")
        print("instances: " + ", ".join(f"{i['label']} {i['state']} (acquired {i['acquired']}, "
                                        f"lost {i['lost']}, reacquired {i['reacquired']})"
                                        for i in tr.instances()))
        c = tr.counters
        print(f"recovery: {c['reacquire_attempts']} search(es), {c['verifications']} "
              f"verification(s), {c['losses_refuted']} loss(es) refuted, {c['moved']} move(s), "
              f"{c['recalled']} tracker(s) left behind recalled"
              + (f", {c['unplaceable']} pose(s) refused: they put trackers beyond one sensor "
                 f"size around the sensor" if c.get("unplaceable") else ""))
    if n:
        watch.finish(tr.state(), never_found=[i["label"] for i in tr.instances()
                                              if args.acquire and i["state"] == "searching"])
        for w in watch.warnings():
            print(f"springtrack track: warning: {w}", file=sys.stderr)
    if args.acquire and doubtful:
        return DOUBTFUL_EXIT
    return 0


PROFILE_BIN_US = 10_000


def write_profile(path, bins) -> None:
    """Merge per-chunk bins (a bin cut by a chunk boundary is summed) and write CSV or PNG."""
    t = np.concatenate([b["t_us"] for b in bins]) if bins else np.empty(0, np.int64)
    ev = np.concatenate([b["events"] for b in bins]) if bins else np.empty(0, np.int64)
    pu = np.concatenate([b["proc_us"] for b in bins]) if bins else np.empty(0)
    keys, inv = np.unique(t, return_inverse=True)
    ev = np.bincount(inv, ev, len(keys)).astype(np.int64)
    pu = np.bincount(inv, pu, len(keys))
    if str(path).endswith(".png"):
        from ..render import plot_load
        plot_load(keys, ev, pu, path, PROFILE_BIN_US)
        return
    with open(path, "w") as f:
        f.write("t_us,events,proc_us\n")
        f.writelines(f"{a},{b},{c:.3f}\n" for a, b, c in zip(keys.tolist(), ev.tolist(), pu.tolist()))


def _write_rows(samples, tr, watch, f, view=None):
    """Samples the tracker took, as CSV rows (the header is already written), into the
    end-of-run watch and the live view."""
    if not len(samples):
        return
    if watch.models is not tr.models:          # placed by the acquisition
        watch.use_models(tr.models)
    watch.add(samples)
    samples.write_rows(f)
    if view is not None:
        view.track(samples)
