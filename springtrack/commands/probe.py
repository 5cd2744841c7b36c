"""The motion model for a model given by hand (``track --model``): its parts' speed
measured on the stream's first window (springtrack.learning.motion.probe), the model
switched on when they are fast, said on stderr."""
from __future__ import annotations

import itertools
import sys

from ..backends import DEFAULT_BACKEND
from ..learning.motion import ACQUIRE_SIZES, MOTION_ON, MOTION_SIGMAS_PER_MS, choose, decided
from ..learning.motion import probe_window_us
from . import options


def motion_params(args, model, source, who: str = "track"):
    """(params, source): the tracking parameters to use (None: --params as given) and the
    stream to track.  With a model given by hand, neither it nor --params setting
    motion_tau_us or polarity_gain, and --learn-param motion_sigmas_per_ms above 0 (the
    default): the model is tracked over the stream's first window (after --acquire-ms with
    --acquire) and, if its parts cross more than motion_sigmas_per_ms of their sizes per
    millisecond, the motion model is switched on (docs/motion.md), and with --acquire and
    no --acquire-ms given, ``args.acquire_ms`` shortened to the window in which they
    cross a few of their sizes (springtrack.learning.motion.choose).  ``who``: the command
    named in what is said."""
    models = model if isinstance(model, (list, tuple)) else [model]
    given = options.read_params(args.params) if args.params else {}
    threshold = options.learn_params(args).get("motion_sigmas_per_ms", MOTION_SIGMAS_PER_MS)
    if decided(models, given, threshold):
        return None, source
    events, total, after, _ = options.first_window(
        source, probe_window_us(args.acquire, args.acquire_ms))
    source = itertools.chain([(events, total)], after)
    c = choose(model, events, given, threshold, getattr(args, "backend", DEFAULT_BACKEND),
               args.acquire, args.acquire_ms, options.given(args, "acquire_ms"),
               options.acquire_bounds(args), args.instances)
    p = c.probe
    if p is None or not (c.on or c.refused):
        return None, source
    measured = (f"the model's parts move {p.speed_px_s:,.0f} px/s, {p.sizes_per_ms:.2g} part "
                f"sizes per ms (median of {p.parts} tracker{'s' if p.parts != 1 else ''} over "
                f"the first {p.window_ms:.3g} ms), more than motion_sigmas_per_ms = "
                f"{threshold:g}")
    if c.refused:
        print(f"{who}: {measured}, but the motion model stays off: {c.refused}",
              file=sys.stderr)
        return None, source
    if c.acquire_ms < args.acquire_ms:
        print(f"{who}: the acquisition's window is {c.acquire_ms:.2g} ms, not "
              f"{args.acquire_ms:g} (the parts cross {ACQUIRE_SIZES:g} of their sizes in it; "
              f"--acquire-ms sets it)", file=sys.stderr)
        args.acquire_ms = c.acquire_ms
    on = ", ".join(f"{k}={v}" for k, v in MOTION_ON.items())
    print(f"{who}: {measured}: the motion model is on ({on}; docs/motion.md); --params with "
          f"motion_tau_us = 0 keeps the paper's step", file=sys.stderr)
    return c.params, source
