"""Host-link benchmarks: sustained face26 telemetry at 1 kHz over a pty, model upload round
trip, command round trip p50/p99.  Results replace the "Host link" section of
docs/benchmarks.md.

    .venv/bin/python benchmarks/link.py [--seconds 60] [--target firmware-sim|test-engine]

``--target firmware-sim`` (default when ``firmware-sim run`` exists) starts
``firmware-sim run --source sim:face_occlusion --pty`` as a separate process;
``test-engine`` starts a process serving the link with the Tracker-backed engine of
tests/support/engine.py (the same firmware_sim.link server, a simpler tracking loop).
"""
from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from hostctl import Device  # noqa: E402
from springtrack.process_end import end_child  # noqa: E402

SECTION = "## Host link"
TEST_ENGINE = """
import sys, threading
sys.path.insert(0, {tests!r})
from support.engine import SimEngine
from firmware_sim import link, transport
port = transport.PtyPort()
eng = SimEngine(seconds={scene_s}).run()
transport.announce_pty(port)
link.serve(port, eng, stop_event=threading.Event())
"""


def firmware_cmd(target: str, source=("--source", "sim:face_occlusion"), seconds: float = 80.0,
                 scene_s: float = 2.0) -> list[str]:
    if target == "firmware-sim":
        exe = ROOT / ".venv" / "bin" / "firmware-sim"
        return [str(exe), "run", "--stats-every", "0", *source, "--seconds", f"{seconds:g}",
                "--pty"]
    return [sys.executable, "-c", TEST_ENGINE.format(tests=str(ROOT / "tests"), scene_s=scene_s)]


def default_target() -> str:
    return "firmware-sim" if (ROOT / "firmware_sim" / "cli.py").exists() and \
        (ROOT / "firmware_sim" / "loop.py").exists() else "test-engine"


class Firmware:
    """A firmware process on a pty; ``.path`` is the pty to connect to."""

    def __init__(self, target: str, timeout: float = 60.0, **kw):
        self.proc = subprocess.Popen(firmware_cmd(target, **kw), stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, cwd=ROOT)
        line = self.proc.stdout.readline()
        m = re.match(r"pty: (\S+)", line)
        if not m:
            err = self.proc.stderr.read() if self.proc.poll() is not None else ""
            self.close()
            raise RuntimeError(f"firmware did not announce its pty: {line!r} {err}")
        self.path = m.group(1)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> None:
        end_child(self.proc, grace_s=5)


def load_average() -> str:
    try:
        return " ".join(open("/proc/loadavg").read().split()[:3])
    except OSError:
        return "?"


def machine() -> str:
    model = "unknown"
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        model = re.search(r"Model name:\s*(.+)", out).group(1).strip()
    except (OSError, AttributeError):
        pass
    return f"{model}, {os.cpu_count()} cores, Python {platform.python_version()}"


def bench_telemetry(dev: Device, seconds: float) -> dict:
    dev.start()
    list(dev.telemetry(seconds=0.5))                   # settle
    lost0, n, t_first, t_last = dev.rx_seq.lost, 0, None, None
    gaps = 0
    prev = None
    t0 = time.monotonic()
    for s in dev.telemetry(seconds=seconds):
        n += 1
        t_first = s.t_us if t_first is None else t_first
        t_last = s.t_us
        if prev is not None and s.t_us - prev != 1000:
            gaps += 1
        prev = s.t_us
    wall = time.monotonic() - t0
    fw = dev.stats()
    return dict(seconds=wall, snapshots=n, rate_hz=n / wall, lost_frames=dev.rx_seq.lost - lost0,
                event_time_gaps=gaps, event_time_s=(t_last - t_first) / 1e6 if n else 0,
                crc_errors=dev.reader.counts["crc_errors"],
                firmware_tx_dropped=fw.get("link.tx_dropped", -1),
                engine_telemetry_dropped=fw.get("loop.telemetry_dropped", -1),
                transfers_dropped=fw.get("transfers_dropped", -1))


def bench_upload(dev: Device, n: int = 20) -> dict:
    ms = []
    for k in range(n):
        t = time.perf_counter()
        dev.load_model("face26" if k % 2 else "grid3x3")
        ms.append((time.perf_counter() - t) * 1e3)
    return dict(p50_ms=float(np.percentile(ms, 50)), p99_ms=float(np.percentile(ms, 99)),
                max_ms=max(ms), n=n)


def bench_latency(dev: Device, n: int = 1000, names=("ping", "param_set", "param_get")) -> dict:
    out = {}
    verbs = {"ping": dev.ping, "param_set": lambda: dev.set(energy_gain=0.05),
             "param_get": lambda: dev.get("alpha_position")}
    for name, fn in ((k, verbs[k]) for k in names):
        ms = []
        for _ in range(n):
            t = time.perf_counter()
            fn()
            ms.append((time.perf_counter() - t) * 1e3)
        out[name] = dict(p50_ms=float(np.percentile(ms, 50)), p99_ms=float(np.percentile(ms, 99)))
    return out


