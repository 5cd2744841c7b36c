"""``springtrack learn INPUT --out MODEL.toml``: learn a shape model from a recording's
events (springtrack.learning.learner), print what it found and optionally draw it."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from . import options
from .options import read_params

EPILOG = """\
method (docs/learning.md): free Gaussian trackers spread over the event clouds (births
where events go unassigned, merges of trackers on one part, deaths of idle ones); springs
join neighbouring trackers that were co-active and kept their relative position. The model's
trackers sit where the parts are at the end of the window; its [params] hold the learned
alpha_position, energy_scale and energy_kind (override them with --params).
units: times in µs of the recording's clock; positions px; covariances px^2.
exit status: 0 model written, 2 bad input, 3 no object found (noise or too few events).
"""


def add_arguments(p):
    p.epilog = EPILOG
    p.add_argument("input", help="event file (.npy, .csv, .raw, .es, .dat, .aedat4), or a live "
                                 "source URL (dv://HOST:PORT, dv:camera, udp://HOST:PORT; docs/live.md)")
    p.add_argument("--out", required=True, help="output model TOML")
    p.add_argument("--trackers", type=int, metavar="N",
                   help="exactly N trackers (default: as many as the learner finds parts)")
    p.add_argument("--names", metavar="ID,ID,...",
                   help="tracker ids, comma-separated, in reading order (default p00, p01, ...)")
    p.add_argument("--name", help="model name (default: the input file's stem)")
    p.add_argument("--params", help="TOML file of tracking parameters to write into the "
                                    "model instead of the learned ones (see docs/algorithm.md); "
                                    "its [learn] table sets the learner's parameters")
    options.add_learn_arguments(p)
    p.add_argument("--png", metavar="PICTURE.png",
                   help="draw the learned model over the last --png-window-us of events")
    p.add_argument("--png-window-us", type=int, default=20_000, metavar="US",
                   help="events drawn under the model, µs before the window's end "
                        "(default 20000)")
    options.add_prep_arguments(p, always=True)


def run(args) -> int:
    from ..learning.learner import NoObjectFound, learn_model
    from ..learning.settings import MAX_PARTS
    from .inputs import read_input
    if args.trackers is not None and not 1 <= args.trackers <= MAX_PARTS:
        raise ValueError(f"--trackers must be in [1, {MAX_PARTS}] (one kernel instance holds at "
                         f"most {MAX_PARTS} trackers), got {args.trackers}")
    track_params = read_params(args.params) if args.params else None   # its errors first
    learner = options.learn_params(args)
    src = read_input(args.input)
    raw, width, height = src.events, src.width, src.height
    prep = options.preparer(args, width, height, always=True)
    events = np.concatenate([raw[:0]] + list(options.prepared([raw], prep)))
    print(f"input     {args.input}: {width}x{height}, {len(raw):,} events "
          f"(decoder {src.stats.summary()}); {prep.stats.summary()}; learning on "
          f"{len(events):,}")
    if len(raw) and not len(events) and (args.start_us is not None or args.end_us is not None):
        given = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in
                         (("start_us", args.start_us), ("end_us", args.end_us)) if v is not None)
        print(f"springtrack learn: no event in the window {given}: the recording's events "
              f"run from {int(raw['t'][0]):,} to {int(raw['t'][-1]):,} µs (its own clock)",
              file=sys.stderr)
        return NoObjectFound.exit_code
    names = [s.strip() for s in args.names.split(",")] if args.names else None
    try:
        res = learn_model(events, trackers=args.trackers, width=width, height=height,
                          names=names, name=args.name or Path(args.input).stem,
                          params=learner, track_params=track_params)
    except NoObjectFound as e:
        print(f"springtrack learn: {e}", file=sys.stderr)
        return NoObjectFound.exit_code
    res.model.save(args.out)
    report(res)
    if args.png:
        from ..render import plot_model
        t1 = res.t_end_us
        plot_model(res.model, events[events["t"] >= t1 - args.png_window_us], args.png,
                   title=f"{res.model.name}: learned from {(t1 - res.t_start_us) / 1e3:.0f} ms; "
                         f"events of the last {args.png_window_us / 1e3:g} ms")
    print(f"wrote {args.out}" + (f", {args.png}" if args.png else ""))
    return 0


def report(res) -> None:
    """Print the trackers, the springs with their evidence, and the lifecycle."""
    m = res.model
    life = ", ".join(f"{k} {v}" for k, v in res.lifecycle.items()
                     if v and k not in ("found", "time_scale"))
    print(f"learned   {len(m.trackers)} trackers, {len(m.connections)} springs from "
          f"{res.events:,} events over {(res.t_end_us - res.t_start_us) / 1e3:.1f} ms "
          f"in {res.wall_s:.2f} s ({life})")
    for line in notes(res):
        print(f"note      {line}")
    ev = m.learned
    print(f"stability {ev['stability']:.2f} = persistence {ev['persistence']:.2f} x coherence "
          f"{ev['coherence']:.2f} x layout rigidity {ev['layout']:.2f} (1 = parts that lived "
          f"two grace periods, fired together, in a rigid layout); parts moved "
          f"{ev['travel_px']:g} px (median)")
    print("params    " + ", ".join(f"{k}={v}" for k, v in m.params.items()))
    print(f"{'tracker':>8} {'x':>7} {'y':>7} {'sigma_x':>7} {'sigma_y':>7} {'mass':>5} {'events':>7}")
    for t, n in zip(m.trackers, res.counts):
        print(f"{t.id:>8} {t.x:7.1f} {t.y:7.1f} {t.sigma[0] ** 0.5:7.2f} {t.sigma[2] ** 0.5:7.2f} "
              f"{t.mass:5.2f} {int(n):7d}")
    if not m.connections:
        print("springs   none (one part)" if len(m.trackers) == 1 else "springs   none")
        return
    print(f"{'spring':>17} {'kinds':<20} {'stiffness':>9} {'coactiv.':>8} {'rigidity':>8} "
          f"{'turn deg':>8}")
    for c, s in zip(m.connections, res.springs):
        print(f"{c.a + '-' + c.b:>17} {'+'.join(c.springs):<20} {c.stiffness:9.5f} "
              f"{s.coactivation:8.3f} {s.rigidity:8.3f} {s.turn_deg:8.1f}")


# a fast part moving farther than this within the learning window: the window is said
# to be long for it (docs/learning.md, "A single fast part and its trail")
FAST_TRAVEL_PX = 100.0
SHORT_WINDOW_US = 10_000      # the window the note suggests instead


def notes(res) -> list:
    """What the learner decided for the user: time constants scaled to a short window,
    parts beyond a kernel instance's capacity reduced, criteria switched off."""
    from ..learning.settings import MAX_PARTS, LearnParams
    out = []
    life = res.lifecycle
    k = life.get("time_scale", 1.0)
    if k < 1.0:
        ref = LearnParams()
        out.append(f"short window: lifecycle times scaled by {k:g} (grace "
                   f"{ref.life_tau_us * k / 1e3:g} ms, step {ref.batch_us * k:.0f} µs)")
    found, n = life.get("found", 0), len(res.model.trackers)
    if found > n:
        out.append(f"{found} parts found, reduced to {n} (dropped {life.get('dropped_to_n', 0)} "
                   f"weakest, merged {life.get('merged_to_n', 0)} pairs)"
                   + ("; a kernel instance holds at most "
                      f"{MAX_PARTS}" if found > MAX_PARTS else "")
                   + "; --trackers N to choose")
    from ..learning.settings import LAYOUT_RIGID
    if res.model.learned.get("layout", 1.0) < LAYOUT_RIGID:
        out.append(f"layout rigidity {res.model.learned['layout']:.2f} < {LAYOUT_RIGID}: the "
                   f"parts slid against each other (texture, a 3-D object, several objects); "
                   f"the springs may pull trackers off their parts")
    ev = res.model.learned
    if "flicker_hz" in ev:
        out.append(f"the event rate pulses at {ev['flicker_hz']:g} Hz ({100 * ev['flicker_share']:.0f} % "
                   f"of its variation): mains flicker; the parts moved {ev['travel_px']:g} px "
                   f"(median): a model of still things lit by a flickering lamp, not of a "
                   f"moving object, unless something moved in the window")
    if res.model.params.get("motion_tau_us", 0.0) > 0 and "sizes_per_ms" in ev:
        out.append(f"parts move {ev['speed_px_s']:,.0f} px/s, {ev['sizes_per_ms']:.2g} part "
                   f"sizes per ms: the motion model is on (velocity and both edges per "
                   f"tracker, docs/motion.md); --learn-param motion_sigmas_per_ms=0 keeps "
                   f"the paper's step")
        travel = ev["speed_px_s"] * ev.get("window_ms", 0.0) * 1e-3
        if len(res.model.trackers) > 1 and travel > FAST_TRAVEL_PX:
            out.append(f"a fast part travels {travel:,.0f} px in this {ev['window_ms']:g} ms "
                       f"window and leaves a trail of late events that can be learned as "
                       f"parts of their own ({len(res.model.trackers)} parts here): if the "
                       f"object has fewer, learn from a shorter window "
                       f"(--end-us {res.t_start_us + SHORT_WINDOW_US} for the first "
                       f"{SHORT_WINDOW_US // 1000} ms; track --learn-first-ms "
                       f"{SHORT_WINDOW_US // 1000})")
    s = res.model.params.get("energy_scale")
    if s is not None and len(res.model.connections) and s > len(res.model.connections):
        out.append(f"energy_scale {s:g} > {len(res.model.connections)} springs: the occlusion "
                   f"criteria (eqs. 21-22) are off, as the object's shape changed in the window")
    return out


