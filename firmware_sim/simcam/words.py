"""What the simulated camera puts on the bus: encoded event words with release marks.

A :class:`Chunk` is a piece of the device's output stream: its bytes, and for each prefix
the event time from which the device may send it (``marks_t[i]``: bytes
``[0, marks_off[i])`` may go out once the device clock reaches ``marks_t[i]``).
``ENCODERS`` maps the device's word format to the function that makes chunks of events.
"""
from __future__ import annotations

import importlib
from functools import partial

import numpy as np

from springtrack.events import as_events, make
from springtrack.io.ccam import encode as ccam_encode

CCAM_PERIOD_SHIFT = 11       # one CCam time-high word per 2048 us period


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


def stream_chunk(events, fmt: str) -> Chunk | None:
    """A Prophesee EVT 2.0 / 3.0 stream as one chunk, released when its last event is due
    (the springtrack.io encoders start every call from time-high 0, so a stream is encoded
    in one piece)."""
    ev = as_events(events)
    if len(ev) == 0:
        return None
    enc = importlib.import_module(f"springtrack.io.{fmt}").encode
    data = bytearray(enc(ev))
    return Chunk(data, ev["t"][-1:].copy(), np.array([len(data)], np.int64), len(ev))


# device word format -> events -> Chunk | None
ENCODERS = {
    "ccam": ccam_chunk,
    "evt2": partial(stream_chunk, fmt="evt2"),
    "evt3": partial(stream_chunk, fmt="evt3"),
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
