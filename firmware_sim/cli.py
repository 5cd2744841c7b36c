"""``firmware-sim``: the near-sensor loop as a program.

    firmware-sim run --source sim:face_occlusion --max-speed --seconds 5 --preset face26 \\
                     --record out.csv
    firmware-sim run --source replay:rec.raw --realtime --pty
    firmware-sim run --source usb --serial 2766 --model face.toml --listen 127.0.0.1:7700

Without a host link it prints a statistics line every ``--stats-every`` s on stderr and a
final one on stdout; ``--record`` writes every telemetry snapshot in the CSV schema of
``springtrack track`` (``t_us,tracker,x,y,sxx,sxy,syy,activity,active,sensitive``).
Exit status: 0 done, 1 the camera never opened (10 s) or a simulated source failed,
2 bad arguments / no camera found.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from springtrack.commands.track import add_acquire_window

from . import faults as _faults
from . import sources as _sources
from . import usb as camusb

NEVER_OPENED_S = 10.0      # give up if the camera never delivered a transfer this long

EPILOG = """\
sources:  """ + _sources.describe(indent=10) + """
faults:   """ + ", ".join(_faults.FAULT_NAMES) + """ (simulated camera only; docs/firmware.md)
units:    event time in µs; --seconds is event time for sim/replay, wall time for usb.
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="firmware-sim",
                                description="Simulated near-sensor firmware: USB camera -> "
                                            "fused decode+track loop -> host link.")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    r = sub.add_parser("run", help="run the loop on a camera or a simulated camera",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("--source", required=True, metavar="URL", help=_sources.usage())
    r.add_argument("--serial", type=int, help="usb: the camera's serial (default: the first)")
    r.add_argument("--profile", choices=list(camusb.PROFILES),
                   help="the camera's kind (word format): usb and sim: default ccam_atis; the "
                        "EVT profiles are Prophesee-style EVKs whose stream the vendor tools "
                        "started (docs/firmware.md); replay: default the file's own words, "
                        "else the file re-encoded for this camera")
    r.add_argument("--geometry", metavar="WxH",
                   help="usb with an EVT profile: the sensor's size in px (default: the "
                        "profile's, e.g. evt3 1280x720)")
    r.add_argument("--roi", metavar="X,Y,W,H",
                   help="track only the events of this region of the sensor (px); the others "
                        "are counted (outside_roi)")
    m = r.add_mutually_exclusive_group()
    m.add_argument("--model", help="shape model TOML file")
    m.add_argument("--preset", help="preset model name (face26, grid3x3)")
    m.add_argument("--learn-first-ms", type=float, metavar="MS",
                   help="learn the model from the stream's first MS ms of event time "
                        "(springtrack learn; docs/learning.md), then track with it from "
                        "where the window ends; --params are written into the learned model")
    r.add_argument("--params", help="TOML file of parameter overrides")
    r.add_argument("--sensor-from", choices=["source", "model"],
                   help="a model whose [sensor] is not the camera's is refused; 'source': "
                        "use it on the camera's sensor (trackers where they are), 'model': "
                        "keep its sensor (events outside it skipped and counted); applies "
                        "to uploaded models too")
    r.add_argument("--backend", default="cython", choices=["cython", "fixed", "mcu"],
                   help="tracker kernel: float64 'cython' (default), the integer-only "
                        "'fixed' kernel of docs/fixed_point.md (positions Q.32 px), or 'mcu': "
                        "that kernel's Cortex-M4 build run in an emulator (docs/mcu.md; slow, "
                        "for correctness tests; needs pip install 'springtrack[mcu]')")
    r.add_argument("--acquire", action="store_true",
                   help="find the model in the events instead of trusting its positions, "
                        "detect its loss and find it again (docs/acquisition.md); the host "
                        "triggers a new search with `hostctl acquire`")
    add_acquire_window(r)
    sp = r.add_mutually_exclusive_group()
    sp.add_argument("--realtime", action="store_true",
                    help="simulated camera releases events at their timestamps (default)")
    sp.add_argument("--max-speed", action="store_true",
                    help="simulated camera serves data as fast as the loop takes it "
                         "(lossless: the reader waits for a free buffer instead of dropping)")
    r.add_argument("--faults", default="", help="comma-separated fault names to inject")
    r.add_argument("--seconds", type=float, help="duration (default: the scene's / file's)")
    r.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    r.add_argument("--telemetry-us", type=int, default=1000, metavar="US",
                   help="telemetry / record period in µs of event time (default 1000)")
    r.add_argument("--record", metavar="OUT.csv", help="write every snapshot as a track CSV")
    r.add_argument("--bias", action="append", default=[], metavar="NAME=VALUE",
                   help="usb/sim: set a CCam bias (0..255), repeatable")
    r.add_argument("--stats-every", type=float, default=1.0, metavar="S",
                   help="print statistics every S wall seconds on stderr (0: never)")
    r.add_argument("--buffers", type=int, default=64,
                   help="transfer buffers of 128 KiB in the pool (default 64)")
    link = r.add_mutually_exclusive_group()
    link.add_argument("--pty", action="store_true",
                      help="serve the host link on a new pty (prints 'pty: /dev/pts/N')")
    link.add_argument("--port", metavar="URL", help="serve the host link on a pyserial URL")
    link.add_argument("--listen", metavar="HOST:PORT",
                      help="serve the host link on TCP (prints 'listen: socket://HOST:PORT')")
    r.add_argument("--key-file", help="HMAC key file for the host link (docs/protocol.md)")
    r.add_argument("--wait-start", action="store_true",
                   help="with a host link: open the camera only when the host sends START "
                        "(e.g. after uploading a model), instead of at once")
    return p


def parse_biases(items) -> dict:
    out = {}
    for it in items:
        name, sep, val = it.partition("=")
        if not sep:
            raise ValueError(f"--bias {it!r}: expected NAME=VALUE")
        try:
            out[name.strip()] = int(val, 0)
        except ValueError:
            raise ValueError(f"--bias {it!r}: value must be an integer") from None
    camusb.check_biases(out)
    return out


def parse_ints(text: str | None, n: int, sep: str, what: str) -> tuple[int, ...] | None:
    """``text`` as ``n`` integers separated by ``sep`` (None stays None)."""
    if text is None:
        return None
    parts = text.lower().split(sep)
    try:
        vals = tuple(int(v) for v in parts)
    except ValueError:
        vals = ()
    if len(vals) != n:
        raise ValueError(f"{what} {text!r}: expected {n} integers separated by {sep!r}")
    return vals


def open_source(args, biases: dict) -> _sources.CameraSource:
    """The camera ``--source`` names.  ``biases`` is read at every (re)connection, so the
    engine's updates survive a reconnect."""
    return _sources.open_source(args.source, _sources.SourceOptions(
        seconds=args.seconds, seed=args.seed, realtime=not args.max_speed, faults=args.faults,
        serial=args.serial, profile=args.profile, biases=biases,
        geometry=parse_ints(args.geometry, 2, "x", "--geometry")))


def default_model(args, source: _sources.CameraSource):
    """--model or --preset; with --learn-first-ms a one-tracker placeholder that tracks
    nothing (the learned model replaces it); else the source's own model (a scene's); else face26, centred
    on the source's sensor."""
    if args.model or args.preset:
        return args.model or args.preset
    if args.learn_first_ms is not None:
        from springtrack.model import ShapeModel, TrackerSpec
        w, h = source.width, source.height
        return ShapeModel("learning", w, h, [TrackerSpec("p00", w / 2, h / 2, (4.0, 0.0, 4.0))],
                          [])
    try:
        own = source.default_model()
    except ValueError as e:
        raise ValueError(f"{e}; give --model or --preset") from None
    if own is not None:
        return own
    from springtrack.model import face26
    w, h = source.width, source.height
    print(f"model: the face26 preset centred on the {w}x{h} sensor (no --model given)",
          file=sys.stderr, flush=True)
    return face26(cx=w / 2, cy=h / 2, width=w, height=h)


def read_key(path):
    if not path:
        return None
    with open(path, "rb") as f:
        key = f.read().strip()
    if not key:
        raise ValueError(f"{path}: empty key file")
    return key


def start_link(args, engine, stop):
    """Start the host link thread if asked; returns (thread, port) or (None, None)."""
    if not (args.pty or args.port or args.listen):
        return None, None
    from . import link, transport
    key = read_key(args.key_file)
    if args.pty:
        port = transport.PtyPort()
        transport.announce_pty(port)
    elif args.port:
        port = transport.open_port(args.port)
    else:
        host, _, p = args.listen.rpartition(":")
        server = transport.TcpServer(host or "127.0.0.1", int(p), key=key)
        print(f"listen: {server.url}", flush=True)

        def accept_loop():
            while not stop.is_set():
                conn = server.accept(0.2)
                if conn is not None:
                    link.serve(conn, engine, key=key, stop_event=stop)
                    conn.close()
            server.close()
        t = threading.Thread(target=accept_loop, name="host-link", daemon=True)
        t.start()
        return t, None
    t = threading.Thread(target=lambda: link.serve(port, engine, key=key, stop_event=stop),
                         name="host-link", daemon=True)
    t.start()
    return t, port


def run(args) -> int:
    from .loop import FirmwareLoop
    # three Python threads (reader, processing, link) share the GIL: hand it over every
    # 0.5 ms instead of 5 ms so the processing thread is never starved for long
    sys.setswitchinterval(0.0005)
    # SIGTERM ends the run like Ctrl-C: threads stopped, --record written, stats printed
    signal.signal(signal.SIGTERM, _terminate)
    biases = parse_biases(args.bias)
    roi = parse_ints(args.roi, 4, ",", "--roi")
    source = open_source(args, biases)
    for line in source.notes:
        print(line, file=sys.stderr, flush=True)
    cam = source.device
    engine = FirmwareLoop(source.open_camera, model=default_model(args, source),
                          params=args.params, telemetry_period_us=args.telemetry_us,
                          nbuf=args.buffers, record=bool(args.record),
                          lossless=cam is not None and args.max_speed, biases=biases,
                          profile=source.profile, backend=args.backend, roi=roi,
                          source_counters=source.counters, sensor_from=args.sensor_from,
                          acquire=_acquire(args), learn_first_ms=args.learn_first_ms,
                          learn_params=learn_params(args))
    stop = threading.Event()
    link_thread, port = start_link(args, engine, stop)
    if args.wait_start and link_thread is None:
        raise ValueError("--wait-start needs a host link (--pty, --port or --listen)")
    if not args.wait_start:
        engine.start()
    t0 = time.monotonic()
    next_stats = t0 + args.stats_every if args.stats_every > 0 else float("inf")
    quiet = 0
    failed = None
    learn_said = False
    try:
        while True:
            time.sleep(0.02)
            now = time.monotonic()
            while engine.reader.log:              # disconnects, reconnects, stalls
                print(f"usb: {engine.reader.log.popleft()}", file=sys.stderr, flush=True)
            learn_said = learn_said or _say_learned(engine)
            if now >= next_stats and link_thread is None:
                print(engine.stats_line(), file=sys.stderr, flush=True)
                next_stats = now + args.stats_every
            if engine.reader.counts["transfers"] == 0 and now - t0 > NEVER_OPENED_S \
                    and engine.reader.state == "reconnecting":
                failed = f"the camera never opened in {NEVER_OPENED_S:g} s: {engine.reader.last_error}"
                break
            if cam is not None:
                if cam.finished and engine.caught_up():
                    quiet += 1
                    if quiet >= 3:
                        break
                else:
                    quiet = 0
            elif args.seconds is not None and now - t0 >= args.seconds:
                break
        if link_thread is not None:
            _wait_telemetry_sent(engine, link_thread)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
    finally:
        stop.set()
        engine.stop()
        if link_thread is not None:
            link_thread.join(3)
        if port is not None:
            port.close()
    if not learn_said:
        _say_learned(engine)
    if args.record:
        rows = engine.write_record(args.record)
        print(f"record: {rows} rows -> {args.record}", file=sys.stderr)
    for line in source.report():
        print(line, file=sys.stderr)
    if failed is None and _sources.failure(source):
        failed = f"the source {args.source} failed: {_sources.failure(source)}"
    print("stats: " + engine.stats_line(), flush=True)
    if failed:
        print(f"firmware-sim run: error: {failed}", file=sys.stderr)
        return 1
    return 0


def learn_params(args) -> dict | None:
    """With --learn-first-ms: the --params file's tracking parameters, to be written into
    the learned model (the firmware then runs with them)."""
    if args.learn_first_ms is None or not args.params:
        return None
    from springtrack.commands.learn import read_params
    return read_params(args.params)


def _say_learned(engine) -> bool:
    """Print what the learner found once it has (stderr); True once said."""
    le = engine.stats()["learn"]
    if not le or le["state"] == "learning":
        return False
    if le["state"] == "failed":
        print(f"learn: {le['error']}; tracking nothing until a model is uploaded",
              file=sys.stderr, flush=True)
    else:
        print(f"learn: {le['report']}", file=sys.stderr, flush=True)
    return True


def _wait_telemetry_sent(engine, link_thread, timeout: float = 30.0) -> None:
    """End of stream with a host link: let the link forward what the engine still holds
    (it holds snapshots until a host says HELLO) before shutting down."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and link_thread.is_alive():
        if not engine.has_output():
            time.sleep(0.2)                    # the link's last writes
            return
        time.sleep(0.02)


def _terminate(signum, frame):
    raise KeyboardInterrupt


def _acquire(args):
    """The slot's acquisition settings from --acquire*, or None."""
    if not args.acquire:
        return None
    from springtrack.commands.track import acquire_bounds
    return {"acquire_ms": args.acquire_ms, "bounds": acquire_bounds(args)}


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return run(args)
    except (ValueError, OSError, camusb.CameraError) as e:
        print(f"firmware-sim {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
