"""``springtrack mcu build|run|profile``: the fixed-point kernel as microcontroller firmware.

``build`` cross-compiles it (springtrack/mcu/) for a core, or a bootable image for a board,
and reports flash and static RAM; ``run`` boots a board image in QEMU for hostctl;
``profile`` runs an event file through that build in the emulator and counts
instructions per event.  Both need the ``[mcu]`` extra: pip install 'springtrack[mcu]'.
"""
from __future__ import annotations

import sys

EPILOG = """\
examples:
  springtrack mcu build --target cortex-m4 --out build/m4
  springtrack mcu build --target cortex-m7 --out build/m7 --model face26
  springtrack mcu build --board netduinoplus2 --out build/nd --model face26
  springtrack mcu run build/nd/firmware.elf --board netduinoplus2 --events rec.raw --pty
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
    from ..mcu.boards import BOARDS
    from ..mcu.targets import TARGETS
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    b = sub.add_parser("build", help="cross-compile the kernel for a core; report flash and RAM")
    what = b.add_mutually_exclusive_group(required=True)
    what.add_argument("--target", choices=list(TARGETS),
                      help="the core: the kernel alone, for the emulator (--backend mcu)")
    what.add_argument("--board", choices=list(BOARDS),
                      help="a bootable firmware image for this board as QEMU models it: "
                           "DIR/firmware.elf (start-up code, UART host link, event input, "
                           "kernel; docs/mcu.md)")
    b.add_argument("--out", required=True, metavar="DIR", help="output directory for the ELF")
    b.add_argument("--model", help="size the build for this model (TOML file or preset)")
    b.add_argument("--key-file",
                   help="--board: build this HMAC key into the image (at least 16 bytes, as "
                        "for firmware-sim run --key-file): every host frame but HELLO must be "
                        "signed; the ELF then holds the key")
    b.add_argument("--sensor", metavar="WxH",
                   help="--board: the largest sensor the image tracks, px (default 320x320, "
                        "or the --model's)")
    r = sub.add_parser("run", help="boot a firmware image in QEMU, its host link on a pty "
                                   "or TCP, for hostctl")
    r.add_argument("elf", help="the image (springtrack mcu build --board B --out DIR: "
                               "DIR/firmware.elf)")
    r.add_argument("--board", required=True, choices=list(BOARDS), help="the board it was built for")
    r.add_argument("--events", required=True, metavar="FILE",
                   help="the event stream: a RAW EVT 2.0 / 2.1 recording (its words as they "
                        "are) or any event file (encoded as EVT 2.0 words)")
    link = r.add_mutually_exclusive_group()
    link.add_argument("--pty", action="store_true",
                      help="serve the host link on a new pty (prints 'pty: /dev/pts/N'; the "
                           "default)")
    link.add_argument("--listen", metavar="HOST:PORT",
                      help="serve the host link on TCP (prints 'listen: socket://HOST:PORT')")
    pr = sub.add_parser("profile", help="instructions per event of the build, in the emulator")
    pr.add_argument("input", help="event file (.npy, .csv, .raw, .es, .dat)")
    pr.add_argument("--model", required=True, help="shape model: TOML file or preset name")
    pr.add_argument("--params", help="TOML file of parameter overrides")
    where = pr.add_mutually_exclusive_group()
    where.add_argument("--target", default="cortex-m4", choices=list(TARGETS),
                       help="the core: the kernel alone, per event, in the emulator")
    where.add_argument("--board", choices=[b for b, v in BOARDS.items() if v.qemu_tick_ns],
                       help="the whole firmware image (decoder, kernel, telemetry) in QEMU, "
                            "counted by instruction (-icount), and its static RAM")
    pr.add_argument("--sensor", metavar="WxH",
                    help="--board: size the image's index for this sensor, px, if larger "
                         "than the model's (e.g. 320x320)")
    pr.add_argument("--events", type=int, default=20_000, metavar="N",
                    help="profile the first N events (default 20000; the emulator runs "
                         "roughly 5 k events/s while counting)")
    pr.add_argument("--clock-mhz", type=float, help="core clock for the events/s figure, MHz")
    pr.add_argument("--cpi", type=float, help="cycles per instruction for that figure")


def run(args) -> int:
    try:
        return ACTIONS[args.action](args)
    except (RuntimeError, ValueError) as e:        # the [mcu] extra missing, a failed build, a faulted run
        print(f"springtrack mcu {args.action}: error: {e}", file=sys.stderr)
        return 2


def _build(args) -> int:
    from ..mcu.build import Capacity, build
    if args.board:
        return _build_image(args)
    if args.sensor or args.key_file:
        raise ValueError("--sensor and --key-file go with --board (a --target build is the "
                         "kernel alone, sized by --model)")
    cap = Capacity()
    if args.model:
        from ..model import load_model
        cap = Capacity.of_model(load_model(args.model))
    res = build(args.target, args.out, cap)
    print(res.report())
    return 0


def _build_image(args) -> int:
    import dataclasses
    from ..mcu.build import Capacity
    from ..mcu.image import DEFAULT_CAPACITY, ELF_NAME, build_image
    cap = DEFAULT_CAPACITY
    if args.model:
        from ..model import load_model
        cap = Capacity.of_model(load_model(args.model))
    if args.sensor:
        w, h = _sensor(args.sensor)
        cap = dataclasses.replace(cap, width=w, height=h)
    key = None
    if args.key_file:
        from ..wire import read_key_file
        key = read_key_file(args.key_file)
    res = build_image(args.board, args.out, cap, key=key)
    print(f"board {args.board}: {ELF_NAME}")
    print(res.report())
    return 0


def _run(args) -> int:
    import signal
    from ..mcu.qemu import Qemu
    q = Qemu(args.elf, args.board, args.events, listen=args.listen)
    s = q.summary
    print(f"pty: {q.link}" if args.listen is None else f"listen: {q.link}", flush=True)
    print(f"{args.board}: {args.elf}; events {args.events}: {s['words']:,} {s['format']} words, "
          f"{s['width']}x{s['height']} px", file=sys.stderr, flush=True)
    signal.signal(signal.SIGTERM, lambda *a: (_ for _ in ()).throw(KeyboardInterrupt))
    try:
        rc = q.wait()
    except KeyboardInterrupt:
        rc = 0
    finally:
        q.close()
    if q.err.strip():
        print(q.err.strip()[-2000:], file=sys.stderr)
    return 0 if rc in (0, -15) else rc


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

    if args.board:
        return _profile_image(args, tr, ev)
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


def _profile_image(args, tr, ev) -> int:
    from ..mcu.image_profile import profile_image
    sensor = _sensor(args.sensor) if args.sensor else None
    r = profile_image(tr.model, tr.params, ev, args.board, sensor)
    mhz, cpi, source = CLOCKS[r["target"]]
    mhz = args.clock_mhz or mhz
    cpi = args.cpi or cpi
    ipe = r["instructions_per_event"]
    rate = mhz * 1e6 / (ipe * cpi)
    c = r["capacity"]
    print(f"board {args.board} ({r['target']}), model {tr.model.name}: {r['events']:,} events "
          f"through the image (EVT 2.0 decoding, the kernel, telemetry records), counted in "
          f"QEMU -icount by SysTick ticks of {r['tick_instructions']} instructions")
    print(f"instructions per event: {ipe:.1f} (mean), of which decoding the words "
          f"{r['decode_per_event']:.1f}")
    print(f"static RAM {r['ram_bytes']:,} bytes for {c.trackers} trackers, {c.connections} "
          f"connections, a {c.width}x{c.height} sensor (stack {r['stack_bytes']:,}, of which "
          f"{r['stack_used_bytes']:,} used); flash {r['flash_bytes']:,} bytes")
    print("largest RAM objects: " + ", ".join(
        f"{k} {v:,}" for k, v in sorted(r["objects"].items(), key=lambda kv: -kv[1])[:10]))
    print(f"at {mhz:g} MHz and {cpi:g} cycles per instruction ({source}): "
          f"{rate / 1e3:,.0f} k events/s")
    print(f"instructions_per_event={ipe:.1f} ram_bytes={r['ram_bytes']} "
          f"events_per_s={rate:.0f}")
    return 0


def _sensor(text: str) -> tuple[int, int]:
    w, _, h = text.lower().partition("x")
    try:
        return int(w), int(h)
    except ValueError:
        raise ValueError(f"--sensor {text!r}: expected WxH in px, e.g. 320x320") from None


ACTIONS = {"build": _build, "run": _run, "profile": _profile}
