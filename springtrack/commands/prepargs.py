"""The recording-preparation options that several commands share (springtrack.prep):
``--start-us``, ``--end-us``, ``--dequantize``, ``--seed``, ``--burst-fraction``."""
from __future__ import annotations

from ..prep import DEFAULT_BURST_FRACTION, Preparer

NAMES = ("start_us", "end_us", "dequantize", "burst_fraction")


def add_arguments(p, always: bool = False, seed: bool = True) -> None:
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
