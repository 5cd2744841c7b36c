"""``firmware-sim``: the near-sensor loop as a program.

    firmware-sim run --source sim:face_occlusion --max-speed --seconds 5 --preset face26 \\
                     --record out.csv
    firmware-sim run --source replay:rec.raw --realtime --pty
    firmware-sim run --source usb --serial 2766 --model face.toml --listen 127.0.0.1:7700

Without a host link it prints a statistics line every ``--stats-every`` s on stderr and a
final one on stdout, and ends with the source; ``--record`` writes every telemetry
snapshot in the CSV schema of ``springtrack track``
(``t_us,tracker,x,y,sxx,sxy,syy,activity,vx,vy,active,sensitive``).  With a host link it serves
the link until a host sends SHUTDOWN (``hostctl shutdown``) or it gets SIGTERM / Ctrl-C:
at the end of the source the loop goes idle (the hosts get a NOTICE) and START replays it.
Exit status: 0 done, 1 the camera never opened (10 s) or a simulated source failed,
2 bad arguments / no camera found / unreadable source.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from springtrack import wire
from springtrack.wire import Fault
from springtrack.commands import options
from springtrack.commands.options import add_acquire_window, add_backend_argument

from . import faults as _faults
from . import sources as _sources
from . import camera as camusb
from .supervise import Supervisor
from .throttle import Throttle

NEVER_OPENED_S = 10.0      # give up if the camera never delivered a transfer this long
SHUTDOWN_S = 1.0           # every thread is given this long to stop
LINK_DRAIN_S = 0.3         # telemetry still forwarded to the hosts when stopping
PORT_RETRY_S = 1.0         # a serial port that failed is opened again after this

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
    m.add_argument("--model", help="shape model: TOML file or preset name (as --preset)")
    m.add_argument("--preset", help="preset model name (face26, grid3x3)")
    m.add_argument("--learn-first-ms", type=float, metavar="MS",
                   help="learn the model from the stream's first MS ms of event time "
                        "(springtrack learn; docs/learning.md), then track with it from "
                        "where the window ends; --params are written into the learned model")
    r.add_argument("--params", help="TOML file of parameter overrides (its [learn] table: "
                                    "the learner's, with --learn-first-ms)")
    options.add_learn_arguments(r)
    r.add_argument("--sensor-from", choices=["source", "file", "model"],
                   help="a model whose [sensor] is not the camera's is refused; 'source' "
                        "(or 'file', as in springtrack track): use it on the camera's sensor "
                        "(trackers where they are), 'model': keep its sensor (events "
                        "outside it skipped and counted); applies to uploaded models too")
    add_backend_argument(r, firmware=True)
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
    r.add_argument("--seconds", type=float,
                   help="duration in seconds (default: the scene's / file's)")
    r.add_argument("--seed", type=int, default=0,
                   help="simulation seed, and of --dequantize's order (default 0)")
    r.add_argument("--telemetry-us", type=int, default=1000, metavar="US",
                   help="telemetry / record period in µs of event time (default 1000)")
    r.add_argument("--record", metavar="OUT.csv", help="write every snapshot as a track CSV")
    r.add_argument("--bias", action="append", default=[], metavar="NAME=VALUE",
                   help="usb/sim: set a CCam bias (0..255), repeatable")
    r.add_argument("--stats-every", type=float, default=1.0, metavar="S",
                   help="print statistics every S wall seconds on stderr (0: never)")
    r.add_argument("--buffers", type=int, default=64,
                   help="transfer buffers of 128 KiB in the pool (default 64)")
    r.add_argument("--rt-priority", type=int, metavar="N",
                   help="run the firmware's threads under Linux SCHED_FIFO at priority N "
                        "(1..99; needs root or CAP_SYS_NICE) while tracking: keeps other "
                        "programs from delaying the USB reader and the tracking loop on a "
                        "busy machine (default: ordinary scheduling)")
    link = r.add_mutually_exclusive_group()
    link.add_argument("--pty", action="store_true",
                      help="serve the host link on a new pty (prints 'pty: /dev/pts/N')")
    link.add_argument("--port", metavar="URL", help="serve the host link on a pyserial URL")
    link.add_argument("--listen", metavar="HOST:PORT",
                      help="serve the host link on TCP (prints 'listen: socket://HOST:PORT')")
    r.add_argument("--key-file", help="HMAC key file for the host link (at least 16 bytes; "
                                      "docs/protocol.md)")
    r.add_argument("--wait-start", action="store_true",
                   help="with a host link: open the camera only when the host sends START "
                        "(e.g. after uploading a model), instead of at once")
    options.add_prep_arguments(r, seed=False)
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
        geometry=parse_ints(args.geometry, 2, "x", "--geometry"), prepare=_prepare(args)))


def _prepare(args):
    """The replay's preparation from the recording-quirk options (springtrack track's), or
    None; refused for a source that is not a recording."""
    if not options.wanted(args):
        return None
    if not args.source.startswith("replay:"):
        raise ValueError(f"--start-us, --end-us, --dequantize and --burst-fraction prepare a "
                         f"recording: use them with --source replay:FILE, not {args.source}")
    options.preparer(args, 1, 1)       # its errors now, naming the values
    return lambda w, h: options.preparer(args, w, h)


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
    """The ``--key-file`` key (``springtrack.wire.read_key_file``), or None."""
    if not path:
        return None
    try:
        return wire.read_key_file(path)
    except ValueError as e:
        raise ValueError(f"--key-file {e}") from None


class Link:
    """The host link thread of ``--pty`` / ``--port`` / ``--listen``, supervised: an
    unexpected exception is reported through the engine and the link restarted; a serial
    port that fails is opened again."""

    def __init__(self, args, engine, key, stop: threading.Event, on_shutdown):
        from . import link, transport
        self.port = self.server = None
        self.stop = stop
        if args.pty:
            self.port = transport.PtyPort()
            transport.announce_pty(self.port)
        elif args.port:
            self.port = transport.open_port(args.port)
        else:
            host, p = parse_listen(args.listen)
            self.server = transport.TcpServer(host, p, key=key)
            print(f"listen: {self.server.url}", flush=True)
        if self.server is not None:
            self.hub = link.Hub(engine, key, on_shutdown=on_shutdown)
            link._switch(0.0005)
            body = lambda: self.hub.serve_tcp(self.server, stop, drain_s=LINK_DRAIN_S)  # noqa: E731
        else:
            self.session = link.LinkServer(self.port, engine, key=key, on_shutdown=on_shutdown)
            self.hub = self.session.hub
            body = self._serve_port
        target = engine.supervisor.thread_target("host-link", body, stop, max_faults=None)
        self.thread = threading.Thread(target=target, name="host-link", daemon=True)
        self.url = args.port
        self.thread.start()

    def _serve_port(self) -> None:
        from . import transport
        while not self.stop.is_set():
            self.session.serve(self.stop, drain_s=LINK_DRAIN_S)
            if self.stop.is_set() or not self.url:
                return
            self.hub.log("port", f"{self.url}: {self.session.closed_reason}; reopening in "
                                 f"{PORT_RETRY_S:g} s")
            if self.stop.wait(PORT_RETRY_S):
                return
            try:
                self.port.close()
                self.port = self.session.port = transport.open_port(self.url)
                self.session.fd = self.session.port.fileno()
            except OSError as e:
                self.session.closed_reason = str(e)

    def close(self, timeout: float) -> None:
        from .transport import PtyPort
        self.stop.set()
        self.thread.join(timeout)
        if isinstance(self.port, PtyPort):
            self.port.close(linger=timeout)      # the host reads its last frames first
        elif self.port is not None:
            self.port.close()
        if self.server is not None:
            self.server.close()


def run(args) -> int:
    """``firmware-sim run``; returns the exit status."""
    # three Python threads (reader, processing, link) share the GIL: hand it over every
    # 0.5 ms instead of 5 ms so the processing thread is never starved for long
    sys.setswitchinterval(0.0005)
    # SIGTERM and SIGHUP (a closed terminal) end the run like Ctrl-C: threads stopped,
    # --record closed, stats printed
    handlers = {sig: signal.signal(sig, _terminate)
                for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
    try:
        return _run(args)
    finally:
        for sig, h in handlers.items():
            signal.signal(sig, h)


def _run(args) -> int:
    from .loop import FirmwareLoop
    biases = parse_biases(args.bias)
    roi = parse_ints(args.roi, 4, ",", "--roi")
    has_link = bool(args.pty or args.port or args.listen)
    if args.listen:
        parse_listen(args.listen)                 # a bad port before anything starts
    if args.wait_start and not has_link:
        raise ValueError("--wait-start needs a host link (--pty, --port or --listen)")
    key = read_key(args.key_file)
    source = open_source(args, biases)
    for line in source.notes:
        print(line, file=sys.stderr, flush=True)
    cam = source.device
    engine = FirmwareLoop(source.open_camera, model=default_model(args, source),
                          params=args.params, telemetry_period_us=args.telemetry_us,
                          nbuf=args.buffers, record=args.record or False,
                          lossless=cam is not None and args.max_speed, biases=biases,
                          profile=source.profile, backend=args.backend, roi=roi,
                          source_counters=source.counters, sensor_from=args.sensor_from,
                          supervisor=Supervisor(), rewind=source.rewind,
                          acquire=_acquire(args), learn_first_ms=args.learn_first_ms,
                          learn_params=learn_params(args), learner=learner_params(args),
                          rt_priority=args.rt_priority)
    throttle = Throttle()             # the program's own log lines
    stop = threading.Event()          # ends the link
    quit_now = threading.Event()      # a host sent SHUTDOWN
    link = Link(args, engine, key, stop, quit_now.set) if has_link else None
    if not args.wait_start:
        engine.start()
    t0 = time.monotonic()
    next_stats = t0 + args.stats_every if args.stats_every > 0 else float("inf")
    quiet = 0
    failed = None
    learn_said = False
    try:
        while not quit_now.is_set():
            time.sleep(0.02)
            now = time.monotonic()
            _print_logs(engine, throttle)
            learn_said = learn_said or _say_learned(engine)
            if now >= next_stats and link is None:
                print(engine.stats_line(), file=sys.stderr, flush=True)
                next_stats = now + args.stats_every
            if engine.reader.counts["transfers"] == 0 and now - t0 > NEVER_OPENED_S \
                    and engine.reader.state == "reconnecting":
                failed = f"the camera never opened in {NEVER_OPENED_S:g} s: {engine.reader.last_error}"
                break
            if cam is not None:
                if engine.running and cam.finished and engine.caught_up():
                    quiet += 1
                    if quiet >= 3:
                        if link is None:
                            engine.end_of_stream()      # a search still running ends
                            break
                        quiet = 0
                        _end_of_stream(engine, source)
                else:
                    quiet = 0
            elif args.seconds is not None and now - t0 >= args.seconds:
                break
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
    finally:
        _ignore_signals()             # a second signal must not cut the shutdown short
        t_stop = time.monotonic()
        stop.set()
        slow = []
        try:
            engine.stop(SHUTDOWN_S)
        except RuntimeError as e:
            slow.append(str(e))
        if link is not None:
            link.close(SHUTDOWN_S)
            if link.thread.is_alive():
                slow.append(f"host-link thread did not stop within {SHUTDOWN_S:g} s")
        _print_logs(engine, throttle)
        for line in throttle.unshown() + ([] if link is None else
                                           [f"link: {x}" for x in link.hub.throttle.unshown()]):
            print(line, file=sys.stderr)
        print(f"shutdown: threads stopped in {(time.monotonic() - t_stop) * 1e3:.0f} ms"
              + (f" ({'; '.join(slow)})" if slow else ""), file=sys.stderr, flush=True)
    if not learn_said:
        _say_learned(engine, args.learn_first_ms)
    if args.record:
        engine.recorder.close()
        print(engine.recorder.summary(), file=sys.stderr)
    for line in source.report():
        print(line, file=sys.stderr)
    if failed is None and _sources.failure(source):
        failed = f"the source {args.source} failed: {_sources.failure(source)}"
    print("stats: " + engine.stats_line(), flush=True)
    if failed:
        print(f"firmware-sim run: error: {failed}", file=sys.stderr)
        return 1
    return 0


def _end_of_stream(engine, source) -> None:
    """With a host link the program outlives its source: the loop goes idle and says so;
    a source that failed is reported (ERROR source_failed)."""
    engine.end_of_stream()
    why = _sources.failure(source)
    if why:
        engine.supervisor.report(Fault.SOURCE_FAILED, f"the source {source.url} failed: {why}")


def _print_logs(engine, throttle) -> None:
    """USB state changes and supervision reports on stderr, at most one line of a kind (its
    first two words: ``error nonfinite_state``, ``open failed``) per second."""
    for prefix, log in (("usb", engine.reader.log), ("firmware", engine.supervisor.log)):
        while log:
            text = log.popleft()
            line = throttle(" ".join([prefix, *text.split()[:2]]), f"{prefix}: {text}")
            if line is not None:
                print(line, file=sys.stderr, flush=True)


def learn_params(args) -> dict | None:
    """With --learn-first-ms: the --params file's tracking parameters, to be written into
    the learned model (the firmware then runs with them)."""
    if args.learn_first_ms is None or not args.params:
        return None
    from springtrack.commands.options import read_params
    return read_params(args.params)


def learner_params(args) -> dict | None:
    """With --learn-first-ms: the learner's parameters (--params [learn], --learn-param)."""
    if args.learn_first_ms is None:
        if args.learn_param:
            raise ValueError("--learn-param needs --learn-first-ms (the device learns nothing "
                             "without it)")
        return None
    from springtrack.commands.options import learn_params as read
    return read(args)


