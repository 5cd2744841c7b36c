"""Test helper: ``firmware-sim run`` as a separate process (hardware-in-the-loop tests)."""
from __future__ import annotations
import time

import select
import subprocess
import sys
from pathlib import Path

from springtrack.process_end import end_child

from . import REPO as ROOT
BIN = Path(sys.executable).parent


def firmware_cmd(*args):
    exe = BIN / "firmware-sim"
    base = [str(exe)] if exe.exists() else [sys.executable, "-m", "firmware_sim.cli"]
    return base + ["run", "--stats-every", "0", *args]


def hostctl_cmd(*args):
    exe = BIN / "hostctl"
    base = [str(exe)] if exe.exists() else [sys.executable, "-m", "hostctl.cli"]
    return base + list(args)


class Firmware:
    """``Firmware(*run_args)``: started; ``path`` is the link it announced on its first
    stdout line (``pty: /dev/pts/N`` or ``listen: socket://...``).  ``close()`` ends it
    (SIGTERM, then SIGKILL after 10 s) and keeps ``out``, ``err`` and ``returncode``."""

    def __init__(self, *args, announce=True):
        self.proc = subprocess.Popen(firmware_cmd(*args), stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, cwd=ROOT)
        self.out = self.err = ""
        if not announce:
            return
        # the first stdout line names the link: 'pty: /dev/pts/N' or 'listen: socket://...'
        r, _, _ = select.select([self.proc.stdout], [], [], 60)
        line = self.proc.stdout.readline() if r else ""
        if not line.startswith(("pty: ", "listen: socket://")):
            self.close()
            raise AssertionError(f"firmware-sim did not print 'pty: ...' or 'listen: ...' "
                                 f"first: {line!r} {self.err[-2000:]}")
        self.path = line.split()[1]

    def wait(self, timeout: float) -> int:
        """Wait for the program to end by itself; returns its exit status."""
        self.proc.wait(timeout)
        return self.close()

    def close(self) -> int:
        end_child(self.proc)
        if not self.proc.stdout.closed:
            self.out += self.proc.stdout.read()
            self.err += self.proc.stderr.read()
            self.proc.stdout.close()
            self.proc.stderr.close()
        self.returncode = self.proc.returncode
        return self.returncode


# The firmware runs the scene in real time; the tests stop it (SIGTERM) when done.  The
# scene is far longer than any test needs: the firmware's start-up and a hostctl process
# importing numpy and filterpy take seconds on a loaded machine.
SCENE_S = "60"


def collect_until(dev, cond, timeout=5.0):
    snaps = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        snaps += list(dev.telemetry(seconds=0.05))
        if cond(snaps):
            return snaps
    raise AssertionError("condition not reached within the timeout")
