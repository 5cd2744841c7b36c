"""Preparing a recording's events for learning or tracking: a time window, a filter of
full-frame bursts and the de-quantisation of coarse timestamps (docs/learning.md).

Some recordings need it before anything can follow their objects.  ``dvs.es``, the
Event Stream example file, has timestamps in 1 ms ticks with the events of a tick in
row order, and a burst of ON events from every pixel at t = 0: as delivered, a tracker
sees each tick as a sweep from the top row down, and the burst throws it off at once.

    >>> ev, stats = springtrack.prep.prepare(events, 320, 240, start_us=1000,
    ...                                      dequantize=True)      # doctest: +SKIP
    >>> p = Preparer(320, 240, dequantize=True)                    # doctest: +SKIP
    >>> for chunk in reader: track(p.feed(chunk))                  # doctest: +SKIP
    >>> track(p.finish()); p.stats                                 # doctest: +SKIP

Definitions:

* **tick**: the timestamps' quantum, detected from the data (:func:`tick_us`): the
  greatest common divisor of the gaps between distinct timestamps (1 µs for a sensor's
  own clock, 1000 µs for ``dvs.es``);
* **window** ``[start_us, end_us)`` on the recorded timestamps (whole ticks);
* **burst**: a tick (or a ``BURST_BIN_US`` bin when the tick is finer) in which at least
  ``burst_fraction`` of the sensor's pixels fire; its events are dropped and counted;
* **de-quantisation**: a tick stamped T is taken to cover [T, T + tick): its n events
  get the times T + floor(k tick / n), k = 0 .. n-1, in a random order drawn from
  ``seed`` and the tick's own time (a hash, so the result does not depend on how the
  stream is cut into chunks), instead of their row order.

The preparation never reorders events across timestamps: events that come back in time
stay where they are (a tracker skips and counts them).  :class:`Preparer` holds back the events until it has seen ``DETECT_MIN_TIMES`` distinct
timestamps (to detect the tick), then the last, possibly incomplete, tick (or burst
bin) of each chunk until the next chunk or :meth:`Preparer.finish`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .events import EVENT_DTYPE, as_events

BURST_BIN_US = 1000            # burst bins when the tick is finer than this
DEFAULT_BURST_FRACTION = 0.5   # of the sensor's pixels firing within one bin
DETECT_MIN_TIMES = 16          # distinct timestamps seen before the tick is detected
BURST_TIMES_KEPT = 16          # burst bins whose start time the stats keep

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def _splitmix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64's output function on uint64 (wrapping arithmetic)."""
    with np.errstate(over="ignore"):
        z = z + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
        return z ^ (z >> np.uint64(31))


def tick_us(t: np.ndarray) -> int:
    """The timestamps' quantum (µs): the gcd of the gaps between distinct timestamps
    (1 if there are fewer than two).  ``t`` need not be sorted."""
    u = np.unique(np.asarray(t, np.int64))
    if len(u) < 2:
        return 1
    return max(1, int(np.gcd.reduce(np.diff(u))))


@dataclass
class PrepStats:
    """What :class:`Preparer` did, in events unless named otherwise."""
    events_in: int = 0
    events_out: int = 0
    outside_window: int = 0
    burst_events: int = 0
    burst_bins: int = 0
    tick_us: int = 0                    # 0 until detected
    dequantized: bool = False
    burst_at_us: list = field(default_factory=list)    # the first bursts' bin start times

    def summary(self) -> str:
        parts = [f"tick={self.tick_us} us" + (" (dequantized)" if self.dequantized else "")]
        if self.outside_window:
            parts.append(f"outside window {self.outside_window:,}")
        if self.burst_events:
            parts.append(f"burst {self.burst_events:,} in {self.burst_bins} bin(s)")
        return ", ".join(parts)


