"""The one home of the options several commands share, and of what they build.

* recording quirks (springtrack.prep; track, render, learn): ``--start-us``,
  ``--end-us``, ``--dequantize``, ``--seed``, ``--burst-fraction`` (:func:`add_prep_arguments`,
  :func:`preparer`, :func:`prepared`);
* acquisition (track, render, firmware-sim run): ``--instances``, ``--acquire``,
  ``--acquire-ms``, ``--acquire-angle``, ``--acquire-scale``, ``--acquire-budget-ms``
  (:func:`add_acquire_arguments`,
  :func:`add_acquire_window`, :func:`acquire_bounds`);
* ``--sensor-from`` (track, render), ``--backend`` (track, render, firmware-sim run, from
  the registry springtrack.backends.BACKENDS), a ``--params`` file's parameters
  (:func:`read_params`: learn, firmware-sim run), the learner's ``--learn-param`` and
  ``[learn]`` table (:func:`add_learn_arguments`, :func:`learn_params`);
* :func:`tracker_from_args`: the Tracker those options ask for; :func:`read_events`.
"""
from __future__ import annotations

import argparse

import numpy as np

from ..backends import DEFAULT_BACKEND, backend_help, backend_names
from ..events import EVENT_DTYPE, as_events
from ..limits import MAX_INSTANCES, MAX_SET_TRACKERS
from ..prep import DEFAULT_BURST_FRACTION, Preparer

NAMES = ("start_us", "end_us", "dequantize", "burst_fraction")


# ---- recording quirks ----------------------------------------------------------------
def add_prep_arguments(p, always: bool = False, seed: bool = True) -> None:
    """Add the options; ``always``: the command prepares its events even without them
    (otherwise only when one of them is given); ``seed``: add ``--seed`` (False: the
    command has its own ``--seed``, which then seeds --dequantize's order too)."""
    when = "" if always else " (any of these options turns the preparation on)"
    g = p.add_argument_group("recording quirks" + when)
    g.add_argument("--start-us", type=int, metavar="US",
                   help="drop events before this time, µs of the recording's clock")
    g.add_argument("--end-us", type=int, metavar="US",
                   help="drop events at and after this time, µs of the recording's clock")
    g.add_argument("--dequantize", action="store_true",
                   help="spread the events of each coarse timestamp tick (detected from the "
                        "data, e.g. 1000 µs) evenly over the tick, in a seeded random order")
    if seed:
        g.add_argument("--seed", type=int, default=0,
                       help="seed of --dequantize's order (default 0)")
    g.add_argument("--burst-fraction", type=float, metavar="F",
                   help=f"drop a tick (or 1 ms) in which at least this fraction of the sensor's "
                        f"pixels fire: a full-frame burst (default {DEFAULT_BURST_FRACTION}; "
                        f"0 keeps bursts)")


def wanted(args) -> bool:
    return any(getattr(args, k) not in (None, False) for k in NAMES)


def preparer(args, width: int, height: int, always: bool = False) -> Preparer | None:
    """The Preparer the options ask for, or None when the command should not prepare."""
    if not (always or wanted(args)):
        return None
    frac = DEFAULT_BURST_FRACTION if args.burst_fraction is None else args.burst_fraction
    return Preparer(width, height, start_us=args.start_us, end_us=args.end_us,
                    dequantize=args.dequantize, burst_fraction=frac or None, seed=args.seed)


def prepared(chunks, prep: Preparer | None):
    """The event chunks through ``prep`` (unchanged when None), then its held-back tail;
    stops reading once the chunks pass ``end_us``."""
    if prep is None:
        yield from chunks
        return
    for chunk in chunks:
        out = prep.feed(chunk)
        if len(out):
            yield out
        if prep.end_us is not None and len(chunk) and int(chunk["t"][-1]) >= prep.end_us:
            break
    tail = prep.finish()
    if len(tail):
        yield tail


