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
    hostctl --port /dev/pts/5 record OUT.csv|OUT.npz [--start] [--seconds S] [--until-end] [--smooth]

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
from dataclasses import dataclass
from typing import Callable

from springtrack import wire
from springtrack.view import add_arguments as add_view_arguments
from springtrack.wire import Role

from .device import Device, HostctlError


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
    for name, verb in VERBS.items():
        sp = sub.add_parser(name, help=verb.help)
        if verb.arguments is not None:
            verb.arguments(sp)
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
        verb = VERBS[args.verb]
        if not verb.device:
            return int(verb.run(args) or 0)
        if not args.port:
            raise HostctlError("no port given: use --port URL or set HOSTCTL_PORT "
                               "(see `hostctl ports`)")
        with Device(args.port, timeout=args.timeout, retries=args.retries,
                    key=read_key(args.key_file), role=Role[args.role.upper()]) as dev:
            return int(verb.run(dev, args) or 0)
    except HostctlError as e:
        print(f"hostctl {args.verb}: error: {e}", file=sys.stderr)
        return e.exit_code
    except (ValueError, OSError) as e:
        print(f"hostctl {args.verb}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


def cmd_ports(args) -> int:
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
    values = parse_assignments(args.assignments)
    for name, gen in dev.set_all(values).items():           # all or nothing
        print(f"{name}={values[name]!r}: generation {gen}")
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
    view = None
    if args.view:
        from springtrack import view as live_view
        from springtrack.model import load_model
        view = live_view.open(args.view, load_model(args.model) if args.model else None,
                              name="hostctl monitor", every_us=args.view_every_us)
    try:
        return monitor(dev, seconds=args.seconds, smooth=args.smooth, rate=args.rate, view=view)
    finally:
        if view is not None:
            view.close()
            print(f"view: {view.frames} frames -> {args.view}", file=sys.stderr)


def _monitor_arguments(sp) -> None:
    _arguments(
        ("--seconds", dict(type=float, default=None, help="stop after S seconds")),
        ("--smooth", dict(action="store_true", help="add Kalman-smoothed velocities")),
        ("--rate", dict(type=float, default=12.0, help="redraws per second (12)")))(sp)
    add_view_arguments(sp)
    sp.add_argument("--model", metavar="MODEL",
                    help="with --view: the device's model (TOML file or preset) to draw its "
                         "springs and name its instances")


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
    from . import drops
    snaps, failure = [], None
    dev0, host0 = drops.device_counters(dev), drops.host_counters(dev)
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
    lost = drops.span(dev0, drops.device_counters(dev) if failure is None else None,
                      host0, drops.host_counters(dev))
    text, warn = drops.summary(lost, summary["snapshots"])
    print(f"recorded {summary['snapshots']} snapshots x {summary['trackers']} trackers "
          f"to {', '.join(summary['files'])}; {text}; model-swap drops {summary['dropped']}")
    if warn:
        print(f"hostctl record: warning: the recording is incomplete: {text}", file=sys.stderr)
    if failure is not None:
        print(f"hostctl record: error: {failure} (recording ended early)", file=sys.stderr)
        return failure.exit_code
    missing = verdict(dev.stats(), summary["tracked"])
    if missing:
        print(f"hostctl record: {missing}: the recording's rows say so (state column)",
              file=sys.stderr)
        return NOT_FOUND_EXIT
    return 0


def cmd_demo(args) -> int:
    from .demo import run_demo
    return run_demo(args)


def _demo_arguments(sp) -> None:
    from .demo import add_arguments
    add_arguments(sp)


def _arguments(*specs):
    """A parser filler adding ``specs``: (flags or name, add_argument keywords) pairs."""
    def add(sp):
        for flags, kw in specs:
            sp.add_argument(*((flags,) if isinstance(flags, str) else flags), **kw)
    return add


@dataclass(frozen=True)
class Verb:
    help: str
    run: Callable                   # (args) without a device, else (dev, args) -> exit code
    arguments: Callable | None = None   # adds the verb's own options to its sub-parser
    device: bool = True             # opens --port first


# the one table of hostctl's verbs, in --help order
VERBS: dict[str, Verb] = {
    "ports": Verb("list serial ports", cmd_ports, device=False),
    "demo": Verb("end-to-end demo: simulated camera -> firmware-sim -> this host, scored and "
                 "drawn", cmd_demo, _demo_arguments, device=False),
    "info": Verb("firmware/protocol versions, geometry, model", cmd_info),
    "load-model": Verb("upload a model (preset name or TOML file)", cmd_load_model,
                       _arguments(("model", {}))),
    "get-model": Verb("download the model the device runs (uploaded, learned or its own) "
                      "as TOML", cmd_get_model,
                      _arguments(("out", dict(metavar="OUT.toml",
                                              help="file to write (- for standard output)")))),
    "set": Verb("set parameters NAME=VALUE ...", cmd_set,
                _arguments(("assignments", dict(nargs="+", metavar="NAME=VALUE")))),
    "get": Verb("show parameters (all if none named)", cmd_get,
                _arguments(("names", dict(nargs="*")))),
    "start": Verb("start tracking (after the source ended: replay it)", _simple("start")),
    "stop": Verb("stop tracking", _simple("stop")),
    "reset": Verb("reset the trackers to the model, clear the faulted state", _simple("reset")),
    "acquire": Verb("search for the model in the events again (a firmware started with "
                    "--acquire)", _simple("acquire")),
    "stats": Verb("firmware and link counters", cmd_stats),
    "shutdown": Verb("end the firmware program", _simple("shutdown")),
    "ping": Verb("command round-trip times", cmd_ping,
                 _arguments(("-n", dict(type=int, default=10)))),
    "monitor": Verb("live view of the trackers (12 redraws/s; --view: in Rerun)", cmd_monitor,
                    _monitor_arguments),
    "record": Verb("record telemetry to OUT.csv or OUT.npz", cmd_record, _arguments(
        ("out", {}),
        ("--seconds", dict(type=float, default=10.0, help="duration (10)")),
        ("--until-end", dict(action="store_true",
                             help="stop early when the device says its source has no more "
                                  "data")),
        ("--start", dict(action="store_true",
                         help="start the device once recording (from its first event; a "
                              "replay that ended is replayed), and stop when its source ends "
                              "(implies --until-end): a short replay is captured whole")),
        ("--smooth", dict(action="store_true",
                          help="add smoothed positions and velocities (npz arrays / "
                               ".smooth.csv)")))),
}

if __name__ == "__main__":
    sys.exit(main())
