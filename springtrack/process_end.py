"""How a command-line program ends when its surroundings end it: a reader of its standard
output that went away (``... | head``) and SIGTERM.

* A broken pipe ends the program quietly with status 141 (128 + SIGPIPE, what a shell
  reports for a program the signal ended): its reader wanted no more; standard output is
  pointed at /dev/null so that the interpreter's final flush does not complain again.
* SIGTERM raises :class:`Terminated` in the main thread, so that ``with`` blocks and
  ``finally`` clauses run (an output being written is finished or marked incomplete, see
  ``springtrack.io.writers``); the program then says so and exits with 143 (128 + SIGTERM).

And how a program ends a child process it started (:func:`end_child`): SIGTERM, so that
the child can finish its output, then SIGKILL if it has not ended after a grace period.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

BROKEN_PIPE_STATUS = 128 + signal.SIGPIPE
TERMINATED_STATUS = 128 + signal.SIGTERM


class Terminated(BaseException):
    """SIGTERM arrived (a BaseException: no ``except Exception`` swallows it)."""


def _raise_terminated(signum, frame):
    raise Terminated(f"terminated by signal {signum}")


def catch_sigterm() -> None:
    """Turn SIGTERM into :class:`Terminated` (main thread only; elsewhere a no-op)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _raise_terminated)


def broken_pipe() -> int:
    """Standard output's reader is gone: silence further writes, return the status."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return BROKEN_PIPE_STATUS


def end_child(proc: subprocess.Popen, grace_s: float = 10.0) -> int:
    """End ``proc`` if it still runs: SIGTERM, then SIGKILL after ``grace_s`` seconds; wait
    for it and return its exit status (negative: the signal that ended it)."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode
