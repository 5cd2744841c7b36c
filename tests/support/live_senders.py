"""Senders of live event streams for the tests, run as separate processes:

    python tests/support/live_senders.py dv PORT FILE [--cut N] [--linger S]
    python tests/support/live_senders.py udp HOST:PORT FILE [--per-datagram N] [--cut N]

``dv``: a dv-processing NetworkWriter on 127.0.0.1:PORT serving FILE's events (read with
dv-processing's own AEDAT 4 reader), as DV's TCP output does; it prints "listening",
waits for a client, sends every batch (or the batches up to N events: a stream cut
mid-way), waits for its queue to drain, lingers S seconds (a sender that closes at once
may reset the connection before the client read its last packets) and exits.
``udp``: FILE's events (any format springtrack.io reads) as aestream-layout datagrams
(springtrack.live.udp) to HOST:PORT, paced, then the end marker (no end marker with
--cut: the receiver's timeout ends it).
"""
from __future__ import annotations

import argparse
import os
import socket
import sys
import time


def free_port(kind=socket.SOCK_STREAM) -> int:
    """A port free on 127.0.0.1 now (for the next process to bind)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve_dv(port: int, path: str, cut: int | None, linger: float) -> None:
    import dv_processing as dv
    rec = dv.io.MonoCameraRecording(path)
    stream = dv.io.Stream.EventStream(0, "events", rec.getCameraName(), rec.getEventResolution())
    writer = dv.io.NetworkWriter("127.0.0.1", port, stream)
    print("listening", flush=True)
    while writer.getClientCount() == 0:
        time.sleep(0.01)
    sent = 0
    while rec.isRunning() and (cut is None or sent < cut):
        batch = rec.getNextEventBatch()
        if batch is not None:
            writer.writeEvents(batch)
            sent += len(batch)
    while writer.getQueuedPacketCount():
        time.sleep(0.01)
    print(f"sent {sent}", flush=True)
    time.sleep(linger)
    os._exit(0)       # the writer's destructor waits for its clients to leave


def send_udp(address: str, path: str, per: int, cut: int | None, pace_s: float) -> None:
    from springtrack import io as stio
    from springtrack.live import udp
    host, _, port = address.rpartition(":")
    ev = stio.open(path).read()
    ev = ev if cut is None else ev[:cut]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for d in udp.datagrams(ev, per):
            s.sendto(d, (host, int(port)))
            time.sleep(pace_s)
        if cut is None:
            s.sendto(udp.end_marker(), (host, int(port)))
    print(f"sent {len(ev)}", flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("kind", choices=["dv", "udp"])
    p.add_argument("address")
    p.add_argument("file")
    p.add_argument("--cut", type=int)
    p.add_argument("--linger", type=float, default=0.5)
    p.add_argument("--per-datagram", type=int, default=512)
    p.add_argument("--pace-s", type=float, default=0.001)
    a = p.parse_args(argv)
    if a.kind == "dv":
        serve_dv(int(a.address), a.file, a.cut, a.linger)
    else:
        send_udp(a.address, a.file, a.per_datagram, a.cut, a.pace_s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
