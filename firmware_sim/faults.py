"""Fault injection for the simulated camera (``firmware-sim run --faults NAME,...``).

Each fault is deterministic (seeded) and counts what it injected in :attr:`Faults.injected`
so tests can compare the loop's counters with the truth.  Schedules are expressed in bulk
reads (the unit the host sees) or in event time (what the scene sees):

=============  ===========================================================================
``timeout``    every ``timeout_every``-th bulk read times out (USBTimeoutError, errno 110);
               no data is lost, the read is simply repeated
``short``      every ``short_every``-th transfer is cut to a random multiple of 4 bytes
``odd``        every ``short_every``-th transfer is cut to a random length that is not a
               multiple of 4: words are split across transfers
``stall``      the ``stall_at``-th read stalls the endpoint (USBError EPIPE, errno 32); every
               read fails until the host calls clear_halt; no data is lost
``corrupt``    about one event word in ``corrupt_every`` is given an undefined word type
               or a coordinate outside the sensor, alternately, in the word format the
               camera streams (firmware_sim.simcam.spoil), replayed words included
``disconnect`` at ``disconnect_at_us`` of event time the device vanishes (USBError ENODEV,
               errno 19; gone from enumeration) for ``disconnect_s`` wall seconds, then
               re-enumerates with a new address, unconfigured; data of that time is lost
``burst``      at ``burst_at_us`` of event time, ``burst_us`` of event time is replaced by a
               noise burst of ``burst_rate`` events/s (far above the processing rate)
=============  ===========================================================================
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

FAULT_NAMES = ("timeout", "short", "odd", "stall", "corrupt", "disconnect", "burst")


@dataclass
class FaultPlan:
    timeout_every: int = 7
    short_every: int = 3
    stall_at: int = 12
    corrupt_every: int = 997
    disconnect_at_us: int = 1_000_000
    disconnect_s: float = 0.3
    burst_at_us: int = 1_500_000
    burst_us: int = 100_000
    burst_rate: float = 200e6
    seed: int = 0


def parse(names) -> tuple[str, ...]:
    """'timeout,stall' or a list -> validated tuple; ValueError naming unknown faults."""
    if names is None:
        return ()
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    bad = [n for n in names if n not in FAULT_NAMES]
    if bad:
        raise ValueError(f"unknown fault(s) {', '.join(bad)}; known: {', '.join(FAULT_NAMES)}")
    return tuple(dict.fromkeys(names))


class Faults:
    """The active faults of one simulated device (consulted by the simulated camera on every read)."""

    def __init__(self, names=(), plan: FaultPlan | None = None, **overrides):
        self.names = parse(names)
        plan = plan or FaultPlan()
        if overrides:
            known = {f.name for f in fields(FaultPlan)}
            bad = set(overrides) - known
            if bad:
                raise ValueError(f"unknown fault parameter(s) {sorted(bad)}; known: {sorted(known)}")
            plan = FaultPlan(**{**plan.__dict__, **overrides})
        self.plan = plan
        self.rng = np.random.default_rng(plan.seed)
        self.reads = 0
        self.injected = {n: 0 for n in FAULT_NAMES}
        self.injected.update(corrupt_unknown=0, corrupt_geometry=0, corrupt_unknown_events=0,
                             corrupt_geometry_events=0, burst_events=0)
        self.disconnect_done = False
        self.burst_done = False

    def __contains__(self, name) -> bool:
        return name in self.names

    def rearm(self) -> None:
        """A replay from the start: the one-off faults (stall, disconnect, burst) fire
        again at their times; ``injected`` keeps counting."""
        self.reads = 0
        self.disconnect_done = False
        self.burst_done = False

    # ---- per read ----------------------------------------------------------------
    def before_read(self) -> str | None:
        """Called at the start of each bulk read; returns 'timeout' / 'stall' or None."""
        self.reads += 1
        p = self.plan
        if "stall" in self.names and self.reads == p.stall_at:
            self.injected["stall"] += 1
            return "stall"
        if "timeout" in self.names and self.reads % p.timeout_every == 0:
            self.injected["timeout"] += 1
            return "timeout"
        return None

    def cut(self, n: int) -> int:
        """Length of this transfer given ``n`` bytes available and room (short/odd faults)."""
        p = self.plan
        if n < 8 or self.reads % p.short_every:
            return n
        if "odd" in self.names:
            m = int(self.rng.integers(1, n // 4)) * 4 + int(self.rng.integers(1, 4))
            self.injected["odd"] += 1
            return min(m, n - 1)
        if "short" in self.names:
            self.injected["short"] += 1
            return int(self.rng.integers(1, n // 4)) * 4
        return n

    def corrupt(self, data, start_unit: int, spoiler) -> None:
        """Spoil about one word in corrupt_every of ``data`` in place, alternately as an
        undefined word type and as an event outside the sensor (``spoiler``: the word
        format's, firmware_sim.simcam.spoil.SPOILERS; words that carry no event are left
        alone).  ``data`` (a writable buffer) starts with a whole word, the stream's word
        ``start_unit``; words are ``spoiler.unit`` bytes."""
        if "corrupt" not in self.names or len(data) < spoiler.unit:
            return
        every = self.plan.corrupt_every
        u = spoiler.unit
        view = memoryview(data)
        first = (-start_unit) % every
        for k in range(first, len(data) // u, every):
            w = view[u * k:u * (k + 1)]
            n = spoiler.events(w)
            if not n:
                continue
            if ((start_unit + k) // every) % 2 == 0:
                spoiler.unknown(w)
                self.injected["corrupt_unknown"] += 1
                self.injected["corrupt_unknown_events"] += n
            else:
                spoiler.outside(w)
                self.injected["corrupt_geometry"] += 1
                self.injected["corrupt_geometry_events"] += n
            self.injected["corrupt"] += 1