def _say_learned(engine, window_ms: float | None = None) -> bool:
    """Print what the learner found once it has (stderr); True once said.  With
    ``window_ms`` (the run ends) a learner still learning says so: nothing was tracked."""
    le = engine.stats()["learn"]
    if le and le["state"] == "learning" and window_ms is not None:
        print(f"learn: the source ended within --learn-first-ms {window_ms:g} "
              f"({le['events']:,} events held): no model learned, nothing tracked",
              file=sys.stderr, flush=True)
        return True
    if not le or le["state"] == "learning":
        return False
    if le["state"] == "failed":
        print(f"learn: {le['error']}; tracking nothing until a model is uploaded",
              file=sys.stderr, flush=True)
    else:
        print(f"learn: {le['report']}", file=sys.stderr, flush=True)
    return True


def parse_listen(value: str) -> tuple[str, int]:
    """``--listen HOST:PORT`` (or ``:PORT``) as (host, port); a ValueError names the option."""
    host, _, p = value.rpartition(":")
    try:
        port = int(p)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise ValueError(f"--listen {value!r}: give HOST:PORT with a port in 0..65535 (0: any "
                         f"free port)")
    return host or "127.0.0.1", port


def _terminate(signum, frame):
    raise KeyboardInterrupt


def _ignore_signals() -> None:
    """The shutdown runs once: signals from now on are ignored (``run`` restores them)."""
    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)


def _acquire(args):
    """The slot's acquisition settings from --acquire*, or None."""
    if not args.acquire:
        return None
    from springtrack.commands.options import acquire_bounds
    return {"acquire_ms": args.acquire_ms, "bounds": acquire_bounds(args),
            "budget_ms": args.acquire_budget_ms}


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
    except KeyboardInterrupt:         # before the run started
        print(f"firmware-sim {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
