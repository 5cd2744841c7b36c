"""Decode counters: what a decoder saw, produced and had to skip."""
from __future__ import annotations

from dataclasses import dataclass, field

from .errors import DecodeError

# A stream is not of its format (random bytes, the wrong extension or --format) when its
# decoder finds at least CORRUPT_MIN corrupt words and they are more than CORRUPT_SHARE of
# the words it read.  Corrupt: every anomaly but events outside the declared sensor (a
# header that lies about the geometry spoils no word).  The real recordings have none; a
# megabyte of random bytes has 31 % (EVT 3.0) to 87 % (DAT).  Commands whose output grows
# with the events (``track``: up to sampling.PER_EVENT rows per event and tracker) and
# those that learn or draw from them refuse such a stream instead of turning it into
# output (``info`` still describes it).
CORRUPT_MIN = 1000
CORRUPT_SHARE = 0.1
GEOMETRY_ANOMALY = "out_of_geometry"


@dataclass
class DecodeStats:
    """Counters of one decoder (or reader).

    ``words``: words (bytes for Event Stream) consumed; ``events``: events returned;
    ``pending_bytes``: bytes of an incomplete word/event held for the next call;
    ``anomalies``: recoverable problems by kind (every kind listed, zeros included);
    ``info``: legitimate but notable content (time-high words, wraps, triggers, ...).
    """
    format: str
    words: int = 0
    events: int = 0
    pending_bytes: int = 0
    anomalies: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    @property
    def total_anomalies(self) -> int:
        return sum(self.anomalies.values())

    @property
    def bad(self) -> dict:
        """The anomaly kinds that occurred, with their counts."""
        return {k: v for k, v in self.anomalies.items() if v}

    @property
    def corrupt(self) -> int:
        """Anomalies that spoil a word (all but events outside the declared sensor)."""
        return sum(v for k, v in self.anomalies.items() if k != GEOMETRY_ANOMALY)

    @property
    def undecodable(self) -> bool:
        """The stream so far is not of its format (see CORRUPT_SHARE)."""
        bad = self.corrupt
        return bad >= CORRUPT_MIN and bad > CORRUPT_SHARE * self.words

    def check_decodable(self, source) -> None:
        """Raise DecodeError if the stream so far is not of its format (see CORRUPT_SHARE)."""
        bad = self.corrupt
        if self.undecodable:
            raise DecodeError(
                f"{source} does not decode as {self.format}: {bad:,} anomalies in its first "
                f"{self.words:,} words (over {CORRUPT_SHARE:.0%} of them; "
                f"{', '.join(f'{k} {v:,}' for k, v in self.bad.items())}): it is not an "
                f"event file of this format, or badly damaged; `springtrack info {source}` "
                f"describes it, `springtrack info --format FORMAT` tries another format")

    def summary(self) -> str:
        """``anomalies=none``, or ``anomalies=N (kind n, ...)``: for a command's stats line."""
        bad = self.bad
        if not bad:
            return "anomalies=none"
        return (f"anomalies={self.total_anomalies} ("
                + ", ".join(f"{k} {v}" for k, v in bad.items()) + ")")

    def warning(self, source) -> str | None:
        """A warning line naming what the decoder dropped or repaired in ``source``, or None
        if nothing was: every command that reads events prints it."""
        if not self.bad:
            return None
        return (f"warning: {source}: the {self.format} decoder met {self.total_anomalies:,} "
                f"anomalies ({', '.join(f'{k} {v:,}' for k, v in self.bad.items())}); what "
                f"they cost is not in the output (`springtrack info {source}` describes them)")

    def lines(self) -> list[str]:
        out = [f"words {self.words}, events {self.events}, pending bytes {self.pending_bytes}"]
        bad = {k: v for k, v in self.anomalies.items() if v}
        out.append("anomalies: " + (", ".join(f"{k} {v}" for k, v in bad.items()) or "none"))
        if self.info:
            out.append("info: " + ", ".join(f"{k} {v}" for k, v in self.info.items()))
        return out
