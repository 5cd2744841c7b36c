"""Supervision of the firmware's threads: no thread dies silently.

Every long-running thread (the USB reader, the fused loop, the host link) runs its body
through :meth:`Supervisor.thread_target`.  An unexpected exception is caught, counted per
thread, reported (``last_error``, the ``faulted`` state and an ERROR frame queued for every
host session, :meth:`Supervisor.reports`), and the body is started again after a short
backoff.  A thread that faults ``max_faults`` times within ``FAULT_WINDOW_S`` is stopped
instead (its ``on_give_up`` runs, e.g. the tracking loop stops cleanly) and reported as
``THREAD_STOPPED``.  RESET from the host clears the ``faulted`` state
(:meth:`Supervisor.clear`); the counters stay for the device's lifetime.

Reports (ERRORs, and the NOTICEs of :meth:`Supervisor.notice`) are numbered; each host
session keeps the number of the last one it sent, so every session sees every report once
(the last ``REPORTS_KEPT`` are kept).
"""
from __future__ import annotations

import sys
import threading
import time
import traceback
from collections import deque

from springtrack.wire import Fault, MsgType, Notice

BACKOFF_S = (0.05, 0.1, 0.2, 0.5, 1.0, 2.0)  # before restart k (then the last, repeated)
FAULT_WINDOW_S = 10.0
MAX_FAULTS = 5                 # faults within FAULT_WINDOW_S before a thread is stopped
REPORTS_KEPT = 256


class Supervisor:
    """Fault counting and reporting shared by the threads of one firmware."""

    def __init__(self):
        self.lock = threading.Lock()
        self.faults: dict[str, int] = {}        # thread name -> faults caught
        self.restarts = 0
        self.stopped: dict[str, int] = {}       # thread name -> times given up
        self.reported: dict[str, int] = {}      # Fault name -> reports
        self.last_error = ""
        self.faulted = False
        self.log: deque[str] = deque(maxlen=256)    # lines for the program's stderr
        self._reports: deque = deque(maxlen=REPORTS_KEPT)   # (id, msg type, code, text)
        self._last_id = 0
        self._recent: dict[str, deque] = {}

    # ---- reporting -------------------------------------------------------------------
    def report(self, code: Fault, text: str, faulted: bool = True) -> None:
        """Tell every host session (an ERROR frame), the program's log and ``last_error``;
        ``faulted``: the device state becomes ``faulted`` until RESET."""
        code = Fault(code)
        with self.lock:
            self._last_id += 1
            self._reports.append((self._last_id, MsgType.ERROR, code, text))
            self.reported[code.name.lower()] = self.reported.get(code.name.lower(), 0) + 1
            self.last_error = f"{code.name.lower()}: {text}"
            if faulted:
                self.faulted = True
        self.log.append(f"error {code.name.lower()}: {text}")

    def notice(self, code: Notice, text: str) -> None:
        """Tell every host session about a state change (a NOTICE frame)."""
        with self.lock:
            self._last_id += 1
            self._reports.append((self._last_id, MsgType.NOTICE, Notice(code), text))
        self.log.append(f"notice {Notice(code).name.lower()}: {text}")

    def reports(self, after: int = 0) -> list[tuple]:
        """Reports numbered above ``after``, oldest first: ``(id, MsgType.ERROR or NOTICE,
        code, text)``."""
        with self.lock:
            return [r for r in self._reports if r[0] > after]

    @property
    def last_report_id(self) -> int:
        return self._last_id

    def clear(self) -> None:
        """The host reset the device: no longer ``faulted`` (counters are kept)."""
        with self.lock:
            self.faulted = False

    # ---- faults ----------------------------------------------------------------------
    def fault(self, thread: str, error: BaseException, max_faults: int | None = MAX_FAULTS,
              action: str = "restarted") -> bool:
        """An unexpected exception in ``thread``: counted and reported (``action``: what
        is done about it).  Returns True if the thread should be restarted, False if it
        faulted ``max_faults`` times within FAULT_WINDOW_S (None: never give up)."""
        now = time.monotonic()
        where = traceback.extract_tb(error.__traceback__)[-1:] if error.__traceback__ else []
        at = f" at {where[0].filename.rsplit('/', 1)[-1]}:{where[0].lineno}" if where else ""
        with self.lock:
            self.faults[thread] = self.faults.get(thread, 0) + 1
            recent = self._recent.setdefault(thread, deque())
            recent.append(now)
            while recent and now - recent[0] > FAULT_WINDOW_S:
                recent.popleft()
            give_up = max_faults is not None and len(recent) >= max_faults
        text = f"thread {thread}: {type(error).__name__}: {error}{at}"
        if give_up:
            with self.lock:
                self.stopped[thread] = self.stopped.get(thread, 0) + 1
            self.report(Fault.THREAD_FAULT, text)
            self.report(Fault.THREAD_STOPPED, f"thread {thread} stopped after {len(recent)} "
                                              f"faults in {FAULT_WINDOW_S:g} s")
            return False
        self.report(Fault.THREAD_FAULT, f"{text}; {action}")
        return True

    def backoff(self, thread: str) -> float:
        with self.lock:
            k = len(self._recent.get(thread, ())) - 1
        return BACKOFF_S[min(max(k, 0), len(BACKOFF_S) - 1)]

    def thread_target(self, name: str, body, stop: threading.Event, on_give_up=None,
                      max_faults: int | None = MAX_FAULTS):
        """A thread target that runs ``body()`` until it returns or ``stop`` is set,
        restarting it after an unexpected exception (see the module docstring)."""
        def target():
            while True:
                try:
                    body()
                    return
                except Exception as e:          # noqa: BLE001 - the point of supervision
                    if not self.fault(name, e, max_faults):
                        if on_give_up is not None:
                            try:
                                on_give_up()
                            except Exception as e2:      # noqa: BLE001
                                self.report(Fault.THREAD_FAULT, f"stopping after {name} "
                                                                f"failed: {e2}")
                        return
                    if stop.wait(self.backoff(name)):
                        return
                    with self.lock:
                        self.restarts += 1
        return target

    def counters(self) -> dict:
        with self.lock:
            return dict(faults=sum(self.faults.values()), restarts=self.restarts,
                        threads_stopped=sum(self.stopped.values()),
                        **{f"faults_{k.replace('-', '_')}": v for k, v in self.faults.items()},
                        **{f"reported_{k}": v for k, v in self.reported.items()})


def where(thread: threading.Thread, depth: int = 3) -> str:
    """Where ``thread`` is now: its innermost ``depth`` frames as ``file:line func``, for the
    message about a thread that did not stop in time."""
    frame = sys._current_frames().get(thread.ident)
    if frame is None:
        return "not running"
    stack = traceback.extract_stack(frame)[-depth:]
    return " < ".join(f"{f.filename.rsplit('/', 1)[-1]}:{f.lineno} {f.name}"
                      for f in reversed(stack))

