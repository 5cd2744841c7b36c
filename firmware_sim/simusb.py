"""A simulated CCam ATIS as a real pyusb backend (``usb.backend.IBackend``).

    from firmware_sim.simusb import SimBackend, SimCamera, scene_source
    backend = SimBackend(SimCamera(scene_source("face_occlusion", seconds=5), realtime=False))
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x00F4, backend=backend)

The device has the camera's descriptors (one configuration, interface 0, bulk IN endpoint
0x81 with wMaxPacketSize 512), answers the vendor requests of ``firmware_sim.usb`` like the
camera and rejects any other control request with a pipe error (USBError errno 32).  After
the start command it serves CCam ATIS words (``springtrack.io.ccam.encode``) from a source:
a simulated scene or a replayed event file.  ``realtime=True`` releases each event only when
the device clock (wall time since start) has reached its timestamp; otherwise data is served
as fast as the host reads.  Faults (``firmware_sim.faults``) are injected on the read path.

pyusb conventions kept: bulk reads fill the caller's ``array('B')`` and return the byte
count; lengths must be a multiple of wMaxPacketSize (libusb would report an overflow,
errno 75); timeouts raise USBTimeoutError (errno 110); a vanished device raises USBError
errno 19 on every call through its old handle and leaves the enumeration until it
re-enumerates (new address, unconfigured).
"""
from __future__ import annotations

import errno
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
import usb.backend
import usb.core

from springtrack.events import as_events

from . import usb as camusb
from .faults import Faults

MAX_PACKET = 512
LOOKAHEAD_US = 20_000        # realtime: scene data generated this far ahead of the clock
DEVICE_FIFO_BYTES = 16 << 20  # the simulated camera's own buffer; beyond it, it drops
SIM_SERIAL = 0x0ACE


class _Desc:
    def __init__(self, **kw):
        self.__dict__.update(kw)


def _usb_error(code: int, text: str):
    if code == errno.ETIMEDOUT:
        return usb.core.USBTimeoutError(text, -7, code)
    return usb.core.USBError(text, None, code)


# ---- sources: chunks of (CCam bytes, release marks) -------------------------------------
class Chunk:
    """Encoded words; ``marks_t[i]``: bytes ``[0, marks_off[i])`` may be sent once the
    device clock reaches ``marks_t[i]``."""
    __slots__ = ("data", "marks_t", "marks_off", "pos", "n_events")

    def __init__(self, data, marks_t, marks_off, n_events):
        self.data = data
        self.marks_t = marks_t
        self.marks_off = marks_off
        self.pos = 0
        self.n_events = n_events


def encode_chunk(events) -> Chunk | None:
    from springtrack.io.ccam import encode
    ev = as_events(events)
    if len(ev) == 0:
        return None
    th = ev["t"] >> 11
    new = np.ones(len(ev), np.int64)
    new[1:] = th[1:] != th[:-1]
    off = 4 * (np.arange(1, len(ev) + 1) + np.cumsum(new))
    data = bytearray(encode(ev))
    if len(data) != off[-1]:
        raise RuntimeError(f"ccam encode produced {len(data)} bytes, expected {off[-1]} "
                           "(one time-high word per new 2048 us period): layout changed?")
    return Chunk(data, ev["t"].copy(), off, len(ev))


def encode_stream_chunk(events, fmt: str) -> Chunk | None:
    """A Prophesee EVT 2.0 / 3.0 stream as one chunk, released when its last event is due
    (the springtrack.io encoders start every call from time-high 0, so a stream is encoded
    in one piece)."""
    import importlib
    ev = as_events(events)
    if len(ev) == 0:
        return None
    enc = importlib.import_module(f"springtrack.io.{fmt}").encode
    data = bytearray(enc(ev))
    return Chunk(data, ev["t"][-1:].copy(), np.array([len(data)], np.int64), len(ev))


def scene_source(scene: str, seconds: float | None = None, seed: int = 0,
                 chunk_us: int = 2000, **scene_params):
    """Events of a firmware_sim scene, chunk by chunk (generated lazily)."""
    from springtrack.sim.sensor import simulate
    for events, _truth in simulate(scene, seconds, seed=seed, chunk_us=chunk_us, **scene_params):
        yield events


