"""The simulated camera as a device: its clock, FIFO, vendor requests and faults.

:class:`SimCamera` is what sits behind the USB cable: a CCam ATIS (after the start command)
or a Prophesee-style EVK streaming EVT 2.0 / 2.1 / 3.0 words.  It serves words
(``simcam.words``) made from a source (``firmware_sim.sources``) of event arrays, or of
ready :class:`~firmware_sim.simcam.words.Chunk` s (a recording's own words, replayed as
they are).
``realtime=True`` releases each event only when the device clock (wall time since the
first chunk) has reached its timestamp; otherwise data is served as fast as the host reads.
Faults (``firmware_sim.faults``) are injected on the read path.  The pyusb side of the
cable is ``simcam.backend.SimBackend``.

Errors are raised as libusb reports them through pyusb: timeouts as USBTimeoutError
(errno 110), a vanished device as USBError errno 19, a halted endpoint errno 32, a read
that is not a multiple of wMaxPacketSize errno 75.
"""
from __future__ import annotations

import errno
import threading
import time
from collections import deque

import numpy as np
import usb.core

from springtrack.events import as_events

from .. import camera as camusb
from ..faults import Faults
from .spoil import SPOILERS
from .words import ENCODERS, Chunk, burst_chunks

CCAM_ONLY_FAULTS = ("burst",)     # it writes CCam words

MAX_PACKET = 512
LOOKAHEAD_US = 20_000        # realtime: scene data generated this far ahead of the clock
DEVICE_FIFO_BYTES = 16 << 20  # the simulated camera's own buffer; beyond it, it drops
SIM_SERIAL = 0x0ACE
CUT_TAIL = -(1 << 62)        # the release time of the cut-off tail of a transfer (at once)


def usb_error(code: int, text: str):
    """The pyusb exception libusb's ``code`` (an errno) raises."""
    if code == errno.ETIMEDOUT:
        return usb.core.USBTimeoutError(text, -7, code)
    return usb.core.USBError(text, None, code)