class Preparer:
    """Streaming preparation (see the module docstring): ``feed(chunk)`` returns the
    prepared events that are complete, ``finish()`` the rest; ``stats`` counts."""

    def __init__(self, width: int, height: int, start_us: int | None = None,
                 end_us: int | None = None, dequantize: bool = False,
                 burst_fraction: float | None = DEFAULT_BURST_FRACTION, seed: int = 0,
                 tick: int | None = None):
        if width < 1 or height < 1:
            raise ValueError(f"prep: sensor size must be positive, got {width}x{height}")
        if start_us is not None and end_us is not None and end_us <= start_us:
            raise ValueError(f"prep: end_us ({end_us}) must be after start_us ({start_us})")
        if burst_fraction is not None and not 0 < burst_fraction <= 1:
            raise ValueError(f"prep: burst_fraction must be in (0, 1], got {burst_fraction}")
        if tick is not None and tick < 1:
            raise ValueError(f"prep: tick must be a positive number of µs, got {tick}")
        self.width, self.height = int(width), int(height)
        self.start_us, self.end_us = start_us, end_us
        self.dequantize, self.burst_fraction, self.seed = dequantize, burst_fraction, int(seed)
        self.stats = PrepStats(tick_us=int(tick or 0), dequantized=bool(dequantize))
        self._held = np.empty(0, EVENT_DTYPE)          # the last, incomplete bin

    # ---- the stream --------------------------------------------------------------------
    def feed(self, chunk) -> np.ndarray:
        ev = as_events(chunk)
        self.stats.events_in += len(ev)
        ev = self._window(ev)
        ev = np.concatenate([self._held, ev]) if len(self._held) else ev
        if not self.stats.tick_us:
            if len(np.unique(ev["t"])) < DETECT_MIN_TIMES:
                self._held = ev                      # until DETECT_MIN_TIMES or finish()
                return ev[:0]
            self.stats.tick_us = tick_us(ev["t"])
        if not len(ev):
            self._held = ev
            return ev
        # hold back the last bin: the next chunk may add to it
        b = self._bins(ev["t"])
        cut = len(b) - int(np.argmin(b[::-1] == b[-1])) if not np.all(b == b[-1]) else 0
        self._held = ev[cut:]
        return self._process(ev[:cut])

    def finish(self) -> np.ndarray:
        ev, self._held = self._held, np.empty(0, EVENT_DTYPE)
        if not self.stats.tick_us:
            self.stats.tick_us = tick_us(ev["t"]) if len(ev) else 1
        return self._process(ev)

    # ---- steps -------------------------------------------------------------------------
    def _window(self, ev: np.ndarray) -> np.ndarray:
        keep = np.ones(len(ev), bool)
        if self.start_us is not None:
            keep &= ev["t"] >= self.start_us
        if self.end_us is not None:
            keep &= ev["t"] < self.end_us
        self.stats.outside_window += int(len(ev) - keep.sum())
        return ev if keep.all() else ev[keep]

    def _bin_us(self) -> int:
        tick = self.stats.tick_us or 1
        return tick if tick >= BURST_BIN_US else BURST_BIN_US

    @property
    def burst_bin_us(self) -> int:
        """The burst filter's bin (µs): the tick, or ``BURST_BIN_US`` when finer."""
        return self._bin_us()

    def _bins(self, t: np.ndarray) -> np.ndarray:
        return t // self._bin_us()

    def _process(self, ev: np.ndarray) -> np.ndarray:
        if not len(ev):
            return ev
        if self.burst_fraction is not None:
            ev = self._drop_bursts(ev)
        if self.dequantize and self.stats.tick_us > 1 and len(ev):
            ev = dequantize(ev, self.stats.tick_us, self.seed)
        self.stats.events_out += len(ev)
        return ev

    def _drop_bursts(self, ev: np.ndarray) -> np.ndarray:
        """Drop the bins in which at least burst_fraction of the pixels fire."""
        need = int(math.ceil(self.burst_fraction * self.width * self.height))
        b = self._bins(ev["t"])
        starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
        sizes = np.diff(np.r_[starts, len(ev)])
        big = np.flatnonzero(sizes >= need)          # too few events to be a burst otherwise
        if not len(big):
            return ev
        drop = np.zeros(len(ev), bool)
        for k in big:
            s = slice(starts[k], starts[k] + sizes[k])
            pix = ev["y"][s].astype(np.int64) * self.width + ev["x"][s]
            if len(np.unique(pix)) >= need:
                drop[s] = True
                self.stats.burst_bins += 1
                if len(self.stats.burst_at_us) < BURST_TIMES_KEPT:
                    self.stats.burst_at_us.append(int(b[starts[k]]) * self._bin_us())
        self.stats.burst_events += int(drop.sum())
        return ev[~drop] if drop.any() else ev


