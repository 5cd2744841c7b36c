"""``Backend``: the interface every tracker backend offers (a typing.Protocol; nothing
inherits from it)."""
from __future__ import annotations

from typing import Protocol


class Backend(Protocol):
    """A tracker kernel over one ShapeModel and its Params, or over a ``ModelSet`` (params
    None: each instance's own).

    ``run(events, sample_us, next_t, cap, into=None)`` -> (events consumed, next sample
    time, sample rows or None): the sampled event loop (springtrack.sampling's rule; rows
    as ``springtrack.backends.samples.sample_buffers``), stopping after ``cap`` rows;
    ``into``, buffers of that layout to write the rows in (the C kernels return views of
    them; a backend may ignore it and return rows of its own).
    A backend of a set also offers the instances' states (springtrack.instances):
    ``states()``, ``set_state(g, state)``, ``place(g, model)``; one of a single model is
    seen through them by ``springtrack.tracker``.
    """

    movable: bool                # move() shifts an instance rigidly

    def run(self, events, sample_us: int, next_t: int, cap: int, into: dict | None = None): ...

    def set_params(self, params) -> None: ...

    def snapshot(self, t: int) -> dict: ...

    def energies(self): ...

    @property
    def mean_energy(self) -> float: ...

    def mean_energies(self) -> list: ...

    def frame(self, g: int = 0): ...

    @property
    def last_t(self) -> int: ...

    def counters(self) -> dict: ...