class SimCamera:
    """Device-side state of one simulated camera."""

    def __init__(self, source, serial: int = SIM_SERIAL, realtime: bool = False,
                 faults: Faults | None = None, bus: int = 1, address: int = 4,
                 commit_us: int = 250, fmt: str = "ccam", legacy: bool = False):
        """``fmt``: ``ccam`` (the CCam ATIS: set-up requests, start command) or ``evt2`` /
        ``evt21`` / ``evt3`` (a Prophesee EVK already streaming those words, ``legacy``:
        EVT 2.1 in the IMX636 order; control requests other than the CCam ones are
        refused)."""
        if fmt not in ENCODERS:
            raise ValueError(f"simulated camera format must be one of {', '.join(ENCODERS)}, "
                             f"got {fmt!r}")
        faults = faults or Faults()
        if fmt != "ccam" and (bad := [f for f in CCAM_ONLY_FAULTS if f in faults]):
            raise ValueError(f"fault(s) {', '.join(bad)} inject CCam words; the simulated "
                             f"camera streams {fmt} (use them with the CCam ATIS)")
        self.fmt = fmt
        self.legacy = legacy
        self._encode = ENCODERS[fmt](legacy=legacy)
        self.spoiler = SPOILERS[fmt](legacy=legacy)
        self.source = iter(source)
        self.serial = serial
        self.realtime = realtime
        self.commit_us = int(commit_us)    # realtime: longest wait before a short transfer
        self.faults = faults
        self.bus, self.address = bus, address
        self.lock = threading.RLock()
        self.connected = True
        self.generation = 0              # bumped on every disconnect: old handles die
        self.reconnect_at = 0.0
        self.fifo: deque[Chunk] = deque()
        self.exhausted = False
        self.bytes_out = 0               # stream bytes made so far: the corruption's word grid
        self.t0_wall = None              # device clock origin: wall time when the first
        self.t_origin = None             # chunk was made, and its first event's time
        self.skip_before = None          # events before this time are lost (disconnect)
        self.source_error = None         # why the source stopped early, if it failed
        self._burst = None
        self.counts = dict(bulk_reads=0, bytes_sent=0, events_generated=0, control_in=0,
                           control_out=0, rejected=0, overflow=0, timeouts=0, starts=0,
                           disconnects=0, reconnects=0, device_overflow_bytes=0,
                           device_overflow_events=0, restart_dropped_bytes=0)
        self._reset_state()

    def restart(self, source) -> None:
        """Serve a new ``source`` from its beginning (a replay): the FIFO, the clock and the
        one-off faults start again; the counters keep counting."""
        with self.lock:
            self.source = iter(source)
            self._encode = ENCODERS[self.fmt](legacy=self.legacy)   # a stream from its start
            self.fifo.clear()
            self.exhausted = False
            self.t0_wall = self.t_origin = self.skip_before = None
            self.source_error = None
            self._burst = None
            self.faults.rearm()
            self._reset_state()            # not started: the host's set-up runs again

    def _reset_state(self):
        self.configuration = 0
        self.claimed = set()
        self.registers = {}
        self.biases = {}
        self.halted = False

    @property
    def started(self) -> bool:
        if self.fmt != "ccam":           # EVT boards: streaming started by vendor tools
            return True
        return all(self.registers.get(reg) == value for reg, value in camusb.CMD_START)

    @property
    def finished(self) -> bool:
        """The source is exhausted and every byte was read (lock-free: the reader may hold
        the device lock while it simulates the next chunk)."""
        return self.exhausted and not self.fifo and self.connected

    def present(self) -> bool:
        with self.lock:
            if not self.connected and time.monotonic() >= self.reconnect_at:
                self.connected = True
                self.address += 1
                self._reset_state()
                self.counts["reconnects"] += 1
            return self.connected

    # ---- device clock and data ---------------------------------------------------------
    def device_time(self) -> int | None:
        if self.t0_wall is None or self.t_origin is None:
            return None
        return self.t_origin + int((time.monotonic() - self.t0_wall) * 1e6)

    def wall_of(self, t_us: int) -> float | None:
        """Wall (time.monotonic) at which event time ``t_us`` occurred (realtime mode)."""
        if self.t0_wall is None or self.t_origin is None:
            return None
        return self.t0_wall + (t_us - self.t_origin) / 1e6

    def _next_chunk(self) -> Chunk | None:
        f = self.faults
        if self._burst is not None:
            c = next(self._burst, None)
            if c is not None:
                f.injected["burst_events"] += c.n_events
                return c
            self._burst = None
        while True:
            try:
                ev = next(self.source, None)
            except Exception as e:   # noqa: BLE001 - any failure of the source ends the stream
                # (as a camera that stops sending), told by source_error, never by an
                # exception in the host's reader thread
                self.source_error = f"{type(e).__name__}: {e}"
                ev = None
            if ev is None:
                self.exhausted = True
                return None
            if isinstance(ev, Chunk):          # words as they are (a replayed recording)
                c = self._ready_chunk(ev)
                if c is None:
                    continue
                return c
            ev = as_events(ev)
            if self.skip_before is not None and len(ev):
                ev = ev[ev["t"] >= self.skip_before]
            if len(ev) == 0:
                continue
            if "burst" in f and not f.burst_done and ev["t"][-1] >= f.plan.burst_at_us:
                f.burst_done = True
                b0 = f.plan.burst_at_us
                b1 = b0 + f.plan.burst_us
                self.skip_before = b1 if self.skip_before is None else max(self.skip_before, b1)
                before = ev[ev["t"] < b0]
                self._burst = burst_chunks(b0, b1, f.plan.burst_rate, f.plan.seed)
                f.injected["burst"] += 1
                if len(before) == 0:
                    return self._next_chunk()
                ev = before
            if self.t_origin is None:
                self.t_origin = int(ev["t"][0])
                if self.realtime and self.t0_wall is None:
                    self.t0_wall = time.monotonic()
            c = self._encode(ev)
            self.counts["events_generated"] += c.n_events
            return self._spoiled(c)

    def _ready_chunk(self, c: Chunk) -> Chunk | None:
        """A chunk of words from the source: None if it lies before ``skip_before`` (lost
        with a disconnect, whole chunks: the words cannot be cut by time)."""
        if self.skip_before is not None and c.marks_t[-1] < self.skip_before:
            return None
        if self.t_origin is None:
            self.t_origin = int(c.marks_t[0])
            if self.realtime and self.t0_wall is None:
                self.t0_wall = time.monotonic()
        self.counts["events_generated"] += c.n_events
        return self._spoiled(c)

    def _spoiled(self, c: Chunk) -> Chunk:
        """``c`` through the corrupt fault (its words found on the stream's word grid: a
        replayed chunk may begin inside a word)."""
        u = self.spoiler.unit
        skip = (-self.bytes_out) % u
        self.faults.corrupt(memoryview(c.data)[skip:], -(-self.bytes_out // u), self.spoiler)
        self.bytes_out += len(c.data)
        return c

    def _releasable(self, c: Chunk, now_t) -> int:
        """Bytes of chunk ``c`` (from its start) the device may send now."""
        if now_t is None:
            return len(c.data)
        k = int(np.searchsorted(c.marks_t, now_t, side="right"))
        return int(c.marks_off[k - 1]) if k else 0

    def _fill(self, want: int, deadline: float | None = None):
        """Generate chunks until ``want`` bytes are queued (max-speed) or the device clock
        is passed (realtime), and at most until the monotonic ``deadline`` once one chunk
        is made (a read honours its timeout: the burst fault's chunks take seconds of CPU
        to generate, which a real camera's FIFO does not)."""
        queued = sum(len(c.data) - c.pos for c in self.fifo)
        made = False
        while not self.exhausted:
            if made and deadline is not None and time.monotonic() >= deadline:
                return
            if self.realtime:          # generate LOOKAHEAD_US ahead: events are never late
                now_t = self.device_time()
                if (self.fifo and now_t is not None
                        and self.fifo[-1].marks_t[-1] > now_t + LOOKAHEAD_US):
                    return
            elif queued >= want:
                return
            c = self._next_chunk()
            if c is None:
                return
            self.fifo.append(c)
            made = True
            queued += len(c.data)
            while queued > DEVICE_FIFO_BYTES and len(self.fifo) > 2:
                # the host does not keep up: the camera's own FIFO overflows and loses the
                # oldest unread data (never the chunk being read)
                lost = self.fifo[1]
                del self.fifo[1]
                queued -= len(lost.data)
                self.counts["device_overflow_bytes"] += len(lost.data)
                self.counts["device_overflow_events"] += lost.n_events

    def _check_disconnect(self):
        f = self.faults
        if "disconnect" not in f or f.disconnect_done or not self.fifo:
            return
        if self.fifo[0].marks_t[0] >= f.plan.disconnect_at_us:
            f.disconnect_done = True
            f.injected["disconnect"] += 1
            self.counts["disconnects"] += 1
            self.connected = False
            self.generation += 1
            self.reconnect_at = time.monotonic() + f.plan.disconnect_s
            lost_until = f.plan.disconnect_at_us + int(f.plan.disconnect_s * 1e6)
            self.skip_before = lost_until if self.skip_before is None else max(self.skip_before, lost_until)
            # what the device held for the lost interval is gone; later data stays queued
            self.fifo = deque(c for c in self.fifo if c.marks_t[0] >= lost_until)
            raise usb_error(errno.ENODEV, "No such device (it may have been disconnected)")

    def bulk_read(self, buff, timeout_ms: int) -> int:
        n_max = len(buff)
        if n_max % MAX_PACKET:
            self.counts["overflow"] += 1
            raise usb_error(errno.EOVERFLOW, f"Overflow: read of {n_max} bytes is not a "
                                              f"multiple of wMaxPacketSize {MAX_PACKET}")
        deadline = time.monotonic() + max(timeout_ms, 1) / 1000.0
        fault = self.faults.before_read()
        if fault == "stall":
            self.halted = True
        if self.halted:
            raise usb_error(errno.EPIPE, "Pipe error (endpoint 0x81 halted)")
        if fault == "timeout":
            time.sleep(max(timeout_ms, 1) / 1000.0)
            self.counts["timeouts"] += 1
            raise usb_error(errno.ETIMEDOUT, "Operation timed out")
        self.counts["bulk_reads"] += 1
        out = memoryview(buff).cast("B")
        while True:
            with self.lock:
                if not self.started:
                    n = 0
                else:
                    n = self._copy(out, n_max, deadline)
            if n:
                self.counts["bytes_sent"] += n
                return n
            now = time.monotonic()
            if now >= deadline:
                self.counts["timeouts"] += 1
                raise usb_error(errno.ETIMEDOUT, "Operation timed out")
            wake = self._ready_wall() if self.realtime else None
            pause = 0.001 if wake is None else max(wake - now, 0.00005)
            time.sleep(min(pause, deadline - now))

    def _ready_wall(self) -> float | None:
        """Realtime: wall time at which the next transfer will be due (the oldest pending
        event's time + commit_us), so the read sleeps once instead of polling."""
        with self.lock:
            if not self.fifo or self.t0_wall is None:
                return None
            c = self.fifo[0]
            k = int(np.searchsorted(c.marks_off, c.pos, side="right"))
            if k >= len(c.marks_t):
                return None
            return self.wall_of(int(c.marks_t[k]) + self.commit_us)

    def _commit_due(self, now_t: int, n_max: int) -> bool:
        """Realtime: like the camera's USB controller, end a transfer early (short packet)
        only once the oldest pending word has waited ``commit_us``; else wait for a full
        buffer."""
        if not self.fifo:
            return False
        c = self.fifo[0]
        k = int(np.searchsorted(c.marks_off, c.pos, side="right"))
        if k >= len(c.marks_t):
            return True
        if now_t >= c.marks_t[k] + self.commit_us:
            return True
        if sum(len(c2.data) - c2.pos for c2 in self.fifo) < n_max:
            return False               # not even all it holds would fill the transfer
        avail = self._releasable(c, now_t) - c.pos
        for c2 in list(self.fifo)[1:]:
            if avail >= n_max:
                break
            avail += self._releasable(c2, now_t)
        return avail >= n_max

    def _copy(self, out, n_max: int, deadline: float | None = None) -> int:
        self._fill(n_max, deadline)
        self._check_disconnect()
        now_t = self.device_time() if self.realtime else None
        if now_t is not None and not self._commit_due(now_t, n_max):
            return 0
        n = 0
        while self.fifo and n < n_max:
            c = self.fifo[0]
            end = self._releasable(c, now_t)
            k = min(end - c.pos, n_max - n)
            if k <= 0:
                break
            out[n:n + k] = c.data[c.pos:c.pos + k]
            c.pos += k
            n += k
            if c.pos >= len(c.data):
                self.fifo.popleft()
            else:
                break
        if n:
            m = self.faults.cut(n)
            if m < n:                  # the cut tail is sent first by the next read
                tail = bytearray(out[m:n])
                self.fifo.appendleft(Chunk(tail, np.array([CUT_TAIL], np.int64),
                                           np.array([len(tail)], np.int64), 0))
                n = m
        return n

    # ---- control requests ------------------------------------------------------------
    def control(self, bm: int, req: int, wvalue: int, windex: int, buff) -> int:
        if bm == camusb.REQ_SERIAL[0] and req == camusb.REQ_SERIAL[1] and wvalue == camusb.SERIAL_WVALUE:
            self.counts["control_in"] += 1
            data = bytes([0, 0, 0, 0, 0, 0, (self.serial >> 8) & 0xFF, self.serial & 0xFF])
            k = min(len(buff), len(data))
            buff[:k] = type(buff)("B", data[:k]) if hasattr(buff, "typecode") else data[:k]
            return k
        payload = bytes(buff)
        if bm == 0x40 and req in (camusb.REQ_BIAS_A[1], camusb.REQ_BIAS_B[1]):
            try:
                self.biases[req] = camusb.parse_bias_payload(payload)
            except ValueError as e:
                self.counts["rejected"] += 1
                raise usb_error(errno.EPIPE, f"Pipe error (bias load refused: {e})") from None
            self.counts["control_out"] += 1
            return len(payload)
        if bm == 0x40 and req == camusb.REQ_COMMAND[1] and len(payload) == 4:
            value = int.from_bytes(payload, "big")
            was = self.started
            self.registers[wvalue] = value
            if self.started and not was:
                self._on_start()
            self.counts["control_out"] += 1
            return 4
        self.counts["rejected"] += 1
        raise usb_error(errno.EPIPE, f"Pipe error (request 0x{bm:02X}/0x{req:02X} "
                                      f"wValue 0x{wvalue:04X} not supported)")

    def _on_start(self):
        self.counts["starts"] += 1
        # a (re)start sends whole words: the tail of a word cut by the odd fault before the
        # host stopped is gone (as a real camera's FIFO is flushed by the set-up)
        self.fifo = deque(c for c in self.fifo if c.marks_t[0] != CUT_TAIL)
        # and resumes at a word: a full transfer that followed a cut tail ended mid-word
        # inside the next chunk, whose rest of that word is dropped up to its next mark
        # (a mark ends whole words, simcam.words.Chunk)
        if self.fifo and self.fifo[0].pos:
            c = self.fifo[0]
            k = int(np.searchsorted(c.marks_off, c.pos, side="left"))
            end = int(c.marks_off[k]) if k < len(c.marks_off) else len(c.data)
            self.counts["restart_dropped_bytes"] += end - c.pos
            c.pos = end
            if c.pos >= len(c.data):
                self.fifo.popleft()
        now_t = self.device_time() if self.realtime and self.counts["starts"] > 1 else None
        if now_t is not None:
            # after a reconnect the clock ran on: what happened meanwhile is lost
            self.skip_before = now_t if self.skip_before is None else max(self.skip_before, now_t)

