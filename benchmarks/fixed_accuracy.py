"""Fixed-point kernel accuracy against the float64 kernel, >= 1 M events per scene.

Run: .venv/bin/python benchmarks/fixed_accuracy.py [--events N] [--sim-seconds S] [--no-write]
Streams: SCENES of tests/support/fixed_bound.py (structured synthetic grid3x3 and face26
scenes, plain and "steady": the parts move smoothly, 30 % uniform noise, 300 k events/s),
and SIM_SCENES (the simulator's face_occlusion and grid scenes with the paper's
per-experiment values, S seconds each), sampled every 1 ms, in the default parameters'
frame.
Writes the "Fixed-point accuracy" section of docs/benchmarks.md and the "Measured
accuracy" section of docs/fixed_point.md.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))     # the bound the tests check, on longer streams
from support.fixed_bound import (BOUNDS, SCENES, SIM_SCENES, compare, scene_stream, sim_stream,  # noqa: E402
                         truth_for, violations)

from _report import machine, replace_section, write_section  # noqa: E402

DOC = REPO / "docs" / "fixed_point.md"


def episode_summary(eps) -> str:
    """Runs of samples with some tracker > 0.25 px from its float twin, in one line."""
    if not eps:
        return "none"
    n = sum(b - a + 1 for a, b, _ in eps)
    return (f"{len(eps)} runs, {n} samples, first at sample {eps[0][0]} "
            f"({eps[0][2]:.2f} px), longest {max(b - a + 1 for a, b, _ in eps)} samples")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--sim-seconds", type=float, default=20.0)
    ap.add_argument("--scenes", nargs="+", default=[*SCENES, *SIM_SCENES],
                    choices=[*SCENES, *SIM_SCENES])
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rows, bad = [], []
    for preset in args.scenes:
        t0 = time.perf_counter()
        if preset in SIM_SCENES:
            model, ev, truth, params = sim_stream(preset, args.sim_seconds)
        else:
            model, ev = scene_stream(preset, args.events, seed=args.seed)
            first = -(-int(ev["t"][0]) // 1000) * 1000
            times = np.arange(first, int(ev["t"][-1]) + 1000, 1000)
            truth, params = truth_for(model, preset, times), None
        res = compare(model, ev, sample_us=1000, truth=truth, params=params)
        sat = sum(v for k, v in res["counters_fixed"].items() if k.startswith("saturated_"))
        assigned = (res["counters_float"]["events_assigned"], res["counters_fixed"]["events_assigned"])
        rows.append((preset, res, sat, assigned))
        bad += [f"{preset}: {v}" for v in violations(res)]
        print(f"{preset:14s} {res['events']:>10,d} events {res['samples']:>6d} samples  "
              f"pos rms {res['pos_rms_px']:.2e} max {res['pos_max_px']:.2e} px  "
              f"cov {res['cov_rel_max']:.2e}  active {res['active_agree']:.5f}  "
              f"sensitive {res['sensitive_agree']:.5f}  metric {res['metric_float_pct']:.4f} / "
              f"{res['metric_fixed_pct']:.4f} %  saturations {sat}  "
              f"episodes > 0.25 px: {episode_summary(res['episodes'])}  "
              f"({time.perf_counter() - t0:.1f} s)", flush=True)
    lines = ["| scene | events | samples | position RMS px | position max px | covariance max rel. "
             "| active agree | sensitive agree | tracking error float / fixed % | diff pp "
             "| assigned float / fixed | saturations | episodes > 0.25 px |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for p, r, sat, (af, ax) in rows:
        lines.append(f"| {p} | {r['events']:,} | {r['samples']:,} | {r['pos_rms_px']:.2e} | "
                     f"{r['pos_max_px']:.2e} | {r['cov_rel_max']:.2e} | {r['active_agree']:.5f} | "
                     f"{r['sensitive_agree']:.5f} | {r['metric_float_pct']:.4f} / "
                     f"{r['metric_fixed_pct']:.4f} | {r['metric_diff_pp']:.1e} | {af:,} / {ax:,} | {sat} | "
                     + episode_summary(r["episodes"]) + " |")
    bound = (f"Bound: position RMS <= {BOUNDS['pos_rms_px']} px, max <= "
             f"{BOUNDS['pos_max_px']} px, covariances within {100 * BOUNDS['cov_rel_max']:.0f} % "
             f"(sxx, syy relative; sxy relative to sqrt(sxx syy)), active and sensitive flags "
             f"equal at >= {100 * BOUNDS['active_agree_min']} % of tracker-samples, tracking "
             f"error within {BOUNDS['metric_diff_pp']} percentage point.  "
             + ("**All met.**" if not bad else "**Violations: " + "; ".join(bad) + "**"))
    text = "\n".join([
        f"Command: `.venv/bin/python benchmarks/fixed_accuracy.py --events {args.events} "
        f"--seed {args.seed} --sim-seconds {args.sim_seconds:g}`  ",
        f"Machine: {machine()}  ",
        "Streams: `SCENES` of `tests/support/fixed_bound.py` (structured synthetic scenes, 30 % noise, "
        "300 k events/s) and its `SIM_SCENES` (the simulator's scenes, seed 0, with the "
        "paper's per-experiment springs, stiffness and s), both kernels on the same events, "
        "samples every 1 ms, the default parameters otherwise (the similarity frame of eq. (22) "
        "and the Cartesian springs).", "",
        *lines, "", bound])
    if not args.no_write:
        write_section("Fixed-point accuracy", text)
        replace_section(DOC, "Measured accuracy", text)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
