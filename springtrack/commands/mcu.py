"""``springtrack mcu build|profile``: the fixed-point kernel as microcontroller firmware.

``build`` cross-compiles it (springtrack/mcu/) for a core and reports flash and static RAM;
``profile`` runs an event file through that build in the emulator and counts
instructions per event.  Both need the ``[mcu]`` extra: pip install 'springtrack[mcu]'.
"""
from __future__ import annotations

import sys

EPILOG = """\
examples:
  springtrack mcu build --target cortex-m4 --out build/m4
  springtrack mcu build --target cortex-m7 --out build/m7 --model face26
  springtrack mcu profile events.npy --model face26 --target cortex-m7 --events 20000

build: the last line is `flash_bytes=N ram_bytes=N` (flash: code, constant tables,
initialised data; RAM: the kernel's state struct, its spatial index, the I/O buffers and
the stack), for the capacity built: --model sizes it to a model's trackers, connections
and sensor, else 64 trackers, 128 connections, 1280x720 px.
profile: instructions per event (mean, p50, p99, max) counted per basic block in the
emulator, the share spent in spring updates (fx_springs), the stack used, and what the
mean means in events/s at --clock-mhz with --cpi cycles per instruction (defaults per
core, see docs/mcu.md); the last line contains instructions_per_event=N.
"""

# core -> (clock MHz, cycles per instruction, where those figures come from): docs/mcu.md
CLOCKS = {
    "cortex-m4": (168.0, 1.3, "STM32F407 at 168 MHz; Cortex-M4 TRM (ARM DDI 0439) 3.3.1: "
                  "1 cycle per data-processing and 32x32->64 multiply, 1-2 per load, 2-4 "
                  "per taken branch, 2-12 per UDIV, applied to the mix below"),
    "cortex-m7": (480.0, 1.0, "STM32H7 at 480 MHz from TCM; Cortex-M7 TRM (ARM DDI 0489): "
                  "dual-issue 6-stage pipeline, taken as 1 instruction per cycle"),
    "rv32imac": (320.0, 1.25, "SiFive FE310 (E31 core) at 320 MHz; E31 Core Complex Manual: "
                 "single-issue 5-stage pipeline, 1-cycle ALU, multi-cycle loads and "
                 "divides"),
}


def add_arguments(p):
    p.epilog = EPILOG
    from ..mcu.targets import TARGETS
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    b = sub.add_parser("build", help="cross-compile the kernel for a core; report flash and RAM")
    b.add_argument("--target", required=True, choices=list(TARGETS), help="the core")
    b.add_argument("--out", required=True, metavar="DIR", help="output directory for the ELF")
    b.add_argument("--model", help="size the build for this model (TOML file or preset)")
    pr = sub.add_parser("profile", help="instructions per event of the build, in the emulator")
    pr.add_argument("input", help="event file (.npy, .csv, .raw, .es, .dat)")
    pr.add_argument("--model", required=True, help="shape model: TOML file or preset name")
    pr.add_argument("--params", help="TOML file of parameter overrides")
    pr.add_argument("--target", default="cortex-m4", choices=list(TARGETS), help="the core")
    pr.add_argument("--events", type=int, default=20_000, metavar="N",
                    help="profile the first N events (default 20000; the emulator runs "
                         "roughly 5 k events/s while counting)")
    pr.add_argument("--clock-mhz", type=float, help="core clock for the events/s figure, MHz")
    pr.add_argument("--cpi", type=float, help="cycles per instruction for that figure")


def run(args) -> int:
    try:
        return _build(args) if args.action == "build" else _profile(args)
    except RuntimeError as e:        # the [mcu] extra missing, a failed build, a faulted run
        print(f"springtrack mcu {args.action}: error: {e}", file=sys.stderr)
        return 2


def _build(args) -> int:
    from ..mcu.build import Capacity, build
    cap = Capacity()
    if args.model:
        from ..model import load_model
        cap = Capacity.of_model(load_model(args.model))
    res = build(args.target, args.out, cap)
    print(res.report())
    return 0


def _profile(args) -> int:
    import numpy as np
    from .. import io as stio
    from ..mcu.profile import profile_events
    from ..tracker import Tracker
    from .options import read_events
    if args.events <= 0:
        raise ValueError(f"--events must be a positive number, got {args.events}")
    tr = Tracker(args.model, params=args.params)
    chunks, n = [], 0
    for chunk, _ in read_events(stio.open(args.input)):
        chunks.append(chunk[:args.events - n])
        n += len(chunks[-1])
        if n >= args.events:
            break
    if not n:
        raise ValueError(f"{args.input}: no events")
    ev = np.concatenate(chunks)

    def progress(k, total):
        if sys.stderr.isatty():
            sys.stderr.write(f"\r{k:,}/{total:,} events")
            sys.stderr.flush()

    r = profile_events(tr.model, tr.params, ev, args.target, progress=progress)
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    mhz, cpi, source = CLOCKS[args.target]
    mhz = args.clock_mhz or mhz
    cpi = args.cpi or cpi
    rate = mhz * 1e6 / (r["mean"] * cpi)
    c = r["counters"]
    print(f"target {args.target}, model {tr.model.name}: {r['events']:,} events "
          f"({c['events_assigned']:,} assigned, {c['spring_updates']:,} spring updates)")
    print(f"instructions per event: mean {r['mean']:.1f}  p50 {r['p50']:.0f}  p99 {r['p99']:.0f}  "
          f"max {r['max']}  in spring updates {100 * r['spring_share']:.1f} %")
    print("by function (instructions per event, inlined code counted in its caller): "
          + ", ".join(f"{k} {v:.1f}" for k, v in list(r["by_function"].items())[:8]))
    mix = r["mix"]
    print(f"mix per event: {mix['loads']:.0f} loads, {mix['blocks']:.0f} basic blocks, "
          f"{mix['divides']:.1f} divisions; stack used {r['stack_bytes']} bytes")
    print(f"at {mhz:g} MHz and {cpi:g} cycles per instruction ({source}): "
          f"{rate / 1e3:,.0f} k events/s")
    print(f"instructions_per_event={r['mean']:.1f} p99={r['p99']:.0f} "
          f"spring_share={r['spring_share']:.3f} events_per_s={rate:.0f}")
    return 0
