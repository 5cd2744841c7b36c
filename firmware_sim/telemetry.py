"""The firmware's telemetry queue: the snapshots the tracking loop took, waiting for the
host link, bounded in rows (the oldest are dropped and counted).

The loop pushes whole blocks (the sample rows of one fed piece, as the fused loop returns
them); the link polls :class:`firmware_sim.engine.Snapshot` records, one per row, each
with its TELEMETRY records: the kernel's own (the fixed-point kernel packs them from its
integer state), else quantised from the float rows by ``wire.quantise_trackers``, once
per block and in the polling (link) thread, off the tracking loop.
"""
from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from springtrack.wire import quantise_trackers

from .engine import Snapshot


@dataclass(slots=True)
class Block:
    """Sample rows of one fed piece, all computed under one generation."""
    generation: int
    energy_kind: int          # which mean energy (eqs. 12, 17, 20) the snapshots report
    samples: dict             # the fused loop's rows: t, trackers, energy (+ wire)
    energies: np.ndarray      # per-connection energies of that kind at the last row
    native: bool              # samples["wire"] holds the kernel's own TELEMETRY records
    first: int = 0            # rows before this one were polled or dropped
    _records: np.ndarray | None = None

    @property
    def end(self) -> int:
        return len(self.samples["t"])

    def records(self) -> np.ndarray:
        """(rows, trackers * 8) TELEMETRY tracker records of every row."""
        if self._records is None:
            self._records = (self.samples["wire"] if self.native else
                             quantise_trackers(self.samples["trackers"]).view(np.uint8))
        return self._records

    def snapshot(self, r: int) -> Snapshot:
        s = self.samples
        return Snapshot(int(s["t"][r]), self.generation, float(s["energy"][r, self.energy_kind]),
                        s["trackers"][r], self.records()[r].tobytes(),
                        (self.energy_kind, self.energies) if r == self.end - 1 else None)


class TelemetryQueue:
    """Blocks of snapshots, at most ``cap`` rows in all; thread-safe."""

    def __init__(self, cap: int):
        self.cap = int(cap)
        self.rows = 0                 # rows waiting
        self.dropped = 0              # rows dropped to keep within cap
        self._blocks: deque = deque()
        self._lock = threading.Lock()

    def push(self, block: Block) -> None:
        with self._lock:
            self._blocks.append(block)
            self.rows += block.end - block.first
            while self.rows > self.cap and self._blocks:       # drop the oldest rows
                old = self._blocks[0]
                drop = min(old.end - old.first, self.rows - self.cap)
                old.first += drop
                if old.first == old.end:
                    self._blocks.popleft()
                self.rows -= drop
                self.dropped += drop

    def poll(self, max_items: int = 64) -> list[Snapshot]:
        out = []
        with self._lock:
            while self._blocks and len(out) < max_items:
                blk = self._blocks[0]
                take = min(blk.end - blk.first, max_items - len(out))
                out.extend(blk.snapshot(r) for r in range(blk.first, blk.first + take))
                blk.first += take
                self.rows -= take
                if blk.first == blk.end:
                    self._blocks.popleft()
        return out
