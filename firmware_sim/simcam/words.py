"""What the simulated camera puts on the bus: encoded event words with release marks.

A :class:`Chunk` is a piece of the device's output stream: its bytes, and for each prefix
the event time from which the device may send it (``marks_t[i]``: bytes
``[0, marks_off[i])`` may go out once the device clock reaches ``marks_t[i]``).

``ENCODERS`` maps the device's word format to a factory of its encoder (events -> Chunk):
the CCam ATIS (each event's word released at its own time) or a Prophesee-style EVK
streaming EVT 2.0, 2.1 or 3.0 (:class:`StreamEncoder`: the stream continued chunk by chunk,
each 512-byte USB packet released when its last event is due, :func:`packet_chunk`).
Bytes that are already words (a recording replayed as it is) become chunks through
:func:`packet_chunk` as well.
"""
from __future__ import annotations

import importlib
from functools import partial

import numpy as np

from springtrack.events import as_events, make
from springtrack.io import decoder as io_decoder
from springtrack.io.ccam import encode as ccam_encode

CCAM_PERIOD_SHIFT = 11       # one CCam time-high word per 2048 us period
PACKET = 512                 # bytes of a high-speed bulk packet: the release unit of EVKs


class Chunk:
    """Encoded words; ``marks_t[i]``: bytes ``[0, marks_off[i])`` may be sent once the
    device clock reaches ``marks_t[i]``."""
    __slots__ = ("data", "marks_t", "marks_off", "pos", "n_events")

    def __init__(self, data, marks_t, marks_off, n_events):
        self.data = data
        self.marks_t = marks_t
        self.marks_off = marks_off
        self.pos = 0
        self.n_events = n_events


def ccam_chunk(events) -> Chunk | None:
    """CCam ATIS words of ``events``, each event's word released at its own time."""
    ev = as_events(events)
    if len(ev) == 0:
        return None
    th = ev["t"] >> CCAM_PERIOD_SHIFT
    new = np.ones(len(ev), np.int64)
    new[1:] = th[1:] != th[:-1]
    off = 4 * (np.arange(1, len(ev) + 1) + np.cumsum(new))
    data = bytearray(ccam_encode(ev))
    if len(data) != off[-1]:
        raise RuntimeError(f"ccam encode produced {len(data)} bytes, expected {off[-1]} "
                           "(one time-high word per new 2048 us period): layout changed?")
    return Chunk(data, ev["t"].copy(), off, len(ev))


def packet_chunk(data, decoder, t_floor: int | None = None) -> tuple[Chunk | None, int]:
    """Words ``data`` (of a stream that ``decoder``, a springtrack.io streaming decoder,
    has followed up to here) as a Chunk released packet by packet: each 512-byte packet once
    the device clock reaches the latest event time completed so far (at least ``t_floor``,
    the previous chunk's last mark).  Returns (chunk or None if ``data`` is empty, the last
    mark)."""
    data = bytearray(data)
    n = len(data)
    if n == 0:
        return None, t_floor
    npk = -(-n // PACKET)
    marks_t = np.empty(npk, np.int64)
    marks_off = np.minimum(np.arange(1, npk + 1, dtype=np.int64) * PACKET, n)
    view = memoryview(data)
    last = t_floor
    events = 0
    for i in range(npk):
        ev = decoder.decode(view[i * PACKET:(i + 1) * PACKET])
        if len(ev):
            events += len(ev)
            t = int(ev["t"].max())
            last = t if last is None else max(last, t)
        marks_t[i] = -(1 << 62) if last is None else last
    if last is not None:
        marks_t[marks_t < -(1 << 61)] = marks_t[marks_t >= -(1 << 61)].min()
    return Chunk(data, marks_t, marks_off, events), last


class StreamEncoder:
    """A Prophesee-style EVK's bulk stream: event arrays -> Chunks of ``fmt`` words
    (``evt2``, ``evt21``, ``evt3``; ``legacy``: EVT 2.1 in the IMX636 order), each array
    continuing the stream of the previous ones (``springtrack.io.<fmt>.encode(...,
    prev_t=...)``)."""

    def __init__(self, fmt: str, legacy: bool = False):
        enc = importlib.import_module(f"springtrack.io.{fmt}").encode
        self.encode = partial(enc, legacy=legacy) if fmt == "evt21" else enc
        self.marks = io_decoder(fmt, **({"legacy": legacy} if fmt == "evt21" else {}))
        self.prev_t = None
        self.last_mark = None

    def __call__(self, events) -> Chunk | None:
        ev = as_events(events)
        if len(ev) == 0:
            return None
        data = self.encode(ev, prev_t=self.prev_t)
        self.prev_t = int(ev["t"][-1])
        chunk, self.last_mark = packet_chunk(data, self.marks, self.last_mark)
        chunk.n_events = len(ev)
        return chunk


def _ccam_encoder(legacy: bool = False):
    if legacy:
        raise ValueError("legacy word order applies to EVT 2.1, not to CCam words")
    return ccam_chunk


# device word format -> factory(legacy) of its encoder: events -> Chunk | None
ENCODERS = {
    "ccam": _ccam_encoder,
    "evt2": partial(StreamEncoder, "evt2"),
    "evt21": partial(StreamEncoder, "evt21"),
    "evt3": partial(StreamEncoder, "evt3"),
}


def burst_chunks(t0: int, t1: int, rate: float, seed: int = 0, width=304, height=240):
    """Noise events at ``rate``/s over [t0, t1) as CCam words, one chunk per time-high
    period (2048 us).

    One period of noise is encoded once; each period reuses its event words after its own
    time-high word, so a burst far above the processing rate costs the simulated camera
    almost nothing."""
    rng = np.random.default_rng(seed)
    period = 1 << CCAM_PERIOD_SHIFT
    per = max(1, int(rate * 2048e-6))          # events per period
    one = make(np.sort(rng.integers(0, period, per)), rng.integers(0, width, per),
               rng.integers(0, height, per), rng.integers(0, 2, per))
    words = ccam_encode(one)                   # time-high 0, then the events of one period
    if len(words) != 4 * (per + 1):
        raise RuntimeError("ccam encode: expected one time-high word per 2048 us period")
    body = words[4:]
    for th in range(t0 >> CCAM_PERIOD_SHIFT, ((t1 - 1) >> CCAM_PERIOD_SHIFT) + 1):
        t_th = th << CCAM_PERIOD_SHIFT
        head = ccam_encode(make([t_th], [0], [0], [0]))[:4]     # that period's time-high word
        data = bytearray(head + body)
        yield Chunk(data, np.array([t_th], np.int64), np.array([len(data)], np.int64), per)
