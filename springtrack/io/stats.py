"""Decode counters: what a decoder saw, produced and had to skip."""
from __future__ import annotations

from dataclasses import dataclass, field


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
