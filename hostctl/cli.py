"""The ``hostctl`` command: steer a springtrack firmware over serial, USB-CDC or TCP.

    hostctl ports
    hostctl demo [--seconds S] [--out DIR]                 # the end-to-end demo (make demo)
    hostctl --port /dev/pts/5 info
    hostctl --port /dev/pts/5 load-model face26            # preset or FILE.toml
    hostctl --port /dev/pts/5 set alpha_position=0.05 energy_scale=3
    hostctl --port /dev/pts/5 get [NAME ...]
    hostctl --port /dev/pts/5 start | stop | reset | acquire | stats | ping | shutdown
    hostctl --port /dev/pts/5 get-model OUT.toml                # the model it runs now
    hostctl --port /dev/pts/5 --role monitor monitor [--seconds S] [--smooth]
    hostctl --port /dev/pts/5 record OUT.csv|OUT.npz [--start] [--seconds S] [--until-end]

``--port`` defaults to $HOSTCTL_PORT.  ``--role monitor`` opens a read-only session beside
the operator's (telemetry, stats, get, ping; docs/protocol.md, "Sessions").  A signed link
(non-loopback TCP) needs the shared key, at least 16 bytes: the contents of ``--key-file``
(as for ``firmware-sim run --key-file``) or $HOSTCTL_KEY - never on the command line,
where other users could read it.  ``shutdown`` ends the firmware program; ``reset`` also
clears its ``faulted`` state.  Exit codes: 0 ok, 1 other error, 2 usage, 3 no such port,
4 no answer, 5 protocol version mismatch, 6 command refused (NACK), 7 authentication
failed (wrong key, or this address locked out after failed attempts), 8 (monitor,
record) a model instance was not found: ``not found`` (its search budget spent) or still
``searching`` with nothing tracked.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from springtrack import wire
from springtrack.wire import Role

from .device import Device, HostctlError

VERBS = ("ports", "demo", "info", "load-model", "get-model", "set", "get", "start", "stop",
         "reset", "acquire", "stats", "ping", "monitor", "record", "shutdown")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hostctl", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    p.add_argument("--port", default=os.environ.get("HOSTCTL_PORT"),
                   help="pyserial URL: /dev/ttyACM0, /dev/pts/N, socket://HOST:PORT "
                        "(default $HOSTCTL_PORT)")
    p.add_argument("--timeout", type=float, default=0.5, help="seconds to wait per try (0.5)")
    p.add_argument("--retries", type=int, default=3, help="retries per command (3)")
    p.add_argument("--key-file", help="file holding the shared link key (else $HOSTCTL_KEY)")
    p.add_argument("--role", choices=[r.name.lower() for r in Role], default="operator",
                   help="session role: operator (default; one at a time, a new one takes "
                        "over) or monitor (read-only)")
    sub = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    sub.add_parser("ports", help="list serial ports")
    from .demo import add_arguments as demo_arguments
    demo_arguments(sub.add_parser("demo", help="end-to-end demo: simulated camera -> firmware-sim "
                                               "-> this host, scored and drawn"))
    sub.add_parser("info", help="firmware/protocol versions, geometry, model")
    sp = sub.add_parser("load-model", help="upload a model (preset name or TOML file)")
    sp.add_argument("model")
    sp = sub.add_parser("get-model", help="download the model the device runs (uploaded, "
                                          "learned or its own) as TOML")
    sp.add_argument("out", metavar="OUT.toml", help="file to write (- for standard output)")
    sp = sub.add_parser("set", help="set parameters NAME=VALUE ...")
    sp.add_argument("assignments", nargs="+", metavar="NAME=VALUE")
    sp = sub.add_parser("get", help="show parameters (all if none named)")
    sp.add_argument("names", nargs="*")
    for verb, text in (("start", "start tracking (after the source ended: replay it)"),
                       ("stop", "stop tracking"),
                       ("reset", "reset the trackers to the model, clear the faulted state"),
                       ("acquire", "search for the model in the events again (a firmware "
                                   "started with --acquire)"),
                       ("stats", "firmware and link counters"),
                       ("shutdown", "end the firmware program")):
        sub.add_parser(verb, help=text)
    sp = sub.add_parser("ping", help="command round-trip times")
    sp.add_argument("-n", type=int, default=10)
    sp = sub.add_parser("monitor", help="live view of the trackers (12 redraws/s)")
    sp.add_argument("--seconds", type=float, default=None, help="stop after S seconds")
    sp.add_argument("--smooth", action="store_true", help="add Kalman-smoothed velocities")
    sp.add_argument("--rate", type=float, default=12.0, help="redraws per second (12)")
    sp = sub.add_parser("record", help="record telemetry to OUT.csv or OUT.npz")
    sp.add_argument("out")
    sp.add_argument("--seconds", type=float, default=10.0, help="duration (10)")
    sp.add_argument("--until-end", action="store_true",
                    help="stop early when the device says its source has no more data")
    sp.add_argument("--start", action="store_true",
                    help="start the device once recording (from its first event; a replay "
                         "that ended is replayed), and stop when its source ends (implies "
                         "--until-end): a short replay is captured whole")
    sp.add_argument("--smooth", action="store_true",
                    help="add smoothed positions and velocities (npz arrays / .smooth.csv)")
    return p


def parse_value(text: str):
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return text


def parse_assignments(items) -> dict:
    out = {}
    for a in items:
        name, sep, value = a.partition("=")
        if not sep or not name:
            raise HostctlError(f"set: expected NAME=VALUE, got {a!r}")
        out[name.strip()] = parse_value(value.strip())
    return out


def read_key(path: str | None) -> bytes | None:
    """The shared key: the key file's bytes without surrounding whitespace (the same rule as
    ``firmware-sim run --key-file``), else $HOSTCTL_KEY as UTF-8, else None."""
    try:
        if path:
            return wire.read_key_file(path)
        key = os.environ.get("HOSTCTL_KEY", "").strip().encode() or None
        wire.check_key(key)
        return key
    except ValueError as e:
        raise HostctlError(f"{'--key-file ' if path else '$HOSTCTL_KEY: '}{e}") from None


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.verb == "ports":
            return cmd_ports()
        if args.verb == "demo":
            from .demo import run_demo
            return run_demo(args)
        if not args.port:
            raise HostctlError("no port given: use --port URL or set HOSTCTL_PORT "
                               "(see `hostctl ports`)")
        with Device(args.port, timeout=args.timeout, retries=args.retries,
                    key=read_key(args.key_file), role=Role[args.role.upper()]) as dev:
            return int(VERB_FUNCS[args.verb](dev, args) or 0)
    except HostctlError as e:
        print(f"hostctl {args.verb}: error: {e}", file=sys.stderr)
        return e.exit_code
    except (ValueError, OSError) as e:
        print(f"hostctl {args.verb}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


def cmd_ports() -> int:
    from serial.tools import list_ports
    ports = list(list_ports.comports())
    for p in ports:
        print(f"{p.device}\t{p.description}\t{p.hwid}")
    if not ports:
        print("no serial ports found (firmware-sim --pty prints its own path)", file=sys.stderr)
    return 0


def cmd_info(dev, args) -> int:
    for k, v in sorted(dev.info.items()):
        if k == "nonce":
            continue
        if k == "trackers" and isinstance(v, list):
            v = f"{len(v)}: " + " ".join(v)
        print(f"{k}: {v}")
    return 0


def cmd_load_model(dev, args) -> int:
    t = time.perf_counter()
    gen = dev.load_model(args.model)
    print(f"model {args.model} committed as generation {gen} "
          f"({(time.perf_counter() - t) * 1e3:.0f} ms)")
    return 0


def cmd_get_model(dev, args) -> int:
    text = dev.get_model()
    if args.out == "-":
        sys.stdout.write(text)
        return 0
    with open(args.out, "w", encoding="utf-8") as f:
        f.write(text)
    from springtrack.model import loads
    m = loads(text, args.out)
    print(f"model {m.name} ({len(m.trackers)} trackers: {m.ids[0]}..{m.ids[-1]}, "
          f"{len(m.connections)} springs, sensor {m.width}x{m.height}) -> {args.out}")
    return 0


def cmd_set(dev, args) -> int:
    for name, value in parse_assignments(args.assignments).items():
        print(f"{name}={value!r}: generation {dev.set(name, value)}")
    return 0


def cmd_get(dev, args) -> int:
    for k, v in dev.get(*args.names).items():
        print(f"{k}={v!r}")
    return 0


def _simple(method):
    def run(dev, args):
        getattr(dev, method)()
        print(f"{method}: ok")
        return 0
    return run


def cmd_stats(dev, args) -> int:
    st = dev.stats()
    if "state" in st:
        print(f"state: {st['state']}" + (f"  (last error: {st['last_error']})"
                                         if st.get("last_error") else ""))
    from .monitor import unfound_line
    if unfound_line(st):
        print(f"acquisition: {unfound_line(st)}")
    for k, v in sorted(st.items()):
        print(f"{k}: {v}")
    for k, v in sorted(dev.link_counters().items()):
        print(f"host.{k}: {v}")
    return 0


def cmd_ping(dev, args) -> int:
    rtt = sorted(dev.ping() * 1e3 for _ in range(args.n))
    print(f"{args.n} pings: min {rtt[0]:.2f} ms, median {rtt[len(rtt) // 2]:.2f} ms, "
          f"max {rtt[-1]:.2f} ms")
    return 0


def cmd_monitor(dev, args) -> int:
    from .monitor import monitor
    return monitor(dev, seconds=args.seconds, smooth=args.smooth, rate=args.rate)


def _why_silent(dev) -> str:
    """Why a device sent no telemetry, from its STATS."""
    from .monitor import why_silent
    try:
        return why_silent(dev.stats())
    except HostctlError as e:
        return f"and its STATS did not answer ({e})"


def cmd_record(dev, args) -> int:
    from .monitor import NOT_FOUND_EXIT, verdict
    from .record import device_ids, save
    from .smooth import Smoother  # noqa: F401 - fail early if filterpy is missing
    snaps, failure = [], None
    if args.start:
        args.until_end = True
        dev.start()                    # this session already receives the telemetry
    try:
        end = time.monotonic() + args.seconds
        while time.monotonic() < end and not (args.until_end and dev.stream_ended):
            snaps += dev.telemetry(seconds=min(0.2, max(0.0, end - time.monotonic())))
        if args.until_end and dev.stream_ended:
            snaps += dev.telemetry(seconds=0.2)     # what the link sent with the notice
    except HostctlError as e:          # the device went away: keep what arrived
        failure = e
    if not snaps and failure is None:
        raise ValueError(f"no telemetry received in {args.seconds:g} s: "
                         f"{_why_silent(dev)}")
    summary = save(args.out, snaps, dev.info, smooth={} if args.smooth else None,
                   ids=lambda n: device_ids(dev, n))
    lc = dev.link_counters()
    print(f"recorded {summary['snapshots']} snapshots x {summary['trackers']} trackers "
          f"to {', '.join(summary['files'])}; lost frames {lc['lost']}, "
          f"CRC errors {lc['crc_errors']}, model-swap drops {summary['dropped']}")
    if failure is not None:
        print(f"hostctl record: error: {failure} (recording ended early)", file=sys.stderr)
        return failure.exit_code
    missing = verdict(dev.stats(), summary["tracked"])
    if missing:
        print(f"hostctl record: {missing}: the recording's rows say so (state column)",
              file=sys.stderr)
        return NOT_FOUND_EXIT
    return 0


VERB_FUNCS = {"info": cmd_info, "load-model": cmd_load_model, "get-model": cmd_get_model,
              "set": cmd_set, "get": cmd_get,
              "start": _simple("start"), "stop": _simple("stop"), "reset": _simple("reset"),
              "acquire": _simple("acquire"), "stats": cmd_stats, "ping": cmd_ping,
              "monitor": cmd_monitor, "record": cmd_record, "shutdown": _simple("shutdown")}


if __name__ == "__main__":
    sys.exit(main())
