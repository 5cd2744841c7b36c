"""The motion model's cost per event (eqs. M1-M8, docs/motion.md) on every backend that
runs it fast: the float kernel (`cython`), the integer kernel (`fixed`) and its
microcontroller build (Cortex-M4 and Cortex-M7 instructions, counted in the emulator as
`springtrack mcu profile` counts them): the model off (the defaults, the paper's step:
motion_tau_us = polarity_gain = 0), both edges without the velocity (polarity_gain = 1,
eq. M6b) and the whole model (motion_tau_us = 1000, polarity_gain = 1).

Streams: the simulator's face_occlusion scene (face26, seed 1, 1 s, as benchmarks/mcu.py)
and the real dot of evt2_sample.raw (a one-tracker model placed on it,
tests/support/dot_truth.py).  Host: ns per event in process CPU time, best of --repeat
runs, the six contenders alternating run by run (the machine is shared).  Cortex-M: the
mean instructions per event over the first --events events.

Run: .venv/bin/python benchmarks/motion_cost.py [--repeat N] [--events N] [--no-write]
Writes the "Motion model: cost per event" section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import springtrack                                        # noqa: E402
import springtrack.io                                     # noqa: E402
from springtrack.learning.motion import MOTION_OFF, MOTION_ON   # noqa: E402
from springtrack.params import Params                     # noqa: E402
from springtrack.sim.sensor import simulate_all           # noqa: E402
from support.dot_truth import dot_model_toml, dot_truth   # noqa: E402

from _report import machine, write_section                # noqa: E402

MOTION, OFF = MOTION_ON, MOTION_OFF
SETTINGS = (("off", OFF), ("edges", dict(OFF, polarity_gain=1.0)), ("on", MOTION))
TARGETS = ("cortex-m4", "cortex-m7")


def streams():
    """(label, model, events): the face scene and the real dot."""
    ev, _ = simulate_all("face_occlusion", 1.0, seed=1)
    out = [("face_occlusion (sim, 1 s)", springtrack.load_model("face26"), ev)]
    data = Path(os.environ.get("SPRINGTRACK_DATA", ROOT.parent / "shared" / "data"))
    raw = data / "evt2_sample.raw"
    if raw.exists():
        dot = springtrack.io.open(str(raw)).read()
        path = Path(tempfile.mkdtemp()) / "dot.toml"
        path.write_text(dot_model_toml(dot_truth(dot)))
        out.append(("real dot (evt2_sample.raw)", springtrack.load_model(str(path)), dot))
    return out


def host_ns(model, ev, repeat: int) -> dict:
    """(backend, setting) -> best ns/event in process CPU time, contenders alternating."""
    best = {}
    for _ in range(repeat):
        for b in ("cython", "fixed"):
            for name, p in SETTINGS:
                tr = springtrack.Tracker(model, Params(**p), backend=b)
                t0 = time.process_time()
                tr.process(ev)
                dt = (time.process_time() - t0) / len(ev) * 1e9
                best[(b, name)] = min(best.get((b, name), np.inf), dt)
    return best


def mcu_instructions(model, ev, n: int) -> dict:
    """(target, setting) -> mean instructions per event over the first n events."""
    from springtrack.mcu.profile import profile_events
    return {(tgt, name): profile_events(model, Params(**p), ev, tgt, limit=n)["mean"]
            for tgt in TARGETS for name, p in SETTINGS}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="host runs per contender (default 5)")
    ap.add_argument("--events", type=int, default=20_000,
                    help="events profiled on the emulated cores (default 20000)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    a = ap.parse_args(argv)
    t0 = time.time()
    lines = ["| stream | backend | motion off (the defaults) | both edges (eq. M6b) "
             "| motion on | extra per event: edges / on |",
             "|---|---|---:|---:|---:|---:|"]
    for label, model, ev in streams():
        ns = host_ns(model, ev, a.repeat)
        for b in ("cython", "fixed"):
            off, de, on = ns[(b, "off")], ns[(b, "edges")], ns[(b, "on")]
            lines.append(f"| {label}, {len(ev):,} events | {b} (ns/event) | {off:.1f} | "
                         f"{de:.1f} | {on:.1f} | {de - off:+.1f} / {on - off:+.1f} ns |")
        ins = mcu_instructions(model, ev, a.events)
        for tgt in TARGETS:
            off, de, on = ins[(tgt, "off")], ins[(tgt, "edges")], ins[(tgt, "on")]
            lines.append(f"| {label}, first {min(a.events, len(ev)):,} events | {tgt} "
                         f"(instructions/event) | {off:.0f} | {de:.0f} | {on:.0f} | "
                         f"{de - off:+.0f} ({100 * (de - off) / off:+.0f} %) / "
                         f"{on - off:+.0f} ({100 * (on - off) / off:+.0f} %) |")
        print("\n".join(lines[-4:]), flush=True)
    body = (f"`.venv/bin/python benchmarks/motion_cost.py --repeat {a.repeat} --events "
            f"{a.events}` ({time.time() - t0:.0f} s), {machine()}.  Motion model on: "
            + ", ".join(f"{k} = {v:g}" for k, v in MOTION.items()) + "; off: the defaults "
            "(the paper's step, both 0); both edges: polarity_gain = 1 alone.  "
            "Host: best of the runs in process CPU time, the contenders alternating; the "
            "machine is shared and loaded, so expect tens of percent of noise in ns.  "
            "Cortex-M: exact counts of the emulated instructions (`springtrack mcu "
            "profile`), the kernel's own work per event (fx_step and its spring updates).\n\n"
            + "\n".join(lines) + "\n")
    print(body)
    if not a.no_write:
        write_section("Motion model: cost per event", body)


if __name__ == "__main__":
    main()
