"""Instructions per event of the microcontroller build, counted in the emulator.

Each event goes through ``mcu_main``'s MCU_STEP (``fx_step``: Algorithm 1 for one event,
and the spring update when it falls due); the count of a NOP call (the entry and the
counters' refresh) is subtracted, so what remains is the kernel's own work.  Counting is
per basic block (emulator.py), exact for the emulated core's instruction set.
"""
from __future__ import annotations

import numpy as np

from ..events import as_events
from . import emulator as E
from .backend import McuBackend


def profile_events(model, params, events, target: str, limit: int | None = None,
                   progress=None) -> dict:
    """Per-event instruction counts on ``events`` (the first ``limit``).  Returns counts
    (array), spring (instructions inside fx_springs per event), and summary figures."""
    ev = as_events(events)
    if limit is not None:
        ev = ev[:limit]
    be = McuBackend(model, params, target=target, count=True)
    emu = be.emu
    emu.instructions = 0
    emu.call(E.MCU_NOP)
    overhead = emu.instructions
    emu.by_function.clear()
    emu.loads = emu.divides = emu.blocks = 0
    counts = np.empty(len(ev), np.int64)
    spring = np.empty(len(ev), np.int64)
    for k, (t, x, y, p) in enumerate(zip(ev["t"].tolist(), ev["x"].tolist(), ev["y"].tolist(),
                                         ev["p"].tolist())):
        emu.instructions = emu.spring_instructions = 0
        be.step(t, x, y, int(p))
        counts[k] = emu.instructions - overhead
        spring[k] = emu.spring_instructions
        if progress is not None and k % 5000 == 0:
            progress(k, len(ev))
    n = max(len(ev), 1)
    emu.by_function.pop("mcu_main", None)
    return dict(target=target, events=len(ev), counts=counts, spring=spring,
                mean=float(counts.sum() / n), p50=float(np.percentile(counts, 50)) if len(ev) else 0.0,
                p99=float(np.percentile(counts, 99)) if len(ev) else 0.0,
                max=int(counts.max()) if len(ev) else 0,
                spring_share=float(spring.sum() / max(counts.sum(), 1)),
                stack_bytes=emu.stack_used(), counters=be.counters(),
                mix=dict(loads=emu.loads / n, divides=emu.divides / n, blocks=emu.blocks / n),
                by_function={k: v / n for k, v in sorted(emu.by_function.items(),
                                                         key=lambda kv: -kv[1])})
