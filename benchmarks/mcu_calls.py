"""Where a spring update's instructions go in the microcontroller build: for each function,
how often it is entered per spring update and what one call costs (inlined code counted in
its caller), counted in the emulator on the first events of the simulator's face_occlusion
scene (seed 1, 1 s) with face26, as ``springtrack mcu profile`` counts them.  Prints a
table for docs/mcu.md ("Where the instructions go"); writes nothing.

Run: .venv/bin/python benchmarks/mcu_calls.py [--events N] [--target cortex-m4]
(about 10 s at the default 20,000 events)
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import springtrack  # noqa: E402
from springtrack.mcu.backend import McuBackend  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402

FUNCTIONS = ("fx_springs", "spring_passes_3", "fit_frame", "frame_weights")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=20_000)
    ap.add_argument("--target", default="cortex-m4")
    args = ap.parse_args()
    ev, _ = simulate_all("face_occlusion", 1.0, seed=1)
    ev = ev[:args.events]
    tr = springtrack.Tracker(springtrack.load_model("face26"), backend="fixed")
    be = McuBackend(tr.model, tr.params, target=args.target, count=True)
    emu = be.emu
    entries = {emu.addr(f) & ~1: f for f in FUNCTIONS}
    calls: Counter[str] = Counter()

    def on_block(_uc, address, _size, _user):
        f = entries.get(address)
        if f is not None:
            calls[f] += 1

    emu.uc.hook_add(__import__("unicorn").UC_HOOK_BLOCK, on_block)
    emu.by_function.clear()
    for t, x, y in zip(ev["t"].tolist(), ev["x"].tolist(), ev["y"].tolist()):
        be.step(t, x, y)
    n, updates = len(ev), max(calls["fx_springs"], 1)
    print(f"{args.target}, face26, face_occlusion: {n:,} events, {updates} spring updates")
    print("| function | per event | calls per spring update | per call |")
    print("|---|---:|---:|---:|")
    for f in FUNCTIONS:
        total = emu.by_function.get(f, 0)
        c = max(calls[f], 1)
        print(f"| `{f}` | {total / n:.1f} | {calls[f] / updates:.2f} | {total / c:,.0f} |")


if __name__ == "__main__":
    main()