# ---- acquisition ---------------------------------------------------------------------
def add_acquire_arguments(p) -> None:
    """--instances and the acquisition's options, shared by track and render."""
    p.add_argument("--instances", type=int, default=1, metavar="N",
                   help="instances of each model (default 1; more than 1 needs --acquire; "
                        f"at most {MAX_INSTANCES} instances, {MAX_SET_TRACKERS} trackers in all)")
    p.add_argument("--acquire", action="store_true",
                   help="find the models in the events instead of trusting their positions; "
                        "lost instances are searched for again (docs/acquisition.md)")
    add_acquire_window(p)


class _Given(argparse.Action):
    """Store the value and note that it was given (``args.<dest>_given``): a default
    the command may choose otherwise."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        setattr(namespace, self.dest + "_given", True)


def given(args, dest: str) -> bool:
    """Whether the option of ``dest`` (one stored by _Given) was on the command line."""
    return getattr(args, dest + "_given", False)


def add_acquire_window(p) -> None:
    """--acquire-ms, --acquire-angle and --acquire-scale (track, render, firmware-sim)."""
    p.add_argument("--acquire-ms", type=float, default=50.0, metavar="MS", action=_Given,
                   help="acquisition window in ms of event time (default 50; track: "
                        "shorter for a model whose parts it measures moving fast, "
                        "docs/motion.md)")
    p.add_argument("--acquire-angle", type=float, default=45.0, metavar="DEG",
                   help="acquisition searches rotations within +-DEG degrees (default 45)")
    p.add_argument("--acquire-scale", default="0.6,1.6", metavar="LO,HI",
                   help="acquisition searches sizes LO..HI times the model's (default 0.6,1.6)")
    p.add_argument("--acquire-budget-ms", type=float, metavar="MS",
                   help="search budget in ms of event time from the first event: a model "
                        "not found by then is 'not found' and no longer searched for "
                        "(default: search until the input ends)")


def acquire_bounds(args) -> dict:
    """The acquisition's bounds from --acquire-angle and --acquire-scale (--acquire-ms
    checked with them: each error names the option)."""
    try:
        lo, hi = (float(v) for v in args.acquire_scale.split(","))
    except ValueError:
        raise ValueError(f"--acquire-scale must be LO,HI (e.g. 0.6,1.6), "
                         f"got {args.acquire_scale!r}") from None
    if not 0 < lo <= hi:
        raise ValueError(f"--acquire-scale must be LO,HI with 0 < LO <= HI, "
                         f"got {args.acquire_scale!r}")
    if not 0 <= args.acquire_angle <= 180:
        raise ValueError(f"--acquire-angle must be in [0, 180] degrees, got {args.acquire_angle:g}")
    if not args.acquire_ms > 0:
        raise ValueError(f"--acquire-ms must be a positive number of ms, got {args.acquire_ms:g}")
    budget = getattr(args, "acquire_budget_ms", None)
    if budget is not None and not budget > 0:
        raise ValueError(f"--acquire-budget-ms must be a positive number of ms, got {budget:g}")
    return {"angle_deg": (-args.acquire_angle, args.acquire_angle), "scale": (lo, hi)}


# ---- sensor, backend, parameters ------------------------------------------------------
def add_sensor_from(p) -> None:
    """``--sensor-from``, shared by the commands that track a file with a model."""
    p.add_argument("--sensor-from", choices=["file", "source", "model"],
                   help="a model whose [sensor] is not the input's is refused; 'file' (or "
                        "'source', as in firmware-sim): track "
                        "it on the input's sensor (trackers where they are), 'model': keep "
                        "the model's sensor (events outside it skipped and counted)")


def add_backend_argument(p, firmware: bool = False) -> None:
    """``--backend``: a name of springtrack.backends.BACKENDS (``firmware``: one the firmware
    loop runs)."""
    p.add_argument("--backend", default=DEFAULT_BACKEND, choices=backend_names(firmware),
                   help=backend_help(firmware))


def read_params(path) -> dict:
    """The tracking parameters a TOML file sets (top level or [params]; its [learn]
    table is the learner's), validated."""
    from ..params import from_mapping, read_toml, tracking_table
    table = tracking_table(read_toml(path))
    valid = from_mapping(table, where=str(path)).as_dict()
    return {k: valid[k] for k in table}


# ---- the learner's parameters ----------------------------------------------------------
def add_learn_arguments(p) -> None:
    """``--learn-param NAME=VALUE`` (learn, track --learn-first-ms, firmware-sim run)."""
    from ..learning.settings import LearnParams
    from dataclasses import fields
    p.add_argument("--learn-param", action="append", metavar="NAME=VALUE", default=[],
                   help="a learner parameter (repeatable; over the --params file's [learn] "
                        "table); units in the names (_us µs, _px pixels), e.g. "
                        "sigma_max_px=24 or birth_events=12; names: "
                        + ", ".join(f.name for f in fields(LearnParams))
                        + " (docs/learning.md)")


def learn_params(args) -> dict:
    """The learner's parameter overrides: the --params file's [learn] table, then each
    --learn-param; validated (each error names the file or the option)."""
    from ..learning.settings import learn_overrides, parse_assignments
    from ..params import read_toml
    table = {}
    if getattr(args, "params", None):
        data = read_toml(args.params)
        table = learn_overrides(data.get("learn", {}), where=f"{args.params} [learn]")
    given = parse_assignments(getattr(args, "learn_param", None))
    return learn_overrides({**table, **learn_overrides(given, where="--learn-param")})



# ---- what the options build ------------------------------------------------------------
def tracker_from_args(args, model, params=None):
    """The springtrack.Tracker of --params (or ``params``, a dict, in its place), --backend,
    --instances and --acquire*."""
    from ..tracker import Tracker
    n_models = len(model) if isinstance(model, (list, tuple)) else 1
    if args.instances < 1:
        raise ValueError(f"--instances must be at least 1, got {args.instances}")
    if n_models * args.instances > MAX_INSTANCES:
        raise ValueError(f"--instances {args.instances} of {n_models} model(s) asks for "
                         f"{n_models * args.instances} instances; the limit is {MAX_INSTANCES} "
                         f"in all (springtrack/limits.py)")
    if args.instances > 1 and not args.acquire:
        raise ValueError(f"--instances {args.instances} would place {args.instances} copies "
                         f"of each model on the same positions: add --acquire to find each")
    backend = getattr(args, "backend", "cython")
    backend = f"mcu:{args.mcu_target}" if backend == "mcu" else backend
    return Tracker(model, params=args.params if params is None else params, backend=backend,
                   acquire=args.acquire,
                   acquire_ms=args.acquire_ms, acquire_bounds=acquire_bounds(args),
                   instances=args.instances, acquire_budget_ms=args.acquire_budget_ms)


def first_window(source, span_us: int):
    """Split a stream of (chunk, total) pairs at ``span_us`` after its first event:
    (the events before, the last total seen, the stream of the pairs after, whether there
    are any: False when the source ended within the window)."""
    held, rest, total, t_end = [], None, None, None
    source = iter(source)
    for chunk, total in source:
        if not len(chunk):
            continue
        if t_end is None:
            t_end = int(chunk["t"][0]) + span_us
        k = int(np.searchsorted(chunk["t"], t_end, side="left"))
        held.append(chunk[:k])
        if k < len(chunk):
            rest = chunk[k:]
            break
    events = np.concatenate(held) if held else np.empty(0, EVENT_DTYPE)

    def after():
        if rest is not None:
            yield rest, total
            yield from source
    return events, total, after(), rest is not None


def read_events(reader):
    """Yield (event chunk, estimated total events) from a ``springtrack.io`` reader."""
    total = getattr(reader, "size_hint", None)
    yield from ((as_events(c), total) for c in reader)
