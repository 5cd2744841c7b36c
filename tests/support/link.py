"""A link server on a real pty or socket in a background thread, and raw frame reading."""
from __future__ import annotations

import threading
import time
import serial
from firmware_sim import link, transport
from springtrack import wire
from springtrack.wire import MsgType


class Served:
    """A link server on a port in a background thread (stopped on exit)."""

    def __init__(self, engine, port=None, key=None):
        self.engine = engine
        self.port = port or transport.PtyPort()
        self.stop = threading.Event()
        self.server = link.LinkServer(self.port, engine, key=key)
        self.thread = threading.Thread(target=self.server.serve, args=(self.stop,), daemon=True)
        self.thread.start()

    @property
    def path(self):
        return self.port.path

    def close(self):
        self.stop.set()
        self.thread.join(3)
        assert not self.thread.is_alive()
        self.port.close()


def raw_host(path):
    return serial.serial_for_url(path, timeout=0.5)


def read_frames(port, want, timeout=2.0):
    r = wire.FrameReader()
    got = []
    end = time.monotonic() + timeout
    while len(got) < want and time.monotonic() < end:
        got += [f for f in r.feed(port.read(max(1, port.in_waiting)))
                if f.type not in (MsgType.HEARTBEAT, MsgType.TELEMETRY, MsgType.APPLIED)]
    return got


class TcpServed:
    """A link hub serving TCP connections in a background thread; ``lines``: its log."""

    def __init__(self, engine, key=None, **limits):
        self.engine = engine
        self.srv = transport.TcpServer("127.0.0.1", 0, key=key)
        self.url = self.srv.url
        self.lines: list[str] = []
        self.hub = link.Hub(engine, key, log=self.lines.append)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.hub.serve_tcp, args=(self.srv, self.stop),
                                       kwargs=limits, daemon=True)
        self.thread.start()

    def close(self):
        self.stop.set()
        self.thread.join(5)
        assert not self.thread.is_alive()
        self.srv.close()
        self.engine.close()
