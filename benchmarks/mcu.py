"""Instructions per event, flash and RAM of the microcontroller build (springtrack/mcu/)
on face26 and grid3x3 for every core, and what they mean in events/s.

Run: .venv/bin/python benchmarks/mcu.py [--events N] [--no-write]
Streams: the simulator's face_occlusion and grid_inplane scenes (springtrack.sim, seed 1),
and the blob_stream scenes of benchmarks/_streams.py; the first N events of each.
Writes the "Microcontroller build" section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import springtrack  # noqa: E402
from springtrack.commands.mcu import CLOCKS  # noqa: E402
from springtrack.instances import ModelSet  # noqa: E402
from springtrack.mcu.backend import McuSet  # noqa: E402
from springtrack.mcu.build import Capacity, cached_build  # noqa: E402
from springtrack.mcu.profile import profile_events  # noqa: E402
from springtrack.mcu.targets import TARGETS  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402
from springtrack.sim.synthetic import blob_stream  # noqa: E402
from springtrack.sampling import UNSET  # noqa: E402
from springtrack.tracker import resolve_params  # noqa: E402

from _report import machine, write_section  # noqa: E402
from _streams import SCENES as BLOB  # noqa: E402

PAPER_RATE = 300_000          # events/s of the paper's face scene (Valeiras et al. 2015)
TARGET_INSTR = 800            # the target on the face scene, Thumb-2


def streams(n: int):
    """(label, preset, events)"""
    out = []
    for label, scene, preset, secs in (("face_occlusion (sim)", "face_occlusion", "face26", 1.0),
                                       ("grid_inplane (sim)", "grid_inplane", "grid3x3", 1.0)):
        ev, _ = simulate_all(scene, secs, seed=1)
        out.append((label, preset, ev[:n]))
    for preset in ("face26", "grid3x3"):
        noise, motion = BLOB[preset]
        ev, _ = blob_stream(springtrack.load_model(preset), n, rate_hz=300_000, noise=noise,
                            seed=1, **motion)
        out.append((f"{preset} blob_stream", preset, ev))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=20_000)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rows, sizes, evs = [], {}, {}
    for label, preset, ev in streams(args.events):
        evs[preset] = ev
        m = springtrack.load_model(preset)
        for tgt in TARGETS:
            t0 = time.perf_counter()
            r = profile_events(m, resolve_params(m), ev, tgt)
            b = cached_build(tgt, Capacity.of_model(m))
            sizes[(preset, tgt)] = (b.flash_bytes, b.ram_bytes, b.objects.get("mcu_state", 0),
                                    b.objects.get("mcu_cells", 0), r["stack_bytes"])
            rows.append((label, preset, tgt, r))
            print(f"{label:22s} {tgt:10s} {r['events']:>7,d} events  mean {r['mean']:7.1f}  "
                  f"p99 {r['p99']:7.0f}  springs {100 * r['spring_share']:4.1f} %  "
                  f"loads {r['mix']['loads']:.0f}  ({time.perf_counter() - t0:.1f} s)", flush=True)
    # several instances (McuSet): the build for face26 with grid3x3, its stack on face events
    pair = ModelSet([springtrack.load_model("face26"), springtrack.load_model("grid3x3")])
    for tgt in TARGETS:
        be = McuSet(pair, target=tgt)
        be.run(evs["face26"], 1000, UNSET, 1 << 20)
        b = be.build
        sizes[("face26 + grid3x3 (2 instances)", tgt)] = (
            b.flash_bytes, b.ram_bytes, b.objects.get("mcu_state", 0),
            b.objects.get("mcu_cells", 0), be.emu.stack_used())
    lines = ["| stream | core | events | instructions / event (mean) | p50 | p99 | in spring updates | "
             "top functions (instructions / event) |", "|---|---|---:|---:|---:|---:|---:|---|"]
    for label, preset, tgt, r in rows:
        top = ", ".join(f"{k} {v:.0f}" for k, v in list(r["by_function"].items())[:4])
        lines.append(f"| {label} | {tgt} | {r['events']:,} | {r['mean']:.0f} | {r['p50']:.0f} | "
                     f"{r['p99']:.0f} | {100 * r['spring_share']:.1f} % | {top} |")
    size_lines = ["| model | core | flash bytes | RAM bytes | of which state | spatial index | stack used (of 8192) |",
                  "|---|---|---:|---:|---:|---:|---:|"]
    for (preset, tgt), (fl, ram, st, cells, stack) in sizes.items():
        size_lines.append(f"| {preset} | {tgt} | {fl:,} | {ram:,} | {st:,} | {cells:,} | {stack:,} |")
    rate_lines = ["| stream | core | clock, CPI | events/s | vs 300 k events/s |", "|---|---|---|---:|---:|"]
    for label, preset, tgt, r in rows:
        if tgt == "rv32imac" or not label.startswith("face"):
            continue
        mhz, cpi, _ = CLOCKS[tgt]
        rate = mhz * 1e6 / (r["mean"] * cpi)
        rate_lines.append(f"| {label} | {tgt} | {mhz:g} MHz, {cpi:g} | {rate / 1e3:,.0f} k | "
                          f"{rate / PAPER_RATE:.2f} x |")
    face = [r for label, _, tgt, r in rows if label.startswith("face_occlusion") and tgt == "cortex-m4"][0]
    verdict = (f"Target of <= {TARGET_INSTR} Thumb-2 instructions per event on the face scene: "
               + ("**met**" if face["mean"] <= TARGET_INSTR else "**not met**")
               + f" ({face['mean']:.0f} on face_occlusion, Cortex-M4).")
    c = face["counters"]
    assigned = c["events_assigned"] / max(c["events_valid"], 1)
    fn = face["by_function"]
    updates = max(c["spring_updates"], 1)
    nc = len(springtrack.load_model("face26").connections)
    n_tr = len(springtrack.load_model("face26").trackers)
    per_update = face["spring_share"] * face["mean"] * face["events"] / updates
    per_event = face["mean"] * (1 - face["spring_share"])
    passes = sum(v for k, v in fn.items() if k.startswith("spring_passes")) * face["events"] / updates
    fit = fn.get("fit_frame", 0) * face["events"] / updates
    period = face["events"] / updates
    need = per_update / (TARGET_INSTR - per_event) if per_event < TARGET_INSTR else float("inf")
    where = ("Where they go (face_occlusion, Cortex-M4, instructions per event; inlined code "
             "counts in its caller): "
             + ", ".join(f"{k} {v:.0f} ({100 * v / face['mean']:.0f} %)"
                         for k, v in list(fn.items())[:8])
             + f".  Per event, outside the spring update: {per_event:.0f} (the candidates' "
             "quadratic forms of eq. (2) in fx_step and qform, eqs. (3)-(6) and the inverse "
             f"covariance in update_tracker and refresh; {100 * assigned:.0f} % of the events are "
             f"assigned, about {(fn.get('update_tracker', 0) + fn.get('refresh', 0)) / max(assigned, 1e-9):.0f}"
             " each).  The spring update, once per "
             f"{period:.0f} events: {per_update:,.0f} instructions, of which the {nc} connections' "
             f"passes (eqs. 10-20) {passes:,.0f} ({passes / nc:.0f} per connection), the "
             f"similarity frame's fit over {n_tr} trackers {fit:,.0f}, and the forces, eqs. (13), "
             "(21)-(22), the state guard and the index checks the rest.  The target would need "
             + (f"the spring update every {need:.0f} events at today's cost (or its cost cut "
                f"to {(TARGET_INSTR - per_event) * period:,.0f})"
                if need != float("inf") else
                f"the per-event part alone cut below {TARGET_INSTR}")
             + ".")
    text = "\n".join([
        f"Command: `.venv/bin/python benchmarks/mcu.py --events {args.events}`  ",
        f"Machine: {machine()} (the counts do not depend on it: they are instructions the "
        "emulated core executes)  ",
        "Build: `springtrack mcu build` (clang of the ziglang package, -O2, freestanding, sized "
        "for the model); counts from `springtrack mcu profile` (unicorn, per basic block, "
        "each event through `fx_step`, the empty call subtracted).", "",
        *lines, "", *size_lines, "",
        "What the face counts mean in time, with the clocks and cycles per instruction of "
        "docs/mcu.md (Cortex-M4: the TRM's cycle counts applied to the measured mix; "
        "Cortex-M7: dual issue from TCM taken as 1 instruction per cycle), against the "
        "paper's face scene at 300 k events/s:", "", *rate_lines, "", verdict, "", where])
    if not args.no_write:
        write_section("Microcontroller build", text)


if __name__ == "__main__":
    main()
