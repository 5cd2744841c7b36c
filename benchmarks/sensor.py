"""Simulated ATIS sensor speed (springtrack.sim.sensor) on the paper scenes, one core.

Writes the "Simulated sensor" section of docs/benchmarks.md: events/s produced, real-time
factor (simulated seconds per wall second, best of --repeat runs so background load on a
shared machine counts less), and the slowest chunk relative to its duration (< 1 means the
generator keeps up with real-time streaming chunk by chunk, as the firmware's simulated
camera needs).  Target: >= 5x real time on face_occlusion (~300 k events/s).

Run: .venv/bin/python benchmarks/sensor.py [--seconds S] [--repeat N] [--no-write]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine, write_section  # noqa: E402

from springtrack.sim.sensor import simulate  # noqa: E402

SCENES = ("face_occlusion", "grid_pull", "grid_rot_y", "grid_inplane")
CHUNK_US = 100_000


def one_run(scene: str, seconds: float, seed: int):
    n, worst, t0 = 0, 0.0, time.perf_counter()
    t_chunk = t0
    for ev, _ in simulate(scene, seconds, seed=seed, chunk_us=CHUNK_US):
        now = time.perf_counter()
        worst = max(worst, (now - t_chunk) / (CHUNK_US * 1e-6))
        t_chunk = now
        n += len(ev)
    return n, time.perf_counter() - t0, worst


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per scene")
    ap.add_argument("--repeat", type=int, default=3, help="runs per scene; the best is kept")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-write", action="store_true", help="do not touch docs/benchmarks.md")
    args = ap.parse_args(argv)
    rows = []
    for scene in SCENES:
        runs = [one_run(scene, args.seconds, args.seed) for _ in range(args.repeat)]
        n, wall, worst = min(runs, key=lambda r: r[1])
        rows.append((scene, n, wall, worst, max(r[1] for r in runs)))
        print(f"{scene}: {n} events, {n / args.seconds:.0f} ev/s, best {args.seconds / wall:.1f}x "
              f"real time (worst run {args.seconds / rows[-1][4]:.1f}x), slowest chunk "
              f"{worst:.2f} of its duration", file=sys.stderr)
    body = [f"Command: `.venv/bin/python benchmarks/sensor.py --seconds {args.seconds:g} "
            f"--repeat {args.repeat}`  ",
            f"Machine: {machine()}  ",
            f"Scenes from `springtrack.sim.scenes`, seed {args.seed}, default sensor config "
            "(304x240, threshold 0.2, 0.1 Hz/px noise), 100 ms chunks, one core. Best of "
            f"{args.repeat} runs (the machine is shared); 'worst run' shows the spread.", "",
            "| scene | events | events/s | x real time (best) | x real time (worst run) | slowest chunk / its duration |",
            "|---|---:|---:|---:|---:|---:|"]
    body += [f"| {s} | {n:,} | {n / args.seconds:,.0f} | {args.seconds / w:.1f} | "
             f"{args.seconds / wmax:.1f} | {worst:.2f} |" for s, n, w, worst, wmax in rows]
    body += ["", "Target: face_occlusion at >= 5x real time on one core."]
    if not args.no_write:
        write_section("Simulated sensor", "\n".join(body))
    print("\n".join(body))
    return 0


if __name__ == "__main__":
    sys.exit(main())
