"""Ports the firmware link serves on, all with the pyserial interface ``firmware_sim.link``
uses (``read(n)`` honouring ``timeout``, ``write(b)`` returning the count written,
``in_waiting``, ``fileno()``, ``close()``):

* :class:`PtyPort` - a fresh pseudo-terminal pair for tests; the host opens ``.path``
  (``/dev/pts/N``).  :func:`announce_pty` prints ``pty: /dev/pts/N`` (flushed).
* :class:`TcpServer` - listens on TCP (127.0.0.1 by default; any other address needs a
  key of at least 16 bytes, docs/protocol.md "Threat model") and yields one
  :class:`FdPort` per accepted connection, with TCP keepalive on; hosts connect with
  ``socket://HOST:PORT``.
* :func:`open_port` - an existing port by pyserial URL (``/dev/ttyACM0``, ``/dev/pts/N``,
  ``socket://host:port``, ``loop://``).
"""
from __future__ import annotations

import fcntl
import ipaddress
import os
import select
import socket
import struct
import sys
import termios
import time
import tty

import serial

from springtrack.wire import check_key

KEEPALIVE_IDLE_S = 10      # TCP keepalive: first probe after this much silence,
KEEPALIVE_INTERVAL_S = 5   # then one probe every this,
KEEPALIVE_PROBES = 3       # and the connection is dead after this many unanswered


class FdPort:
    """A pyserial-like port over a file descriptor or a connected socket (non-blocking)."""

    def __init__(self, fd: int | None = None, sock: socket.socket | None = None, name: str = ""):
        self.sock = sock
        self.fd = sock.fileno() if sock is not None else fd
        os.set_blocking(self.fd, False)
        self.timeout = 0.01
        self.name = name
        self.is_open = True

    def fileno(self) -> int:
        return self.fd

    @property
    def in_waiting(self) -> int:
        r, _, _ = select.select([self.fd], [], [], 0)
        return 4096 if r else 0

    def read(self, n: int = 1) -> bytes:
        r, _, _ = select.select([self.fd], [], [], self.timeout)
        if not r:
            return b""
        try:
            data = self.sock.recv(n) if self.sock is not None else os.read(self.fd, n)
        except BlockingIOError:
            return b""
        if not data:
            raise serial.SerialException(f"{self.name or 'port'}: peer closed the connection")
        return data

    def write(self, data: bytes) -> int:
        try:
            return self.sock.send(data) if self.sock is not None else os.write(self.fd, data)
        except BlockingIOError:
            return 0

    def reset_input_buffer(self) -> None:
        while self.in_waiting:
            try:
                if not self.read(4096):
                    break
            except serial.SerialException:
                break

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            if self.sock is not None:
                self.sock.close()
            else:
                os.close(self.fd)


class PtyPort(FdPort):
    """The master side of a new pty pair.  The slave is put in raw mode (no echo, no line
    discipline) and kept open here so that hosts may come and go without EIO."""

    def __init__(self):
        master, slave = os.openpty()
        tty.setraw(slave)
        self.slave_fd = slave
        self.path = os.ttyname(slave)
        super().__init__(fd=master, name=self.path)

    def unread(self) -> int:
        """Bytes written to the pty that the host has not read yet."""
        try:
            return struct.unpack("i", fcntl.ioctl(self.slave_fd, termios.FIONREAD, b"\0" * 4))[0]
        except OSError:
            return 0

    def close(self, linger: float = 0.0) -> None:
        """Close both ends, after waiting up to ``linger`` seconds for the host to read what
        is still in the pty (closing the master discards it: e.g. the ACK of SHUTDOWN)."""
        end = time.monotonic() + linger
        while self.is_open and self.unread() and time.monotonic() < end:
            time.sleep(0.01)
        if self.is_open:
            super().close()
            os.close(self.slave_fd)


def announce_pty(port: PtyPort, stream=None) -> None:
    """Print the first stdout line the HIL tests and users wait for: ``pty: /dev/pts/N``."""
    stream = stream or sys.stdout
    print(f"pty: {port.path}", file=stream, flush=True)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class TcpServer:
    """A TCP listener for the firmware link; ``accept()`` returns one connection as an
    :class:`FdPort`.  Binding to a non-loopback address without a key is refused."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, key: bytes | None = None):
        if not is_loopback(host) and not key:
            raise ValueError(f"refusing to listen on {host}:{port} without a key: a non-loopback "
                             f"bind needs --key-file (HMAC signing, see docs/protocol.md)")
        check_key(key)
        self.sock = socket.create_server((host, port), reuse_port=False)
        self.host, self.port = self.sock.getsockname()[:2]
        self.url = f"socket://{self.host}:{self.port}"

    def accept(self, timeout: float | None = None) -> FdPort | None:
        r, _, _ = select.select([self.sock], [], [], timeout)
        if not r:
            return None
        try:
            conn, addr = self.sock.accept()
        except (BlockingIOError, ConnectionAbortedError):
            return None
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        keepalive(conn)
        return FdPort(sock=conn, name=f"tcp {addr[0]}:{addr[1]}")

    def close(self) -> None:
        self.sock.close()


def keepalive(sock: socket.socket) -> None:
    """TCP keepalive: a peer that vanished without closing (cable, crash, sleep) is found
    dead after KEEPALIVE_IDLE_S + KEEPALIVE_PROBES * KEEPALIVE_INTERVAL_S (25 s) of silence,
    and its session closed (where the platform has the options)."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for opt, value in (("TCP_KEEPIDLE", KEEPALIVE_IDLE_S), ("TCP_KEEPINTVL", KEEPALIVE_INTERVAL_S),
                       ("TCP_KEEPCNT", KEEPALIVE_PROBES)):
        if hasattr(socket, opt):
            sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, opt), value)


def open_port(url: str, baudrate: int = 3_000_000):
    """An existing port by pyserial URL; errors name the URL."""
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=0.01, write_timeout=0)
    except (serial.SerialException, ValueError) as e:
        raise OSError(f"{url}: cannot open port: {e}") from None