def bench_monitor(dev: Device, seconds: float = 3.0) -> dict:
    """Redraw rate of ``hostctl monitor --smooth`` (output to a buffer) during streaming."""
    import io
    from hostctl.monitor import monitor
    buf = io.StringIO()
    t = time.monotonic()
    monitor(dev, seconds=seconds, smooth=True, out=buf)          # the CLI's default rate
    frames = buf.getvalue().count("\x1b[H\x1b[2J")
    return dict(redraw_hz=frames / (time.monotonic() - t))


def write_section(text: str, section: str = SECTION) -> None:
    """Replace (or append) this script's own ``## ...`` section of docs/benchmarks.md."""
    path = ROOT / "docs" / "benchmarks.md"
    doc = path.read_text() if path.exists() else "# Benchmarks\n"
    start = doc.find(section + "\n")
    if start >= 0:
        end = doc.find("\n## ", start + len(section))
        doc = doc[:start] + text + (doc[end + 1:] if end >= 0 else "")
    else:
        doc = doc.rstrip("\n") + "\n\n" + text
    path.write_text(doc.rstrip("\n") + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--target", choices=("firmware-sim", "test-engine"), default=default_target())
    ap.add_argument("--no-write", action="store_true", help="do not update docs/benchmarks.md")
    args = ap.parse_args(argv)
    fw = Firmware(args.target, seconds=args.seconds + 20)
    load0 = load_average()
    try:
        with Device(fw.path) as dev:
            tele = bench_telemetry(dev, args.seconds)
            busy = bench_latency(dev, 300, names=("ping",))["ping"]
            up_busy = bench_upload(dev, 10)
            mon = bench_monitor(dev)
            dev.stop()
            up = bench_upload(dev)
            lat = bench_latency(dev)
    finally:
        fw.close()
    cmd = f".venv/bin/python benchmarks/link.py --seconds {args.seconds:g} --target {args.target}"
    text = "\n".join([
        SECTION, "",
        f"Machine: {machine()}.  Command: `{cmd}` ({time.strftime('%Y-%m-%d')}); firmware = "
        f"`{args.target}` in its own process (sim:face_occlusion, realtime), host = "
        f"`hostctl.Device`, both ends over one pty.  Load average (1/5/15 min) at start "
        f"{load0}, at end {load_average()} (the machine is shared).  Round trips of host "
        f"commands over the link, host to firmware and back; the event-to-telemetry latency "
        f"is the \"Firmware loop\" section's.", "",
        "| measure | result |", "|---|---|",
        f"| face26 telemetry, {tele['seconds']:.1f} s wall | {tele['snapshots']} snapshots = "
        f"{tele['rate_hz']:.1f} Hz, lost frames {tele['lost_frames']}, event-time gaps "
        f"{tele['event_time_gaps']} ({tele['event_time_s']:.1f} s of event time), CRC errors "
        f"{tele['crc_errors']}, link tx dropped {tele['firmware_tx_dropped']}, snapshots dropped "
        f"by the firmware's queue {tele['engine_telemetry_dropped']}, USB transfers dropped "
        f"{tele['transfers_dropped']} |",
        f"| model upload round trip (face26/grid3x3 alternately, {up['n']}x; BEGIN + pipelined "
        f"chunks + COMMIT), tracker stopped | p50 {up['p50_ms']:.1f} ms, p99 {up['p99_ms']:.1f} ms, "
        f"max {up['max_ms']:.1f} ms |",
        f"| the same while tracking and streaming 1 kHz telemetry ({up_busy['n']}x) | "
        f"p50 {up_busy['p50_ms']:.1f} ms, p99 {up_busy['p99_ms']:.1f} ms, "
        f"max {up_busy['max_ms']:.1f} ms |",
        *(f"| command round trip {k} (1000x, tracker stopped) | p50 {v['p50_ms']:.2f} ms, "
          f"p99 {v['p99_ms']:.2f} ms |" for k, v in lat.items()),
        f"| command round trip ping (300x) during 1 kHz telemetry | p50 {busy['p50_ms']:.2f} ms, "
        f"p99 {busy['p99_ms']:.2f} ms |",
        f"| `monitor --smooth` redraw rate during 1 kHz telemetry (default 12/s, spec >= 10 Hz) | "
        f"{mon['redraw_hz']:.1f} Hz |",
        ""])
    print(text)
    if not args.no_write:
        write_section(text)
    return 0 if tele["lost_frames"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
