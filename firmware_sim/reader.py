"""The USB reader thread: owns the device, reads bulk transfers into a buffer pool.

* ``nbuf`` buffers of ``transfer_bytes`` (a multiple of wMaxPacketSize) are allocated once;
  each bulk read goes straight into a free buffer (``array('B')``, no copy) and the filled
  buffer is queued for the processing thread, which hands it back with :meth:`release`.
* Small transfers (real time: the controller ends a transfer with a short packet after a
  fraction of a millisecond) are copied into the tail buffer of the queue if it has room,
  so the queue is bounded in bytes rather than in transfers (the only copy, <= 16 KiB).
* Load shedding: if no buffer is free, the oldest queued transfer is dropped whole and
  counted (like a sensor's event-rate controller); the reader never waits for the consumer
  (except in the lossless mode used to replay a simulated camera at maximum speed).
  The consumer is told a gap happened (``get`` returns ``gap=True``) so the decoder waits
  for a fresh time base instead of stamping events with a stale one.
* One thread owns the device: control requests from other threads are queued with
  :meth:`call` and run between two bulk reads (pyusb is not safe for a control transfer
  while another thread sits in a bulk read).
* Every read has a finite timeout.  Stall (EPIPE): clear_halt and go on.  Disconnect
  (ENODEV): close, report, and reopen with exponential backoff until stopped.
* Any other exception is the supervisor's (``firmware_sim.supervise``): counted, reported,
  and the thread restarted (a fresh connection, a gap before the next transfer).
"""
from __future__ import annotations

import array
import threading
import time
from collections import deque

import usb.core

from . import camera as camusb
from .supervise import Supervisor, where

