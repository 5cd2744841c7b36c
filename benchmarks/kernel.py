"""Kernel throughput: events/s of the tracker backends on synthetic grid3x3 and face26 streams.

Run: .venv/bin/python benchmarks/kernel.py [--events N] [--no-write]
Writes the "Kernel" section of docs/benchmarks.md.  The stream is a realistic-shaped
scene: every part emits events at a total of 300 k events/s of scene time, the shape
drifts and rotates, and a fraction of the events is background noise, so that about 30 %
(face) of events are assigned to a tracker.  The cost per event depends on that
fraction, so it is reported beside each figure.  Springs every 55 events (paper).
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import springtrack  # noqa: E402
from springtrack.synthetic import blob_stream  # noqa: E402

from _report import machine, write_section  # noqa: E402

SCENES = {
    # preset: (noise fraction, motion)
    "face26": (0.62, dict(speed_px_s=(10, -5), rot_deg_s=-8, wobble_px=4)),
    "grid3x3": (0.62, dict(speed_px_s=(15, 8), rot_deg_s=10)),
}


def bench(backend: str, preset: str, ev, repeats: int = 3):
    best = float("inf")
    for _ in range(repeats):
        tr = springtrack.Tracker(preset, backend=backend)
        t0 = time.perf_counter()
        tr.process(ev)
        best = min(best, time.perf_counter() - t0)
    c = tr.counters
    return len(ev) / best, c["events_assigned"] / max(c["events_valid"], 1)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=5_000_000)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rows = []
    for preset, (noise, motion) in SCENES.items():
        m = springtrack.load_model(preset)
        ev, _ = blob_stream(m, args.events, rate_hz=300_000, noise=noise, seed=1, **motion)
        backends = ["cython"]
        if importlib.util.find_spec("springtrack._fixed") is not None:
            backends.append("fixed")
        for b in backends:
            rate, frac = bench(b, preset, ev)
            rows.append((preset, b, len(ev), rate, frac))
            print(f"{preset:8s} {b:8s} {len(ev):>10,d} events  {rate / 1e6:7.2f} M events/s  "
                  f"{1e9 / rate:6.1f} ns/event  assigned {100 * frac:4.1f} %", flush=True)
    lines = ["| model | backend | events | M events/s | ns/event | assigned |",
             "|---|---|---:|---:|---:|---:|"]
    lines += [f"| {p} | {b} | {n:,} | {r / 1e6:.2f} | {1e9 / r:.1f} | {100 * f:.1f} % |"
              for p, b, n, r, f in rows]
    text = "\n".join([
        f"Command: `.venv/bin/python benchmarks/kernel.py --events {args.events}`  ",
        f"Machine: {machine()}  ",
        "Stream: `springtrack.synthetic.blob_stream`, 300 k events/s of scene time, "
        "springs every 55 events; best of 3 runs, one core, `Tracker.process` on the whole "
        "array (no sampling). Paper (C++, i7 laptop): 2.26 µs/event = 0.44 M events/s.",
        "", *lines])
    if not args.no_write:
        write_section("Kernel", text)


if __name__ == "__main__":
    main()
