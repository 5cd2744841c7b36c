"""Real-time scheduling of the loop's own threads (Linux ``SCHED_FIFO``).

On a shared machine the ordinary scheduler may leave the USB reader or the processing
thread waiting for a core for milliseconds while other programs run: that wait, not the
work, makes the tail of the event-to-telemetry latency (docs/benchmarks.md, "Firmware
loop").  A ``SCHED_FIFO`` thread runs as soon as it is runnable.  Both threads block
between transfers, so they take the core only for the work itself; the kernel's real-time
throttling (``/proc/sys/kernel/sched_rt_runtime_us``) still leaves the rest of the system
its share if one of them ever spins.

:func:`check` tries the policy on a throw-away thread, so a missing permission is an error
before anything starts, naming the way out; :func:`apply` sets it for the calling thread.
"""
from __future__ import annotations

import os
import threading

POLICY = "SCHED_FIFO"


class PriorityError(OSError):
    """The system refuses real-time scheduling to this process."""


def _set(priority: int) -> None:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))   # 0: this thread


def bounds() -> tuple[int, int]:
    """The priorities SCHED_FIFO accepts (1..99 on Linux)."""
    if not hasattr(os, "SCHED_FIFO"):
        raise PriorityError(f"{POLICY} is not available on this system (Linux only)")
    return os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)


def check(priority: int) -> int:
    """``priority`` if this process may run threads under SCHED_FIFO at it, else
    PriorityError (ValueError outside the policy's range)."""
    lo, hi = bounds()
    if not lo <= priority <= hi:
        raise ValueError(f"real-time priority {priority} is outside {POLICY}'s {lo}..{hi}")
    box: dict = {}

    def probe():
        try:
            _set(priority)
        except OSError as e:
            box["error"] = e
    t = threading.Thread(target=probe, name="rt-probe")
    t.start()
    t.join()
    if "error" in box:
        raise PriorityError(
            f"{POLICY} priority {priority} refused ({box['error'].strerror}): run as root, "
            f"grant the interpreter CAP_SYS_NICE (setcap cap_sys_nice+ep on it), or raise "
            f"the rtprio limit (ulimit -r / /etc/security/limits.conf); or run without "
            f"--rt-priority") from None
    return priority


def apply(priority: int | None) -> None:
    """Put the calling thread under SCHED_FIFO at ``priority`` (None: leave it as it is)."""
    if priority is not None:
        _set(priority)