def learn_first(source, ms: float, width: int, height: int, name: str = "learned",
                params=None, learner: dict | None = None):
    """Learn a model from the first ``ms`` milliseconds of a stream of (chunk, total)
    pairs; returns the model and the stream of the events after that window (the
    tracking starts where the learning ended).  ``params``: a --params TOML path
    (tracking parameters written into the model); ``learner``: the learner's parameter
    overrides (:func:`options.learn_params`).  Prints what was learned to stderr."""
    from ..learning.learner import NoObjectFound, learn_model
    if not ms > 0:
        raise ValueError(f"--learn-first-ms must be positive, got {ms}")
    events, _, after, more = options.first_window(source, int(round(ms * 1000)))
    if not more:
        span = (f"{(int(events['t'][-1]) - int(events['t'][0])) / 1e3:g} ms of events"
                if len(events) else "no events")
        raise ValueError(f"--learn-first-ms {ms:g}: the stream holds {span}, nothing is left "
                         f"to track after the learning window; give a shorter window")
    try:
        res = learn_model(events, width=width, height=height, name=name, params=learner,
                          track_params=read_params(params) if params else None)
    except NoObjectFound as e:
        raise NoObjectFound(f"--learn-first-ms {ms:g} ({len(events):,} events): {e}") from None
    m = res.model
    print(f"learned {len(m.trackers)} trackers, {len(m.connections)} springs from the first "
          f"{ms:g} ms ({res.events:,} events, {res.wall_s:.2f} s); stability "
          f"{m.learned['stability']:.2f}; "
          + ", ".join(f"{k}={v}" for k, v in m.params.items()), file=sys.stderr)
    for line in notes(res):
        print(f"learn: {line}", file=sys.stderr)
    return m, after
