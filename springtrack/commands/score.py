"""``springtrack score TRUTH.csv TRACK.csv``: the paper's tracking error (section IV).

Per track sample: mean distance between each tracker and its part (tracker id == part
id; grid: the 9 elements, face: the 7 internal parts) as a percentage of the object's
length (grid side; vertical length of the face mask); then its temporal mean, printed as
the last line ``mean_error_pct=<value>``.  Definitions: springtrack/metrics.py."""
from __future__ import annotations

import numpy as np


def add_arguments(p):
    from springtrack.metrics import FACE_LENGTHS
    p.add_argument("truth", help="ground-truth CSV (t_us,part,x,y), e.g. from springtrack simulate")
    p.add_argument("track", help="track CSV (t_us,tracker,x,y,...), e.g. from springtrack track")
    p.add_argument("--face-length", choices=FACE_LENGTHS, default="mask",
                   help="face length: mask = all 26 parts' vertical extent (paper, default); "
                        "internal = the 7 internal parts' vertical extent")
    p.add_argument("--max-gap-us", type=int, default=1000,
                   help="skip track samples farther than this from any truth time (default 1000)")


def run(args) -> int:
    from springtrack.metrics import read_truth_csv, score_track
    from springtrack.track import read_csv

    truth = read_truth_csv(args.truth)
    track = read_csv(args.track)
    es = score_track(truth, track, face_length=args.face_length, max_gap_us=args.max_gap_us)
    if not len(es.t_us):
        raise ValueError(f"{args.track}: no track sample within {args.max_gap_us} us of a truth "
                         f"time in {args.truth}")
    L = np.nanmean(es.length)
    what = ("grid side" if es.kind == "grid" else
            f"vertical extent of the {'26-part mask' if args.face_length == 'mask' else '7 internal parts'}")
    print(f"{es.kind}: {len(es.t_us)} samples scored, {es.t_us[0] / 1e6:.3f}-{es.t_us[-1] / 1e6:.3f} s, "
          f"length = {what}, mean {L:.1f} px; unmatched samples {es.unmatched}, "
          f"missing positions {es.missing}")
    print(f"{'part':<12}{'mean px':>10}{'max px':>10}{'mean %':>10}")
    for k, p in enumerate(es.parts):
        e = es.err_px[:, k]
        print(f"{p:<12}{np.nanmean(e):>10.2f}{np.nanmax(e):>10.2f}"
              f"{np.nanmean(100 * e / es.length):>10.2f}")
    print(f"{'error %':<12}median {np.nanmedian(es.pct):.2f}  p90 {np.nanpercentile(es.pct, 90):.2f}  "
          f"max {np.nanmax(es.pct):.2f}")
    print(f"mean_error_pct={es.mean_pct:.4f}")
    return 0
