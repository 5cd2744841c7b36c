"""The interface between the firmware's host link and its tracking loop.

``firmware_sim.link`` (the host-link server) drives any object with these methods;
``firmware_sim.loop`` implements it.  Every call is made from the link thread and must
be thread-safe; updates are double-buffered and take effect between two events.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from springtrack.wire import Nack


class UpdateRejected(ValueError):
    """An update was invalid; ``code`` is the wire protocol's NACK code for the reason."""

    def __init__(self, code: Nack, message: str):
        super().__init__(message)
        self.code = Nack(code)


@dataclass(frozen=True, slots=True)
class Snapshot:
    """One telemetry snapshot: the tracker states after all events with t < ``t_us``."""
    t_us: int
    generation: int                 # of the model and parameters it was computed with
    mean_energy: float              # the energy feeding eqs. (21)-(22)
    trackers: np.ndarray            # (trackers,) springtrack.track.TRACK_DTYPE, float state
    records: bytes                  # the same in the TELEMETRY layout (wire.TELE_TRACKER)
    energies: tuple | None = None   # (energy kind index, per-connection array) or None


class Engine(Protocol):
    def info(self) -> dict:
        """firmware version, sensor width/height, capacities, model name and hash, running."""

    def load_model(self, toml_text: str) -> int:
        """Validate and queue a model swap; returns the new model generation.
        Raises UpdateRejected (Nack.INVALID_MODEL) leaving the running model untouched."""

    def set_param(self, name: str, value) -> int:
        """Validate and queue a parameter change; returns the generation it will carry.
        Raises UpdateRejected (Nack.UNKNOWN_NAME, OUT_OF_RANGE, WRONG_TYPE or BUSY)."""

    def get_params(self) -> dict: ...

    def model_text(self) -> str:
        """The running model (uploaded, learned or the start's) as TOML, with its ids."""

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def reset(self) -> None: ...

    def acquire(self) -> int:
        """Search for the model again (acquisition); returns the generation it carries.
        Raises UpdateRejected (Nack.BAD_STATE) when the engine cannot acquire."""

    def stats(self) -> dict:
        """Counters: transfers, bytes, events decoded/tracked, drops, anomalies, queue HWM, ..."""

    def poll_telemetry(self, max_items: int = 64) -> list[Snapshot]:
        """Snapshots produced since the last call, oldest first.  Those carrying
        ``energies`` are sent as ENERGIES too, at most once per wire.ENERGY_PERIOD_US."""

    def poll_applied(self) -> list:
        """(generation, t_us) pairs: the event time at which each queued update took effect."""

    def reports(self, after: int = 0) -> list:
        """ERROR and NOTICE reports numbered above ``after``, oldest first: ``(id,
        wire.MsgType.ERROR or NOTICE, wire.Fault or wire.Notice code, text)``; every host
        session sends each one once (``firmware_sim.supervise.Supervisor``)."""

    def report_fault(self, thread: str, error: BaseException, action: str = "restarted") -> None:
        """An unexpected exception caught in another thread (the host link): counted and
        reported like the engine's own; ``action`` says what was done about it."""
