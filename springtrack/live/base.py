"""What every live stream shares: the reader interface of ``springtrack.io`` over batches
that arrive, and the counts that say how the stream went.

A handler's poll returns a :class:`Batch` (events, or a note that nothing came); the
:class:`LiveReader` turns them into checked EVENT_DTYPE chunks, counts events, batches and
gaps (the stream silent for longer than ``gap_s`` of wall time, then resumed), and when the
stream ends -- its sender closed it, the connection dropped, it stayed silent for
``timeout_s`` -- ends the iteration cleanly and says why in ``stats.ended``, printing one
summary line to ``report_to`` (stderr by default; None: silent).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from urllib.parse import parse_qsl

import numpy as np

from ..events import EVENT_DTYPE, EventError, as_events

GAP_S = 0.5              # a silence longer than this (s of wall time) counts as a gap
POLL_S = 0.0005          # wait between polls of a stream with nothing ready (s)


class StreamOptionError(ValueError):
    """A live URL's option (``?name=value``) is unknown or malformed."""


@dataclass
class LiveStats:
    """How a live stream went: ``events`` and ``batches`` received, ``gaps`` (silences
    longer than ``gap_s`` after which the stream resumed), ``reconnects``, ``bad_bytes``
    (payload that was not whole events, dropped), ``ended`` (why it stopped, None while
    running), ``wall_s`` from connection to end."""
    source: str
    events: int = 0
    batches: int = 0
    gaps: int = 0
    reconnects: int = 0
    bad_bytes: int = 0
    longest_silence_s: float = 0.0
    ended: str | None = None
    wall_s: float = 0.0
    extra: dict = field(default_factory=dict)

    # the counters every reader's stats show (springtrack.io.DecodeStats' names)
    @property
    def words(self) -> int:
        return self.batches

    @property
    def pending_bytes(self) -> int:
        return 0

    @property
    def anomalies(self) -> dict:
        return {"bad_bytes": self.bad_bytes}

    @property
    def info(self) -> dict:
        return {"gaps": self.gaps, "reconnects": self.reconnects}

    def warning(self, source) -> str | None:
        """A warning line naming what the stream dropped (payload that was not whole
        events), or None if nothing was: every command that reads events prints it."""
        if not self.bad_bytes:
            return None
        return (f"warning: {source}: {self.bad_bytes:,} bytes of the stream were not whole "
                f"events and were dropped; what they cost is not in the output")

    def check_decodable(self, source) -> None:
        """A live stream is never refused for its dropped bytes (a camera's stream may
        recover): they are counted in ``bad_bytes`` and named by :meth:`warning`."""

    def summary(self) -> str:
        more = "".join(f" {k}={v}" for k, v in self.extra.items())
        return (f"stream {self.source}: events={self.events} batches={self.batches} "
                f"gaps={self.gaps} reconnects={self.reconnects} bad_bytes={self.bad_bytes}"
                f"{more} longest_silence_s={self.longest_silence_s:.3f} "
                f"wall_s={self.wall_s:.3f} ended: {self.ended or 'still running'}")


MAX_COALESCE = 64        # packets ready at once that one poll joins into one chunk


@dataclass
class Batch:
    """One poll of a stream: ``events`` (a structured array with fields t, x, y, p of any
    numeric types; None: nothing ready now) from ``packets`` of the sender's packets
    (a reader that fell behind joins the packets waiting, up to MAX_COALESCE, so its cost
    per event falls as its backlog grows), ``ended`` (why the stream is over, or None)."""
    events: np.ndarray | None = None
    ended: str | None = None
    bad_bytes: int = 0
    packets: int = 1


def joined(parts: list) -> np.ndarray:
    """One array of ``parts`` (a list of event arrays)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def options(url: str, query: str, known: dict) -> dict:
    """The ``?name=value&...`` options of ``url`` converted by ``known`` (name ->
    (converter, default)); StreamOptionError naming an unknown or malformed one."""
    out = {k: d for k, (_, d) in known.items()}
    for k, v in parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)):
        if k not in known:
            raise StreamOptionError(f"{url}: unknown option {k!r}; known: {', '.join(known)}")
        try:
            out[k] = known[k][0](v)
        except ValueError as e:
            raise StreamOptionError(f"{url}: option {k}={v!r}: {e}") from None
    return out


def positive_seconds(v: str) -> float:
    s = float(v)
    if not s >= 0:
        raise ValueError("must be a number of seconds >= 0")
    return s


class LiveReader:
    """A live event stream with the interface of ``springtrack.io.Reader``: ``path`` (the
    URL), ``format``, ``width``/``height`` (from the stream's metadata; None if it has
    none), ``header``, ``chunks()`` / iteration, ``read()``, ``stats`` (:class:`LiveStats`),
    ``size_hint`` None.  Read once, front to back."""

    def __init__(self, url: str, fmt: str, width: int | None, height: int | None, poll,
                 header: dict | None = None, gap_s: float = GAP_S, close=None):
        self.path = url
        self.format = fmt
        self.width = width
        self.height = height
        self.header = dict(header or {})
        self.event_type = None
        self.options = {}
        self.offset = 0
        self.size_hint = None
        self.stats = LiveStats(url)
        self.report_to = sys.stderr
        self.gap_s = gap_s
        self._poll = poll
        self._close = close
        self._used = False

    def __repr__(self):
        return f"<LiveReader {self.path} format={self.format} geometry={self.width}x{self.height}>"

    def __iter__(self):
        return self.chunks()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        if self._close is not None:
            self._close()
            self._close = None

    def chunks(self, nbytes: int | None = None):
        """Yield each non-empty batch as an EVENT_DTYPE array as it arrives, until the
        stream ends (``stats.ended`` says why).  ``nbytes`` is accepted for the file
        readers' interface; a live batch is as large as its sender made it."""
        if self._used:
            raise RuntimeError(f"{self.path}: a live stream is read once")
        self._used = True
        st = self.stats
        start = last = time.perf_counter()
        try:
            while True:
                b = self._poll()
                st.bad_bytes += b.bad_bytes
                if b.events is not None and len(b.events):
                    now = time.perf_counter()
                    silent = now - last
                    if st.batches and silent > self.gap_s:
                        st.gaps += 1
                    if st.batches:
                        st.longest_silence_s = max(st.longest_silence_s, silent)
                    last = now
                    try:
                        ev = as_events(b.events)
                    except EventError as e:
                        raise EventError(e.index, f"{self.path}: batch {st.batches + 1}: "
                                                  f"{e.detail}") from None
                    st.batches += b.packets
                    st.events += len(ev)
                    yield ev
                elif b.ended is not None:
                    st.ended = b.ended
                    return
                elif b.events is None:
                    time.sleep(POLL_S)
        finally:
            st.wall_s = time.perf_counter() - start
            if st.ended is None:
                st.ended = "the reader stopped reading"
            self.close()
            if self.report_to is not None:
                print(st.summary(), file=self.report_to, flush=True)

    def read(self, nbytes: int | None = None) -> np.ndarray:
        parts = list(self.chunks())
        return np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)
