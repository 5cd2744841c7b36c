"""The interface between the firmware's host link and its tracking loop.

``firmware_sim.link`` (the host-link server) drives any object with these methods;
``firmware_sim.loop`` implements it.  Every call is made from the link thread and must
be thread-safe; updates are double-buffered and take effect between two events.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np


class UpdateRejected(ValueError):
    """An update was invalid; ``code`` is one of the wire protocol's NACK codes."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


class Engine(Protocol):
    def info(self) -> dict:
        """firmware version, sensor width/height, capacities, model name and hash, running."""

    def load_model(self, toml_text: str) -> int:
        """Validate and queue a model swap; returns the new model generation.
        Raises UpdateRejected (code 'invalid_model') leaving the running model untouched."""

    def set_param(self, name: str, value) -> int:
        """Validate and queue a parameter change; returns the generation it will carry.
        Raises UpdateRejected ('unknown_name' | 'out_of_range' | 'wrong_type' | 'busy')."""

    def get_params(self) -> dict: ...

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def reset(self) -> None: ...

    def stats(self) -> dict:
        """Counters: transfers, bytes, events decoded/tracked, drops, anomalies, queue HWM, ..."""

    def poll_telemetry(self, max_items: int = 64) -> list:
        """Snapshots produced since the last call: each a dict with t_us, generation,
        mean_energy, and a per-tracker structured array (x, y, sxx, sxy, syy, activity,
        active, sensitive)."""

    def poll_applied(self) -> list:
        """(generation, t_us) pairs: the event time at which each queued update took effect."""