def dequantize(ev: np.ndarray, tick: int, seed: int = 0) -> np.ndarray:
    """Spread the events of each run of one timestamp T (a tick of ``tick`` µs covering
    [T, T + tick)) evenly over the tick, in a random order drawn from ``seed``, T and the
    events' places in the run (so chunking does not change it).  Returns a new array;
    runs keep their order (in time order if ``ev`` was)."""
    ev = as_events(ev)
    n = len(ev)
    if n == 0 or tick <= 1:
        return ev.copy()
    t = ev["t"]
    starts = np.flatnonzero(np.r_[True, t[1:] != t[:-1]])
    sizes = np.diff(np.r_[starts, n])
    group = np.repeat(np.arange(len(starts)), sizes)
    place = np.arange(n) - starts[group]
    key = _splitmix64(_splitmix64(t.astype(np.uint64) ^ _splitmix64(np.uint64(seed)))
                      + place.astype(np.uint64))
    order = np.lexsort((key, group))
    rank = np.arange(n) - starts[group]                # position within the group, shuffled
    out = ev[order]
    out["t"] = t[order] + (rank * tick) // sizes[group]
    return out


def prepare(events, width: int, height: int, **options):
    """Prepare a whole event array: ``(events, PrepStats)``; options as :class:`Preparer`."""
    p = Preparer(width, height, **options)
    head = p.feed(events)
    tail = p.finish()
    return (np.concatenate([head, tail]) if len(head) and len(tail) else
            (head if len(head) else tail)), p.stats


# ---- detection (springtrack info) -----------------------------------------------------
ROW_ORDER_SHARE = 0.9          # of row changes inside ticks going down the sensor
ROW_ORDER_MIN_PAIRS = 100      # row changes inside ticks needed to judge the order
COARSE_TICK_US = 10            # a tick this long or longer is worth de-quantising


