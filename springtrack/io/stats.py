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

    def lines(self) -> list[str]:
        out = [f"words {self.words}, events {self.events}, pending bytes {self.pending_bytes}"]
        bad = {k: v for k, v in self.anomalies.items() if v}
        out.append("anomalies: " + (", ".join(f"{k} {v}" for k, v in bad.items()) or "none"))
        if self.info:
            out.append("info: " + ", ".join(f"{k} {v}" for k, v in self.info.items()))
        return out
