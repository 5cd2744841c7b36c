"""``firmware-sim run --record``: every snapshot the tracking loop took, kept in memory
and written as a springtrack track CSV (the schema of ``springtrack track``)."""
from __future__ import annotations

import time
from dataclasses import dataclass

from springtrack.track import CSV_HEADER, Track


@dataclass(frozen=True, slots=True)
class Recorded:
    ids: list                 # tracker ids of the model the block was computed with
    samples: dict             # the fused loop's rows: t, trackers, energy, wire
    wall: float               # time.monotonic() when the block was taken


class Recorder:
    def __init__(self):
        self.blocks: list[Recorded] = []

    def add(self, ids, samples: dict) -> None:
        self.blocks.append(Recorded(list(ids), samples, time.monotonic()))

    def write(self, path) -> int:
        """Write every snapshot as a track CSV; returns the number of rows."""
        rows = 0
        with open(path, "w", newline="") as f:
            f.write(",".join(CSV_HEADER) + "\n")
            for b in self.blocks:
                tr = Track.from_samples(b.samples, b.ids)
                tr.write_rows(f)
                rows += len(tr) * len(b.ids)
        return rows