BACKOFF_S = (0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
COALESCE_MAX = 16 * 1024      # transfers up to this size may be copied into the queued tail


class Reader:
    def __init__(self, open_camera, nbuf: int = 16, transfer_bytes: int = camusb.TRANSFER_BYTES,
                 timeout_ms: int = camusb.READ_TIMEOUT_MS, shed: bool = True,
                 supervisor: Supervisor | None = None, on_give_up=None):
        """``open_camera()`` returns a started :class:`firmware_sim.camera.Camera` (called again
        after a disconnect).  ``shed=False`` (a simulated camera at max speed only: a real
        camera cannot be paused) waits for a free buffer instead of dropping.
        ``supervisor`` restarts the thread after an unexpected exception; ``on_give_up``
        runs when it stops it instead."""
        self.shed = shed
        self.supervisor = supervisor or Supervisor()
        self.on_give_up = on_give_up
        if nbuf < 3:
            raise ValueError(f"the buffer pool needs at least 3 buffers, got {nbuf}")
        self.open_camera = open_camera
        self.timeout_ms = int(timeout_ms)
        self.pool = [array.array("B", bytes(transfer_bytes)) for _ in range(nbuf)]
        self.free: deque[int] = deque(range(nbuf))
        # queued transfers: [buffer index, bytes, gap before it, transfers coalesced in it]
        self.filled: deque[list] = deque()
        self.cond = threading.Condition()
        self.cmds: deque = deque()
        self.cam = None
        self.gap = False                         # data lost before the next transfer
        self.state = "idle"
        self.last_error = ""
        self.log: deque[str] = deque(maxlen=256)  # state changes and errors, for reports
        self.stop_event = threading.Event()
        self.thread = None
        self.counts = dict(transfers=0, bytes=0, transfers_dropped=0, bytes_dropped=0,
                           timeouts=0, stalls=0, disconnects=0, reconnects=0, open_failures=0,
                           short_transfers=0, odd_transfers=0, queue_hwm=0, commands=0,
                           command_errors=0, coalesced=0)

    # ---- lifecycle ---------------------------------------------------------------------
    def start(self) -> None:
        if self.thread is not None and self.thread.is_alive():
            return
        self.stop_event.clear()
        target = self.supervisor.thread_target("usb-reader", self._run, self.stop_event,
                                               on_give_up=self.on_give_up)
        self.thread = threading.Thread(target=target, name="usb-reader", daemon=True)
        self.thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self.stop_event.set()
        with self.cond:
            self.cond.notify_all()
        if self.thread is not None:
            self.thread.join(timeout)
            if self.thread.is_alive():
                raise RuntimeError(f"USB reader thread did not stop within {timeout} s "
                                   f"(at {where(self.thread)})")
            self.thread = None

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    # ---- consumer side -------------------------------------------------------------------
    def get(self, timeout: float = 0.05):
        """-> (buffer index, byte count, gap before it) or None after ``timeout`` s."""
        with self.cond:
            if not self.filled:
                self.cond.wait(timeout)
            if not self.filled:
                return None
            idx, n, gap, _ = self.filled.popleft()
            return idx, n, gap

    def discard_queued(self) -> int:
        """Drop the transfers read but not taken (the host stopped the loop: they are not
        processed, and the camera's next stream starts afresh); returns their bytes."""
        with self.cond:
            items = list(self.filled)
            self.filled.clear()
            self.free.extend(idx for idx, *_ in items)
            if items:
                self.gap = True                  # what comes next is not contiguous
            self.cond.notify_all()
        return sum(n for _, n, *_ in items)

    def release(self, idx: int) -> None:
        with self.cond:
            self.free.append(idx)
            if not self.shed:
                self.cond.notify_all()

    def queue_depth(self) -> int:
        return len(self.filled)

    def call(self, fn, timeout: float = 2.0):
        """Run ``fn(camera)`` in the reader thread between two reads; returns its result or
        raises its exception (or TimeoutError / RuntimeError if no camera is open)."""
        if not self.running:
            if self.cam is None:
                raise RuntimeError("no camera open")
            return fn(self.cam)
        done = threading.Event()
        box = {}
        self.cmds.append((fn, box, done))
        if not done.wait(timeout):
            raise TimeoutError(f"camera command not executed within {timeout} s")
        if "error" in box:
            raise box["error"]
        return box.get("result")

    # ---- the reader thread ---------------------------------------------------------------
    def _take_buffer(self) -> int | None:
        with self.cond:
            if not self.shed:                    # lossless (max-speed replay): wait
                while not self.free and not self.stop_event.is_set():
                    self.cond.wait(0.05)
                return self.free.popleft() if self.free else None
            if self.free:
                return self.free.popleft()
            idx, n, _, k = self.filled.popleft()  # shed load: drop the oldest transfer(s)
            self.counts["transfers_dropped"] += k
            self.counts["bytes_dropped"] += n
            if self.filled:                      # the gap is before the new oldest
                self.filled[0][2] = True
            else:
                self.gap = True
            return idx

    def _run_commands(self) -> None:
        while self.cmds:
            fn, box, done = self.cmds.popleft()
            self.counts["commands"] += 1
            try:
                box["result"] = fn(self.cam)
            except Exception as e:               # reported to the caller, never fatal here
                self.counts["command_errors"] += 1
                box["error"] = e
            done.set()

    def _connect(self) -> bool:
        for k in range(10 ** 9):
            if self.stop_event.is_set():
                return False
            try:
                self.cam = self.open_camera()
                self.state = "streaming"
                return True
            except Exception as e:               # never let the reader thread die
                self.counts["open_failures"] += 1
                self.last_error = f"open failed: {e}"
                self.state = "reconnecting"
                if k == 0 or k % 20 == 0:
                    self.log.append(f"open failed ({k + 1}x): {e}")
                self.stop_event.wait(BACKOFF_S[min(k, len(BACKOFF_S) - 1)])
        return False

    def _lost(self, e: Exception) -> None:
        self.counts["disconnects"] += 1
        self.last_error = f"device disconnected: {e}"
        self.state = "disconnected"
        self.log.append(f"disconnected: {e}; reconnecting with backoff")
        try:
            self.cam.close()
        except Exception:
            pass
        self.cam = None
        with self.cond:
            self.gap = True

    def _run(self) -> None:
        first = self.cam is None
        if self.counts["bytes"]:
            with self.cond:                      # a restart: the set-up drains a read
                self.gap = True
        try:
            while not self.stop_event.is_set():
                if self.cam is None:
                    if not self._connect():
                        break
                    if not first:
                        self.counts["reconnects"] += 1
                        self.log.append(f"reconnected after {self.counts['open_failures']} "
                                        f"failed attempt(s) in total")
                    first = False
                if self.cmds:
                    self._run_commands()
                idx = self._take_buffer()
                if idx is None:
                    continue
                buf = self.pool[idx]
                try:
                    n = self.cam.read_into(buf, self.timeout_ms)
                except usb.core.USBError as e:
                    self.release(idx)
                    if camusb.is_disconnect(e):
                        self._lost(e)
                    elif camusb.is_stall(e):
                        self.counts["stalls"] += 1
                        self.last_error = f"stall: {e}"
                        self.log.append(f"endpoint stalled ({e}); halt cleared")
                        try:
                            self.cam.clear_halt()
                        except usb.core.USBError as e2:
                            if camusb.is_disconnect(e2):
                                self._lost(e2)
                    else:
                        self.last_error = f"bulk read: {e}"
                        self._lost(e)
                    continue
                except Exception:
                    self.release(idx)            # the pool keeps every buffer
                    raise
                if n == 0:
                    self.counts["timeouts"] += 1
                    self.release(idx)
                    continue
                c = self.counts
                c["transfers"] += 1
                c["bytes"] += n
                if n % 4:
                    c["odd_transfers"] += 1
                elif n < len(buf) and n % 512:
                    c["short_transfers"] += 1
                with self.cond:
                    tail = self.filled[-1] if self.filled else None
                    if (tail is not None and not self.gap and n <= COALESCE_MAX
                            and tail[1] + n <= len(self.pool[tail[0]])):
                        # a small transfer (real time: short packets) joins the queued tail
                        # buffer: the queue is bounded in bytes, not in transfers
                        memoryview(self.pool[tail[0]])[tail[1]:tail[1] + n] = \
                            memoryview(buf)[:n]
                        tail[1] += n
                        tail[3] += 1
                        c["coalesced"] += 1
                        self.free.append(idx)
                    else:
                        self.filled.append([idx, n, self.gap, 1])
                        self.gap = False
                    if len(self.filled) > c["queue_hwm"]:
                        c["queue_hwm"] = len(self.filled)
                    self.cond.notify()
                # yield the GIL to the processing thread just notified, before this thread's
                # next read runs its Python set-up: otherwise the hand-off waits for that
                # set-up, most of the loop's latency after the USB's (docs/firmware.md)
                time.sleep(0)
        finally:
            self._run_commands()
            if self.cam is not None:
                try:
                    self.cam.close()
                except Exception:
                    pass
                self.cam = None
            self.state = "stopped"
