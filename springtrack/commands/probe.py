"""The motion model for a model given by hand (``track --model``): its parts' speed
measured on the stream's first window (springtrack.learning.motion.probe), the model
switched on when they are fast, said on stderr."""
from __future__ import annotations

import itertools
import sys

from ..learning.motion import (ACQUIRE_SIZES, MOTION_ON, MOTION_SIGMAS_PER_MS,
                               fast_acquire_ms, fast_enough, probe, probe_window_us,
                               sets_motion)
from ..backends import DEFAULT_BACKEND, check_backend_params
from ..params import resolve
from . import options


def _decided(models, given: dict, threshold: float) -> bool:
    """Whether the motion model is settled without a probe: never (threshold 0), set by
    --params or a model's [params], or decided by the learner that made a model (its
    [learned] table holds the speed it measured)."""
    return (not threshold > 0 or sets_motion(given)
            or any(sets_motion(m.params) or "sizes_per_ms" in (m.learned or {})
                   for m in models))


def motion_params(args, model, source, who: str = "track"):
    """(params, source): the tracking parameters to use (None: --params as given) and the
    stream to track.  With a model given by hand, neither it nor --params setting
    motion_tau_us or polarity_gain, and --learn-param motion_sigmas_per_ms above 0 (the
    default): the model is tracked over the stream's first window (after --acquire-ms with
    --acquire) and, if its parts cross more than motion_sigmas_per_ms of their sizes per
    millisecond, the motion model is switched on (docs/motion.md), and with --acquire and
    no --acquire-ms given, ``args.acquire_ms`` shortened to the window in which they
    cross a few of their sizes (springtrack.learning.motion.fast_acquire_ms).  ``who``:
    the command named in what is said."""
    models = model if isinstance(model, (list, tuple)) else [model]
    given = options.read_params(args.params) if args.params else {}
    threshold = options.learn_params(args).get("motion_sigmas_per_ms", MOTION_SIGMAS_PER_MS)
    if _decided(models, given, threshold):
        return None, source
    window = probe_window_us(args.acquire, args.acquire_ms)
    events, total, after, _ = options.first_window(source, window)
    source = itertools.chain([(events, total)], after)
    if not len(events):
        return None, source
    p = probe(model, events, given, acquire=args.acquire, acquire_ms=args.acquire_ms,
              acquire_bounds=options.acquire_bounds(args), instances=args.instances)
    if not (p.measured and fast_enough(p.sizes_per_ms, threshold)):
        return None, source
    chosen = {**given, **MOTION_ON}
    measured = (f"the model's parts move {p.speed_px_s:,.0f} px/s, {p.sizes_per_ms:.2g} part "
                f"sizes per ms (median of {p.parts} tracker{'s' if p.parts != 1 else ''} over "
                f"the first {p.window_ms:.3g} ms), more than motion_sigmas_per_ms = "
                f"{threshold:g}")
    try:
        backend = getattr(args, "backend", DEFAULT_BACKEND)
        for m in models:
            check_backend_params(backend, m, resolve(m, chosen))
    except ValueError as e:
        print(f"{who}: {measured}, but the motion model stays off: {e}", file=sys.stderr)
        return None, source
    if args.acquire and not options.given(args, "acquire_ms"):
        ms = fast_acquire_ms(p.sizes_per_ms, args.acquire_ms)
        if ms < args.acquire_ms:
            print(f"{who}: the acquisition's window is {ms:.2g} ms, not {args.acquire_ms:g} "
                  f"(the parts cross {ACQUIRE_SIZES:g} of their sizes in it; --acquire-ms "
                  f"sets it)", file=sys.stderr)
            args.acquire_ms = ms
    on = ", ".join(f"{k}={v}" for k, v in MOTION_ON.items())
    print(f"{who}: {measured}: the motion model is on ({on}; docs/motion.md); --params with "
          f"motion_tau_us = 0 keeps the paper's step", file=sys.stderr)
    return chosen, source