def file_source(path, width: int = camusb.PROFILES["ccam_atis"].width,
                height: int = camusb.PROFILES["ccam_atis"].height, stats: dict | None = None):
    """Events of any file ``springtrack.io`` reads, re-encoded for the CCam geometry;
    events outside ``width x height`` are dropped and counted in ``stats['outside']``."""
    from springtrack import io as stio
    stats = {} if stats is None else stats
    stats.setdefault("outside", 0)
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: replay file not found")
    for chunk in stio.open(path):
        ev = as_events(chunk)
        keep = (ev["x"] < width) & (ev["y"] < height)
        stats["outside"] += int((~keep).sum())
        yield ev[keep] if not keep.all() else ev


def events_source(events, chunk_events: int = 4096):
    """An in-memory event array, in pieces (tests)."""
    ev = as_events(events)
    for s in range(0, len(ev), chunk_events):
        yield ev[s:s + chunk_events]


def burst_chunks(t0: int, t1: int, rate: float, seed: int = 0, width=304, height=240):
    """Noise events at ``rate``/s over [t0, t1), one chunk per time-high period (2048 us).

    One period of noise is encoded once (``springtrack.io.ccam.encode``); each period reuses
    its event words after its own time-high word, so a burst far above the processing rate
    costs the simulated camera almost nothing."""
    from springtrack.events import make
    from springtrack.io.ccam import encode
    rng = np.random.default_rng(seed)
    per = max(1, int(rate * 2048e-6))
    one = make(np.sort(rng.integers(0, 2048, per)), rng.integers(0, width, per),
               rng.integers(0, height, per), rng.integers(0, 2, per))
    words = encode(one)                        # time-high 0, then the events of one period
    if len(words) != 4 * (per + 1):
        raise RuntimeError("ccam encode: expected one time-high word per 2048 us period")
    body = words[4:]
    for th in range(t0 >> 11, ((t1 - 1) >> 11) + 1):
        head = encode(make([th << 11], [0], [0], [0]))[:4]     # that period's time-high word
        data = bytearray(head + body)
        yield Chunk(data, np.array([th << 11], np.int64), np.array([len(data)], np.int64), per)


