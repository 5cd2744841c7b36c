"""Latency from an event to the live view: a sender process stamps synthetic events with
the wall clock (µs since the Unix epoch) and streams them over loopback; this process
reads the stream (springtrack.live), tracks it (grid3x3 on 320 x 240) and logs it to a
Rerun recording (springtrack.view, FILE.rrd); for every frame the view logs, the latency
is the wall clock at the end of the log call minus the newest event's stamp in it (the
oldest waited up to one frame period, 10 ms, longer).  Results replace the "Latency"
section of docs/live.md.

    .venv/bin/python benchmarks/live_latency.py [--transport dv|udp|both] [--seconds 5]
        [--rate 20000]

Measured up to Rerun's recording stream (the SDK's log call returning), not to pixels
on a screen: the viewer's own display adds its frame time.
"""
from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _report import machine, replace_section  # noqa: E402

DOC = ROOT / "docs" / "live.md"
BATCH_S = 0.001               # the sender's batch period (s)
W, H = 320, 240
WRAP = 1 << 32                # the UDP layout's clock range (µs)


def blob(n: int, t_us: int, rng) -> np.ndarray:
    """``n`` events around a point circling the sensor's centre once a second, stamped
    ``t_us`` (the batch's send time)."""
    a = 2 * np.pi * (t_us % 1_000_000) / 1e6
    cx, cy = W / 2 + 60 * np.cos(a), H / 2 + 60 * np.sin(a)
    ev = np.empty(n, [("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])
    ev["t"] = t_us
    ev["x"] = np.clip(rng.normal(cx, 6, n), 0, W - 1)
    ev["y"] = np.clip(rng.normal(cy, 6, n), 0, H - 1)
    ev["p"] = rng.integers(0, 2, n)
    return ev


def send(transport: str, address: str, seconds: float, rate: float) -> None:
    """The sender process: batches of ``rate * BATCH_S`` events every BATCH_S."""
    rng = np.random.default_rng(0)
    per = max(1, int(rate * BATCH_S))
    host, _, port = address.rpartition(":")
    if transport == "dv":
        import dv_processing as dv
        w = dv.io.NetworkWriter(host, int(port), dv.io.Stream.EventStream(0, "events", "synthetic", (W, H)))
        print("listening", flush=True)
        while w.getClientCount() == 0:
            time.sleep(0.01)
    else:
        from springtrack.live import udp
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        print("listening", flush=True)
        time.sleep(1.0)
    end = time.monotonic() + seconds
    nxt = time.monotonic()
    while time.monotonic() < end:
        ev = blob(per, time.time_ns() // 1000, rng)
        if transport == "dv":
            store = dv.EventStore()
            for e in ev:
                store.push_back(int(e["t"]), int(e["x"]), int(e["y"]), bool(e["p"]))
            w.writeEvents(store)
        else:
            s.sendto(udp.encode(ev), (host, int(port)))
        nxt += BATCH_S
        time.sleep(max(0.0, nxt - time.monotonic()))
    if transport == "dv":
        while w.getQueuedPacketCount():
            time.sleep(0.01)
        time.sleep(0.5)
        os._exit(0)           # the writer's destructor waits for its clients to leave
    s.sendto(udp.end_marker(), (host, int(port)))


def receive(url: str, rrd: Path) -> dict:
    from springtrack import live
    from springtrack.geometry import fit_model
    from springtrack.model import load_model
    from springtrack.tracker import Tracker
    from springtrack.view import RerunView

    lat_ms = []

    class Timed(RerunView):
        def frame(self, t_us, st, energies):
            ev = self.pending
            k = int(np.searchsorted(ev["t"], t_us)) - 1
            super().frame(t_us, st, energies)
            now = time.time_ns() // 1000
            if k >= 0:          # modulo the UDP layout's 32-bit clock (both transports)
                lat_ms.append(((now - int(ev["t"][k])) % WRAP) / 1000)

    model = fit_model(load_model("grid3x3"), W, H, "file")
    tr = Tracker(model)
    tr.record(1000)
    view = Timed(str(rrd), tr.models)          # ready before the stream starts
    reader = live.open(url)
    reader.report_to = None
    for chunk in reader:
        view.events(chunk)
        for part in tr.stream(chunk):
            view.track(part)
    view.close()
    return {"lat": np.array(lat_ms), "stats": reader.stats,
            "frames": view.frames}


def run(transport: str, seconds: float, rate: float) -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM if transport == "dv"
                       else socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sender = subprocess.Popen([sys.executable, __file__, "--send", transport,
                               f"127.0.0.1:{port}", "--seconds", str(seconds),
                               "--rate", str(rate)], stdout=subprocess.PIPE, text=True)
    assert sender.stdout.readline().strip() == "listening"
    url = (f"dv://127.0.0.1:{port}" if transport == "dv"
           else f"udp://127.0.0.1:{port}?geometry={W}x{H}&timeout=2")
    with tempfile.TemporaryDirectory() as tmp:
        r = receive(url, Path(tmp) / "view.rrd")
    sender.wait(60)
    lat, st = r["lat"], r["stats"]
    return (f"| {transport} | {rate:,.0f} | {r['frames']} | {np.median(lat):.1f} | "
            f"{np.percentile(lat, 95):.1f} | {lat.max():.1f} | {st.events:,} | {st.batches:,} | "
            f"{st.gaps} |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--transport", choices=["dv", "udp", "both"], default="both")
    p.add_argument("--seconds", type=float, default=5.0, help="streaming time (s)")
    p.add_argument("--rate", type=float, default=20_000, help="events per second")
    p.add_argument("--send", nargs=2, metavar=("TRANSPORT", "HOST:PORT"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.send:
        send(a.send[0], a.send[1], a.seconds, a.rate)
        return 0
    rows = [run(t, a.seconds, a.rate) for t in (["dv", "udp"] if a.transport == "both"
                                                 else [a.transport])]
    cmd = "benchmarks/live_latency.py " + " ".join(argv if argv is not None else sys.argv[1:])
    load = os.getloadavg()[0]
    body = (f"Machine: {machine()}, load average {load:.1f} while measuring (a loaded machine "
            f"stretches the tail).  Command: `.venv/bin/python {cmd.strip()}`.\n\n"
            "| transport | events/s | frames | latency median (ms) | p95 (ms) | max (ms) | "
            "events | batches | gaps |\n|---|---|---|---|---|---|---|---|---|\n"
            + "\n".join(rows) + "\n\nLatency: wall clock when the view's log call for a "
            "frame returns, minus the newest event's send stamp in that frame (same host, "
            "same clock). The frame's oldest events waited up to one frame period (10 ms) "
            "more.")
    print(body)
    replace_section(DOC, "Latency", body, "# Live cameras, streams and the live view\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