@dataclass
class Quirks:
    """The recording quirks :class:`QuirkScan` found (events unless named otherwise)."""
    events: int = 0
    tick_us: int = 1                  # the timestamps' quantum over the whole stream
    time_backwards: int = 0           # events earlier than the one before (unsorted)
    row_steps: int = 0                # consecutive events of one timestamp on other rows
    row_steps_down: int = 0           # ... of which the second is on a later row
    row_steps_up: int = 0             # ... on an earlier row
    bursts_checked: bool = True       # False when the sensor size is unknown
    burst_bins: int = 0
    burst_events: int = 0
    burst_at_us: list = field(default_factory=list)
    burst_bin_us: int = BURST_BIN_US
    burst_fraction: float = DEFAULT_BURST_FRACTION

    @property
    def coarse(self) -> bool:
        return self.tick_us >= COARSE_TICK_US

    @property
    def row_ordered(self) -> bool:
        """The events of a tick come in row order (the sensor read out row by row and
        stamped them with the tick's time), not in the order they happened."""
        return (self.row_steps >= ROW_ORDER_MIN_PAIRS
                and max(self.row_steps_down, self.row_steps_up)
                >= ROW_ORDER_SHARE * self.row_steps)

    def _order(self) -> str:
        way, k = (("down", self.row_steps_down) if self.row_steps_down >= self.row_steps_up
                  else ("up", self.row_steps_up))
        return f"{k:,} of {self.row_steps:,} row changes go {way} the sensor"

    def findings(self) -> list[tuple[str, str]]:
        """(what was found, what to do) for each quirk, in the options' words."""
        out = []
        if self.coarse:
            order = (f"; inside a tick the events come in row order ({self._order()}), so "
                     f"a tracker sees each tick as a sweep across the rows"
                     if self.row_ordered else "")
            out.append((f"coarse timestamps: {self.tick_us} us ticks{order}",
                        f"--dequantize spreads each tick's events evenly over it in a seeded "
                        f"random order (track, render, learn; docs/learning.md)"))
        elif self.row_ordered:
            out.append((f"events of one timestamp in row order ({self._order()})",
                        "harmless at this time resolution"))
        if self.time_backwards:
            out.append((f"unsorted: {self.time_backwards:,} events "
                        f"({self.time_backwards / max(self.events, 1):.2%}) are earlier than the "
                        f"one before",
                        "the tracker skips and counts them (back_in_time); sort the events "
                        "by time to keep them"))
        if self.burst_bins:
            at = ", ".join(f"{t:,}" for t in self.burst_at_us[:4])
            more = " ..." if self.burst_bins > 4 else ""
            out.append((f"full-frame bursts: {self.burst_bins} bin(s) of {self.burst_bin_us} us "
                        f"in which >= {self.burst_fraction:.0%} of the pixels fire "
                        f"({self.burst_events:,} events, at t = {at}{more} us)",
                        "any of --dequantize, --start-us, --end-us or --burst-fraction drops "
                        "them (track, render, learn); or start after them with --start-us"))
        if not self.bursts_checked:
            out.append(("full-frame bursts not checked: the sensor size is unknown",
                        "give the events' file a header with its size (or see `springtrack "
                        "render`)"))
        return out


class QuirkScan:
    """Streaming detection of a recording's quirks (``springtrack info``): ``feed`` the
    chunks of a ``width`` x ``height`` recording in order, then :meth:`finish` -> Quirks.
    The bursts are the :class:`Preparer`'s own rule (it runs alongside, output unused);
    with no sensor size (None) they are not checked."""

    def __init__(self, width: int | None, height: int | None,
                 burst_fraction: float = DEFAULT_BURST_FRACTION):
        self.q = Quirks(burst_fraction=burst_fraction, bursts_checked=bool(width and height))
        self._prep = (Preparer(width, height, burst_fraction=burst_fraction)
                      if width and height else None)
        self._gcd = 0
        self._last = None           # the previous chunk's last event (t, y)

    def feed(self, chunk) -> None:
        ev = as_events(chunk)
        if not len(ev):
            return
        self.q.events += len(ev)
        t = ev["t"]
        y = ev["y"].astype(np.int64)
        if self._last is not None:
            t = np.r_[self._last[0], t]
            y = np.r_[self._last[1], y]
        dt = np.diff(t)
        self.q.time_backwards += int((dt < 0).sum())
        gaps = np.abs(dt[dt != 0])
        if len(gaps):
            self._gcd = int(np.gcd.reduce(np.r_[self._gcd, gaps]))
        same = dt == 0
        dy = np.diff(y)[same]
        self.q.row_steps += int((dy != 0).sum())
        self.q.row_steps_down += int((dy > 0).sum())
        self.q.row_steps_up += int((dy < 0).sum())
        self._last = (int(t[-1]), int(y[-1]))
        if self._prep is not None:
            self._prep.feed(ev)

    def finish(self) -> Quirks:
        self.q.tick_us = max(1, self._gcd)
        if self._prep is None:
            return self.q
        self._prep.finish()
        st = self._prep.stats
        self.q.burst_bins, self.q.burst_events = st.burst_bins, st.burst_events
        self.q.burst_at_us = list(st.burst_at_us)
        self.q.burst_bin_us = self._prep.burst_bin_us
        return self.q