class SimCamera:
    """Device-side state of one simulated CCam ATIS."""

    def __init__(self, source, serial: int = SIM_SERIAL, realtime: bool = False,
                 faults: Faults | None = None, bus: int = 1, address: int = 4,
                 commit_us: int = 250, fmt: str = "ccam"):
        """``fmt``: ``ccam`` (the CCam ATIS: set-up requests, start command) or ``evt2`` /
        ``evt3`` (a Prophesee board already streaming: the source must be one array, served
        as a single chunk; control requests other than the CCam ones are refused)."""
        if fmt not in ("ccam", "evt2", "evt3"):
            raise ValueError(f"simulated camera format must be ccam, evt2 or evt3, got {fmt!r}")
        self.fmt = fmt
        self.source = iter(source)
        self.serial = serial
        self.realtime = realtime
        self.commit_us = int(commit_us)    # realtime: longest wait before a short transfer
        self.faults = faults or Faults()
        self.bus, self.address = bus, address
        self.lock = threading.RLock()
        self.connected = True
        self.generation = 0              # bumped on every disconnect: old handles die
        self.reconnect_at = 0.0
        self.fifo: deque[Chunk] = deque()
        self.exhausted = False
        self.words_out = 0               # word grid position (corruption schedule)
        self.t0_wall = None              # device clock origin: wall time when the first
        self.t_origin = None             # chunk was made, and its first event's time
        self.skip_before = None          # events before this time are lost (disconnect)
        self._burst = None
        self.counts = dict(bulk_reads=0, bytes_sent=0, events_generated=0, control_in=0,
                           control_out=0, rejected=0, overflow=0, timeouts=0, starts=0,
                           disconnects=0, reconnects=0, device_overflow_bytes=0,
                           device_overflow_events=0)
        self._reset_state()

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
        return self.registers.get(0x000) == 0xC81 and self.registers.get(0x400) == 0xC81

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
            ev = next(self.source, None)
            if ev is None:
                self.exhausted = True
                return None
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
            c = encode_chunk(ev) if self.fmt == "ccam" else encode_stream_chunk(ev, self.fmt)
            self.counts["events_generated"] += c.n_events
            f.corrupt(c.data, self.words_out)
            self.words_out += len(c.data) // 4
            return c

    def _releasable(self, c: Chunk, now_t) -> int:
        """Bytes of chunk ``c`` (from its start) the device may send now."""
        if now_t is None:
            return len(c.data)
        k = int(np.searchsorted(c.marks_t, now_t, side="right"))
        return int(c.marks_off[k - 1]) if k else 0

    def _fill(self, want: int):
        """Generate chunks until ``want`` bytes are queued (max-speed) or the device clock
        is passed (realtime)."""
        queued = sum(len(c.data) - c.pos for c in self.fifo)
        while not self.exhausted:
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
            raise _usb_error(errno.ENODEV, "No such device (it may have been disconnected)")

    def bulk_read(self, buff, timeout_ms: int) -> int:
        n_max = len(buff)
        if n_max % MAX_PACKET:
            self.counts["overflow"] += 1
            raise _usb_error(errno.EOVERFLOW, f"Overflow: read of {n_max} bytes is not a "
                                              f"multiple of wMaxPacketSize {MAX_PACKET}")
        deadline = time.monotonic() + max(timeout_ms, 1) / 1000.0
        fault = self.faults.before_read()
        if fault == "stall":
            self.halted = True
        if self.halted:
            raise _usb_error(errno.EPIPE, "Pipe error (endpoint 0x81 halted)")
        if fault == "timeout":
            time.sleep(max(timeout_ms, 1) / 1000.0)
            self.counts["timeouts"] += 1
            raise _usb_error(errno.ETIMEDOUT, "Operation timed out")
        self.counts["bulk_reads"] += 1
        out = memoryview(buff).cast("B")
        while True:
            with self.lock:
                if not self.started:
                    n = 0
                else:
                    n = self._copy(out, n_max)
            if n:
                self.counts["bytes_sent"] += n
                return n
            now = time.monotonic()
            if now >= deadline:
                self.counts["timeouts"] += 1
                raise _usb_error(errno.ETIMEDOUT, "Operation timed out")
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
        avail = self._releasable(c, now_t) - c.pos
        for c2 in list(self.fifo)[1:]:
            if avail >= n_max:
                break
            avail += self._releasable(c2, now_t)
        return avail >= n_max

    def _copy(self, out, n_max: int) -> int:
        self._fill(n_max)
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
                self.fifo.appendleft(Chunk(tail, np.array([-(1 << 62)], np.int64),
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
                raise _usb_error(errno.EPIPE, f"Pipe error (bias load refused: {e})") from None
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
        raise _usb_error(errno.EPIPE, f"Pipe error (request 0x{bm:02X}/0x{req:02X} "
                                      f"wValue 0x{wvalue:04X} not supported)")

    def _on_start(self):
        self.counts["starts"] += 1
        now_t = self.device_time() if self.realtime and self.counts["starts"] > 1 else None
        if now_t is not None:
            # after a reconnect the clock ran on: what happened meanwhile is lost
            self.skip_before = now_t if self.skip_before is None else max(self.skip_before, now_t)


class SimBackend(usb.backend.IBackend):
    """pyusb backend over one or more :class:`SimCamera` devices."""

    def __init__(self, *cameras: SimCamera, vid: int = camusb.CCAM_VID, pid: int = camusb.CCAM_PID):
        super().__init__()
        self.cameras = list(cameras)
        self.vid, self.pid = vid, pid

    # ---- descriptors ---------------------------------------------------------------
    def enumerate_devices(self):
        for cam in self.cameras:
            if cam.present():
                yield cam

    def get_device_descriptor(self, dev):
        return _Desc(bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0xFF,
                     bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=64,
                     idVendor=self.vid, idProduct=self.pid, bcdDevice=0x0100, iManufacturer=0,
                     iProduct=0, iSerialNumber=0, bNumConfigurations=1, address=dev.address,
                     bus=dev.bus, port_number=1, port_numbers=(1,), speed=usb.util.SPEED_HIGH)

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(f"configuration index {config} out of range")
        return _Desc(bLength=9, bDescriptorType=2, wTotalLength=25, bNumInterfaces=1,
                     bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80, bMaxPower=250,
                     extra_descriptors=[])

    def get_interface_descriptor(self, dev, intf, alt, config):
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError(f"interface {intf} alt {alt} of configuration {config} out of range")
        return _Desc(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
                     bNumEndpoints=1, bInterfaceClass=0xFF, bInterfaceSubClass=0,
                     bInterfaceProtocol=0, iInterface=0, extra_descriptors=[])

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if (ep, intf, alt, config) != (0, 0, 0, 0):
            raise IndexError(f"endpoint {ep} out of range")
        return _Desc(bLength=7, bDescriptorType=5, bEndpointAddress=camusb.EP_IN,
                     bmAttributes=0x02, wMaxPacketSize=MAX_PACKET, bInterval=0, bRefresh=0,
                     bSynchAddress=0, extra_descriptors=[])

    # ---- handles ---------------------------------------------------------------------
    def _cam(self, h) -> SimCamera:
        cam, gen = h
        if not cam.connected or cam.generation != gen:
            raise _usb_error(errno.ENODEV, "No such device (it may have been disconnected)")
        return cam

    def open_device(self, dev):
        if not dev.present():
            raise _usb_error(errno.ENODEV, "No such device (it may have been disconnected)")
        return (dev, dev.generation)

    def close_device(self, dev_handle):
        pass

    def set_configuration(self, dev_handle, config_value):
        cam = self._cam(dev_handle)
        if config_value not in (0, 1):
            raise _usb_error(errno.EINVAL, f"Invalid parameter (configuration {config_value})")
        cam.configuration = config_value

    def get_configuration(self, dev_handle):
        return self._cam(dev_handle).configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        self._cam(dev_handle)
        if (intf, altsetting) != (0, 0):
            raise _usb_error(errno.EINVAL, "Invalid parameter (alternate setting)")

    def claim_interface(self, dev_handle, intf):
        cam = self._cam(dev_handle)
        if intf != 0:
            raise _usb_error(errno.ENOENT, f"Entity not found (interface {intf})")
        cam.claimed.add(intf)

    def release_interface(self, dev_handle, intf):
        cam = self._cam(dev_handle)
        cam.claimed.discard(intf)

    # ---- transfers -------------------------------------------------------------------
    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        cam = self._cam(dev_handle)
        if ep != camusb.EP_IN:
            raise _usb_error(errno.EPIPE, f"Pipe error (no IN endpoint 0x{ep:02X})")
        if 0 not in cam.claimed:
            raise _usb_error(errno.EBUSY, "Resource busy (interface 0 not claimed)")
        if cam.configuration != 1:
            raise _usb_error(errno.EIO, "Input/Output Error (device not configured)")
        if timeout is None or timeout <= 0:
            raise ValueError("simulated camera: bulk reads need a finite timeout")
        return cam.bulk_read(buff, timeout)

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        self._cam(dev_handle)
        raise _usb_error(errno.EPIPE, f"Pipe error (no OUT endpoint 0x{ep:02X})")

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        cam = self._cam(dev_handle)
        with cam.lock:
            return cam.control(bmRequestType, bRequest, wValue, wIndex, data)

    def clear_halt(self, dev_handle, ep):
        self._cam(dev_handle).halted = False

    def reset_device(self, dev_handle):
        cam = self._cam(dev_handle)
        cam._reset_state()

    def is_kernel_driver_active(self, dev_handle, intf):
        self._cam(dev_handle)
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        self._cam(dev_handle)

    def attach_kernel_driver(self, dev_handle, intf):
        self._cam(dev_handle)
