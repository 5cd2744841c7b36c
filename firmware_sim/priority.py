"""Real-time scheduling of the firmware process (Linux ``SCHED_FIFO``).

On a shared machine the ordinary scheduler may leave the USB reader or the processing
thread waiting for a core for milliseconds while other programs run: that wait, not the
work, makes the tail of the event-to-telemetry latency (docs/benchmarks.md, "Firmware
loop").  A ``SCHED_FIFO`` thread runs as soon as it is runnable.  Every thread of the
process gets it, not only those two: they share the GIL, and an ordinary thread that
another program preempts while it holds the GIL (the main loop, a link thread, the garbage
collector running in one of them) would stall the real-time ones as long (priority
inversion).  Threads started later inherit the policy from the thread that starts them.
The objects alive when real time starts are frozen out of the garbage collector
(``gc.freeze``), so a full collection during the run scans only what the run made.  The
threads block between transfers and commands, so they take a core only for the work
itself; the kernel's real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``) still
leaves the rest of the system its share if one of them ever spins.

:func:`check` tries the policy on a throw-away thread, so a missing permission is an error
before anything starts, naming the way out; :func:`apply` sets it for the process and
:func:`release` takes it back.
"""
from __future__ import annotations

import gc
import os
import threading

POLICY = "SCHED_FIFO"


class PriorityError(OSError):
    """The system refuses real-time scheduling to this process."""


def _set(priority: int, tid: int = 0) -> None:
    os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))   # 0: this thread


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
    """Put every thread of the process under SCHED_FIFO at ``priority`` and freeze the
    objects alive now out of the garbage collector (None: leave everything as it is)."""
    if priority is None:
        return
    gc.freeze()
    _set(priority)
    for t in threading.enumerate():
        if t.native_id is not None and t.is_alive():
            try:
                _set(priority, t.native_id)
            except ProcessLookupError:      # it ended meanwhile
                pass


def release(priority: int | None) -> None:
    """Undo :func:`apply`: every thread back to the ordinary scheduler, the frozen objects
    back to the collector (None: nothing was applied)."""
    if priority is None:
        return
    for tid in [0] + [t.native_id for t in threading.enumerate() if t.native_id is not None]:
        try:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except ProcessLookupError:
            pass
    gc.unfreeze()
