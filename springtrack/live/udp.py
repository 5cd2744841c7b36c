"""``udp://HOST:PORT``: an event stream in UDP datagrams, in aestream's packet layout.

The layout (aestream's UDP output, ``aestream output udp HOST PORT``): little-endian
32-bit words, one or two per event::

    word 0:  bit 31 NO_TIME | bits 30-16 x | bit 15 polarity | bits 14-0 y
    word 1:  t, µs (uint32), present when NO_TIME is 0

A datagram holds whole events of one kind (its first word's NO_TIME says which); a word
of the other kind, or bytes that are not a whole event, are dropped and counted
(``bad_bytes``).  Timestamps wrap every 2**32 µs (71.6 min): a step back by more than
half that range is a wrap and is unwrapped; a smaller one is kept (the tracker skips and
counts events that go back in time).  Events without timestamps are stamped with the
receiver's clock, µs since the stream's first datagram.

The layout carries no geometry: give it as ``?geometry=WxH`` (else it is unknown, as for a
``.npy`` file).  UDP has no connection: the stream ends on an empty datagram (a marker of
springtrack's senders, :func:`end_marker`; aestream sends none) or after ``?timeout=S``
seconds without a datagram once one has come (default 5; 0: never).  Nothing numbers the
datagrams, so a datagram lost on the way cannot be counted: keep the sender on the same
host or a quiet link, and see ``gaps`` (silences) in the counts.
"""
from __future__ import annotations

import socket
import time

import numpy as np

from .base import GAP_S, MAX_COALESCE, Batch, LiveReader, joined, options, positive_seconds

USAGE = "udp://HOST:PORT"
HELP = ("events in UDP datagrams, aestream's layout (docs/live.md): listen on HOST:PORT; "
        "?geometry=WxH gives the sensor size, ?timeout=S ends the stream after S s "
        "without a datagram (default 5)")

NO_TIME = np.uint32(1 << 31)
X_SHIFT = 16
X_MASK = 0x7FFF
Y_MASK = 0x7FFF
POLARITY = np.uint32(1 << 15)
WRAP = 1 << 32
MAX_DATAGRAM = 65507          # the largest UDP payload over IPv4
RECV_BUFFER = 8 << 20         # socket receive buffer asked for (bytes), against bursts
WAIT_S = 0.05                 # longest wait for a datagram in one poll (s)


def geometry(v: str) -> tuple[int, int]:
    w, sep, h = v.lower().partition("x")
    if not sep or not w.isdigit() or not h.isdigit() or int(w) < 1 or int(h) < 1:
        raise ValueError("must be WxH in pixels, e.g. 640x480")
    if int(w) > X_MASK + 1 or int(h) > Y_MASK + 1:
        raise ValueError(f"the layout addresses at most {X_MASK + 1}x{Y_MASK + 1} pixels")
    return int(w), int(h)


OPTIONS = {"geometry": (geometry, None), "timeout": (positive_seconds, 5.0),
           "gap": (positive_seconds, GAP_S)}


def encode(events, timestamps: bool = True) -> bytes:
    """Events (fields t, x, y, p) as the words of one or more datagrams; times kept modulo
    2**32 µs (``timestamps=False``: no times, the receiver stamps them)."""
    ev = np.asarray(events)
    w0 = ((ev["x"].astype(np.uint32) & X_MASK) << X_SHIFT) | (ev["y"].astype(np.uint32) & Y_MASK)
    w0 |= np.where(ev["p"] > 0, POLARITY, np.uint32(0)).astype(np.uint32)
    if not timestamps:
        return (w0 | NO_TIME).astype("<u4").tobytes()
    out = np.empty((len(ev), 2), "<u4")
    out[:, 0] = w0
    out[:, 1] = (ev["t"].astype(np.int64) % WRAP).astype(np.uint32)
    return out.tobytes()


def datagrams(events, per_datagram: int = 1024, timestamps: bool = True):
    """The datagrams that send ``events``, ``per_datagram`` events each."""
    for s in range(0, len(events), per_datagram):
        yield encode(events[s:s + per_datagram], timestamps)


def end_marker() -> bytes:
    """The empty datagram that ends a stream at a springtrack receiver."""
    return b""


