"""``firmware-sim run --record``: every snapshot the tracking loop took, as a springtrack
track CSV (the schema of ``springtrack track``).

:class:`StreamRecorder` (the command line's) writes as it goes: the file is opened when the
engine is made (an unwritable path is an error at once), a writer thread converts each
block of snapshots and writes it whole, flushed, so that a recording cut by SIGKILL, a
crash or the OOM killer keeps everything up to the last second or so, and memory holds at
most ``QUEUE_BLOCKS`` blocks waiting for the disk (beyond them blocks are dropped and
counted in ``dropped_blocks``/``dropped_rows``, reported with the summary).  On a clean end
:meth:`StreamRecorder.close` writes what is queued.  :class:`Recorder` keeps every block
in memory (``blocks``) for the Python API and tests, written by :meth:`Recorder.write`.
"""
from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass

from springtrack.track import CSV_HEADER, Track

QUEUE_BLOCKS = 1024         # blocks waiting for the writer thread (a block: one period's rows)


@dataclass(frozen=True, slots=True)
class Recorded:
    ids: list                 # tracker ids of the model the block was computed with
    samples: dict             # the fused loop's rows: t, trackers, energy, wire
    wall: float               # time.monotonic() when the block reached the telemetry queue


def _write_block(f, b: Recorded) -> int:
    tr = Track.from_samples(b.samples, b.ids)
    tr.write_rows(f)
    return len(tr) * len(b.ids)


class Recorder:
    def __init__(self):
        self.blocks: list[Recorded] = []

    def add(self, ids, samples: dict, wall: float) -> None:
        self.blocks.append(Recorded(list(ids), samples, wall))

    def write(self, path) -> int:
        """Write every snapshot as a track CSV; returns the number of rows."""
        rows = 0
        with open(path, "w", newline="") as f:
            f.write(",".join(CSV_HEADER) + "\n")
            for b in self.blocks:
                rows += _write_block(f, b)
        return rows

    def close(self) -> None:
        pass


class StreamRecorder:
    """Snapshots written to ``path`` as they come (see the module docstring)."""

    def __init__(self, path):
        self.path = path
        self.f = open(path, "w", newline="")          # OSError now: the path is unwritable
        self.f.write(",".join(CSV_HEADER) + "\n")
        self.f.flush()
        self.rows = 0
        self.dropped_blocks = self.dropped_rows = 0
        self.error: str | None = None
        self.q: queue.Queue = queue.Queue(QUEUE_BLOCKS)
        self.thread = threading.Thread(target=self._writer, name="record-writer", daemon=True)
        self.thread.start()

    def add(self, ids, samples: dict, wall: float) -> None:
        """Queue a block (processing thread: never blocks)."""
        try:
            self.q.put_nowait(Recorded(list(ids), samples, wall))
        except queue.Full:
            self.dropped_blocks += 1
            self.dropped_rows += len(samples["t"]) * len(ids)

    def _writer(self) -> None:
        while True:
            b = self.q.get()
            if b is None:
                return
            if self.error is not None:
                continue
            try:
                self.rows += _write_block(self.f, b)
                self.f.flush()
            except (OSError, ValueError) as e:      # disk full, file gone: stop writing
                self.error = f"writing {self.path} failed: {e}"

    def close(self) -> int:
        """Write what is queued, close the file; returns the rows written."""
        if self.thread.is_alive():
            self.q.put(None)
            self.thread.join()
        try:
            self.f.close()
        except OSError as e:
            self.error = self.error or f"closing {self.path} failed: {e}"
        return self.rows

    def summary(self) -> str:
        text = f"record: {self.rows} rows -> {self.path}"
        if self.dropped_blocks:
            text += (f"; warning: {self.dropped_rows} rows ({self.dropped_blocks} blocks) were "
                     f"dropped: the disk did not keep up")
        if self.error:
            text += f"; error: {self.error} (the file holds the rows before)"
        return text
