"""``springtrack mcu run``: a firmware image (image.py) booted in QEMU's model of its board,
its host link on a pty or a TCP port, its event stream (stream.py) loaded where the board
keeps it (boards.py), so that a host steers it over the protocol of docs/protocol.md.

    >>> with Qemu(elf, "netduinoplus2", "events.raw") as q:     # doctest: +SKIP
    ...     print(q.link)                                        # /dev/pts/N

QEMU (``qemu-system-arm``, Debian package qemu-system-arm) runs the ELF as the board would:
reset through the vector table, the UART the image drives mapped to serial0.  SHUTDOWN
from the host ends the image (semihosting SYS_EXIT), and with it QEMU.
"""
from __future__ import annotations

import re
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from .boards import board as get_board
from . import stream
from ..process_end import end_child

QEMU = "qemu-system-arm"
INSTALL_HINT = ("qemu-system-arm is not installed: apt-get install qemu-system-arm "
                "(Debian/Ubuntu; `make test` installs it when missing)")
START_S = 30.0            # QEMU announces its pty within this


def qemu_binary() -> str:
    exe = shutil.which(QEMU)
    if exe is None:
        raise RuntimeError(INSTALL_HINT)
    return exe


def command(elf, board_name: str, stream_file, link: str, icount: bool = False) -> list[str]:
    """QEMU's command line: ``link`` is "pty" or "tcp:HOST:PORT"; ``icount``: the virtual
    clock counts instructions, one per ns (the image's SysTick then counts instructions:
    Board.qemu_tick_ns per tick)."""
    b = get_board(board_name)
    serial = "pty" if link == "pty" else f"{link},server=on,wait=off"
    return [qemu_binary(), "-M", b.name, "-nodefaults", "-display", "none",
            *(["-icount", "shift=0,sleep=off"] if icount else []),
            "-serial", serial, "-net", "none", "-kernel", str(elf),
            "-semihosting-config", "enable=on,target=native",
            "-device", f"loader,file={stream_file},addr=0x{b.stream[0]:x},force-raw=on"]


class Qemu:
    """The image running in QEMU; ``link`` is its host link (a pty path or
    socket://HOST:PORT), ``summary`` what the event stream holds.  ``close()`` ends it."""

    def __init__(self, elf, board_name: str, events, listen: str | None = None,
                 icount: bool = False):
        """``events``: an event file, or (array, width, height)."""
        b = get_board(board_name)
        self.tmp = tempfile.TemporaryDirectory(prefix="springtrack-qemu-")
        data, self.summary = (stream.pack_events(*events, b.stream[1])
                              if isinstance(events, tuple) else stream.pack(events, b.stream[1]))
        sfile = Path(self.tmp.name) / "stream.bin"
        sfile.write_bytes(data)
        link = "pty" if listen is None else "tcp:" + listen
        self.proc = subprocess.Popen(command(elf, board_name, sfile, link, icount),
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        self.err = ""
        if listen is not None:
            self.link = f"socket://{listen}"
            self._wait_listening(listen)
        else:
            self.link = self._wait_pty()

    def _wait_pty(self) -> str:
        end = time.monotonic() + START_S
        while time.monotonic() < end:
            r, _, _ = select.select([self.proc.stdout], [], [], 0.5)
            if r:
                line = self.proc.stdout.readline()
                self.err += line
                m = re.search(r"redirected to (\S+) \(label serial0\)", line)
                if m:
                    return m.group(1)
            if self.proc.poll() is not None:
                break
        self.close()
        raise RuntimeError(f"QEMU did not announce its pty: {self.err.strip()[-1000:]}")

    def _wait_listening(self, listen: str) -> None:
        import socket
        host, _, port = listen.rpartition(":")
        end = time.monotonic() + START_S
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                self.err += self.proc.stdout.read()
                raise RuntimeError(f"QEMU ended: {self.err.strip()[-1000:]}")
            with socket.socket() as s:     # listening: a probe connection would take the
                try:                       # one serial session, so only check the port
                    s.bind((host, int(port)))
                except OSError:
                    return
            time.sleep(0.05)
        self.close()
        raise RuntimeError(f"QEMU did not listen on {listen}")

    def wait(self, timeout: float | None = None) -> int:
        return self.proc.wait(timeout)

    def close(self) -> int:
        end_child(self.proc)
        if not self.proc.stdout.closed:
            self.err += self.proc.stdout.read()
            self.proc.stdout.close()
        self.tmp.cleanup()
        return self.proc.returncode

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