class Decoder:
    """Datagrams -> events, with the time base kept across them (wraps unwrapped)."""

    def __init__(self):
        self.last = None          # last timestamp, unwrapped (µs)
        self.clock0 = None        # receiver clock at the first datagram (s)

    def decode(self, data: bytes, now: float) -> tuple[np.ndarray, int]:
        """(events with fields t, x, y, p, bytes dropped) of one datagram received at
        ``now`` (s, monotonic)."""
        if self.clock0 is None:
            self.clock0 = now
        whole = len(data) - len(data) % 4
        words = np.frombuffer(data, "<u4", whole // 4)
        bad = len(data) - whole
        if not len(words):
            return np.empty(0, _FIELDS), bad
        if words[0] & NO_TIME:
            keep = (words & NO_TIME) != 0
            w0 = words[keep]
            bad += 4 * int(len(words) - len(w0))
            t = np.full(len(w0), int((now - self.clock0) * 1e6), np.int64)
        else:
            pairs = len(words) // 2
            bad += 4 * (len(words) - 2 * pairs)
            w0, ts = words[0:2 * pairs:2], words[1:2 * pairs:2]
            keep = (w0 & NO_TIME) == 0
            bad += 8 * int(pairs - keep.sum())
            w0, ts = w0[keep], ts[keep]
            t = self._unwrap(ts.astype(np.int64))
        out = np.empty(len(w0), _FIELDS)
        out["t"] = t
        out["x"] = (w0 >> X_SHIFT) & X_MASK
        out["y"] = w0 & Y_MASK
        out["p"] = (w0 & POLARITY) != 0
        return out, bad

    def _unwrap(self, ts: np.ndarray) -> np.ndarray:
        """uint32 µs times -> int64, a step back by more than half the range a wrap."""
        if not len(ts):
            return ts
        prev = np.empty_like(ts)
        prev[0] = ts[0] if self.last is None else self.last % WRAP
        prev[1:] = ts[:-1]
        wraps = np.cumsum(ts - prev < -(WRAP // 2))
        base = 0 if self.last is None else self.last - self.last % WRAP
        t = ts + base + wraps * WRAP
        self.last = int(t[-1])
        return t


_FIELDS = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])


def parse_address(target: str, url: str) -> tuple[str, int, str]:
    """(host, port, query) of ``//HOST:PORT[?options]``."""
    hostport, _, query = target[2:].partition("?") if target.startswith("//") else ("", "", "")
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise ValueError(f"{url}: give the address to listen on as udp://HOST:PORT "
                         f"(e.g. udp://0.0.0.0:3333)")
    return host.strip("[]") or "0.0.0.0", int(port), query


def listen(host: str, port: int, url: str) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if opt is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, RECV_BUFFER)
            break
        except OSError:
            continue
    try:
        sock.bind((host, port))
    except OSError as e:
        sock.close()
        raise ConnectionError(f"{url}: cannot listen on {host}:{port}: {e.strerror}") from None
    sock.settimeout(WAIT_S)
    return sock


def open(target: str, url: str) -> LiveReader:             # noqa: A001
    host, port, query = parse_address(target, url)
    opts = options(url, query, OPTIONS)
    sock = listen(host, port, url)
    dec = Decoder()
    state = {"last": None}

    def poll() -> Batch:
        parts, bad, ended = [], 0, None
        sock.settimeout(WAIT_S)
        while len(parts) < MAX_COALESCE:
            try:
                data = sock.recv(MAX_DATAGRAM)
            except (socket.timeout, BlockingIOError):
                break
            now = time.monotonic()
            if not data:
                ended = "the sender's end marker (an empty datagram)"
                break
            state["last"] = now
            ev, b = dec.decode(data, now)
            parts.append(ev)
            bad += b
            sock.settimeout(0)            # then only what is already waiting
        if parts:                         # the end marker, if any, ends the next poll
            state["ended"] = ended
            return Batch(joined(parts), bad_bytes=bad, packets=len(parts))
        last = state["last"]
        if ended or state.get("ended"):
            return Batch(ended=ended or state["ended"], bad_bytes=bad)
        if last is not None and opts["timeout"] and time.monotonic() - last > opts["timeout"]:
            return Batch(ended=f"no datagram for {opts['timeout']:g} s (?timeout)", bad_bytes=bad)
        return Batch(bad_bytes=bad)

    w, h = opts["geometry"] or (None, None)
    reader = LiveReader(url, "udp", w, h, poll, gap_s=opts["gap"], close=sock.close,
                        header={"address": sock.getsockname()[:2],
                                "geometry_source": "the URL's ?geometry" if w else None})
    return reader
