"""The firmware's host-link server: answers host commands and streams telemetry.

Entry point (used by ``firmware-sim run``)::

    from firmware_sim import link, transport
    port = transport.open_port(url)            # or transport.PtyPort() / TcpServer(...)
    stats = link.serve(port, engine, key=None, stop_event=threading.Event())

``serve`` blocks until ``stop_event`` is set or the port fails (a TCP peer closing), and
returns the link counters.  ``port`` is any pyserial-like object (``read(n)``, ``write(b)``,
``in_waiting``, ``timeout``); ``engine`` implements ``firmware_sim.engine.Engine``.  With a
``key`` every host frame except HELLO must carry a valid HMAC tag and a fresh counter.

Robustness rules (docs/protocol.md, "Reliability"): a frame with a bad CRC/COBS is
dropped and counted; a malformed, unknown or refused command gets a NACK and changes
nothing; a repeated command (same seq, type and payload) is answered from a cache and
not executed twice; an exception inside a handler is NACKed (INTERNAL) and counted,
never propagated.  The link never blocks: writes are non-blocking; while more than
``TX_TELEMETRY_LIMIT`` bytes wait to be written no snapshot is taken from the engine
(they wait in its bounded queue, which drops the oldest and counts them); other frames
are dropped (``tx_dropped``, and the host sees the sequence gap) only beyond
``TX_REPLY_LIMIT`` queued bytes (a host that sends but never reads).
"""
from __future__ import annotations

import os
import select
import sys
import threading
import time
import zlib
from collections import OrderedDict

import numpy as np
import serial

from springtrack import wire
from springtrack.wire import MsgType, Nack

from .engine import UpdateRejected

MAX_MODEL_BYTES = 256 * 1024
REPLY_CACHE = 16
TX_TELEMETRY_LIMIT = 32 * 1024      # unwritten bytes above which no snapshot is taken
TX_REPLY_LIMIT = 1024 * 1024        # bytes queued before even replies are dropped (a host
                                    # that sends but never reads must not exhaust memory)
FIRMWARE_NAME = "firmware-sim"


class LinkServer:
    """One host session over one port (see the module docstring)."""

    def __init__(self, port, engine, key: bytes | None = None, heartbeat_s: float = 1.0,
                 energy_period_us: int = wire.ENERGY_PERIOD_US):
        self.port, self.engine = port, engine
        self.nonce = os.urandom(wire.NONCE_LEN)
        self.guard = wire.ReplayGuard(key, self.nonce) if key else None
        self.reader = wire.FrameReader()
        self.rx_seq = wire.SeqTracker()
        self.tx_seq = int.from_bytes(os.urandom(2), "little")
        self.txq = bytearray()
        self.replies: OrderedDict = OrderedDict()
        self.upload = None
        self.session = False
        self.heartbeat_s = heartbeat_s
        self.energy_period_us, self.next_energy_t = energy_period_us, None
        self.t0 = time.monotonic()
        self.next_beat = self.t0 + heartbeat_s
        self.fd = _port_fd(port)
        self._sent: list[bytes] = []
        self.closed_reason = ""
        self.counts = dict(rx_frames=0, rx_lost=0, rx_retries=0, auth_unsigned=0,
                           auth_bad_tag=0, auth_replay=0, version_refused=0, acks=0, nacks=0,
                           handler_errors=0, tx_frames=0, tx_bytes=0, tx_dropped=0,
                           telemetry_sent=0, telemetry_stale=0, tx_stale_bytes=0,
                           energies_sent=0)

    # ---- main loop ------------------------------------------------------------
    def serve(self, stop_event: threading.Event | None = None) -> dict:
        stop_event = stop_event or threading.Event()
        try:
            self._send_raw(b"\x00")                 # end any garbage the host holds
            while not stop_event.is_set():
                self.step()
            self.drain_telemetry(2.0)            # what the engine produced before the stop
        except (OSError, serial.SerialException) as e:   # peer gone: end this session
            self.closed_reason = str(e)
        return self.stats()

    def drain_telemetry(self, timeout: float) -> None:
        """Forward the engine's queued snapshots and flush, within ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            before = self.counts["tx_frames"] + self.counts["tx_dropped"]
            self.pump_telemetry()
            self._drain()
            if self.counts["tx_frames"] + self.counts["tx_dropped"] == before and not self.txq:
                break
            if len(self.txq) > TX_TELEMETRY_LIMIT // 2 and self.fd is not None:
                select.select([], [self.fd], [], 0.01)
        self.flush(max(0.0, end - time.monotonic()))

    def step(self) -> None:
        """One iteration: read, handle, stream telemetry, heartbeat, write."""
        # wait briefly for a byte, then take all that is there (in_waiting is not a byte
        # count on every pyserial port)
        wire.set_read_timeout(self.port, 0.002)
        data = self.port.read(1)
        if data:
            wire.set_read_timeout(self.port, 0)
            data += self.port.read(65536)
        if data:
            for frame in self.reader.feed(data):
                self.handle(frame)
        self.pump_telemetry()
        now = time.monotonic()
        if self.session and now >= self.next_beat:
            self.next_beat = now + self.heartbeat_s
            self.send(MsgType.HEARTBEAT, wire.encode_heartbeat(**self._beat()))
        self._drain()

    def stats(self) -> dict:
        c = dict(self.counts)
        c.update({f"rx_{k}": v for k, v in self.reader.counts.items() if k != "frames"})
        return c

    # ---- sending ----------------------------------------------------------------
    def send(self, mtype: int, payload: bytes = b"", droppable: bool = False,
             version: int = wire.PROTOCOL_VERSION) -> bytes | None:
        if len(self.txq) > (TX_TELEMETRY_LIMIT if droppable else TX_REPLY_LIMIT):
            self.counts["tx_dropped"] += 1
            self.tx_seq = (self.tx_seq + 1) & 0xFFFF     # the host sees the gap
            return None
        # a leading delimiter too: a host attaching mid-stream skips to the first 0x00
        # (hunting) and still gets the next whole frame
        raw = b"\x00" + wire.encode_frame(mtype, self.tx_seq, payload, version=version)
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        self.counts["tx_frames"] += 1
        self._send_raw(raw)
        return raw

    def _send_raw(self, raw: bytes) -> None:
        self.txq += raw
        self.counts["tx_bytes"] += len(raw)
        self._drain()

    def _drain(self) -> None:
        """Write what the port accepts now without blocking (partial writes are fine)."""
        while self.txq:
            if self.fd is not None:
                _, w, _ = select.select([], [self.fd], [], 0)
                if not w:
                    return
            n = self.port.write(bytes(self.txq[:4096]))
            if not n:
                return
            del self.txq[:n]

    def flush(self, timeout: float) -> None:
        end = time.monotonic() + timeout
        while self.txq and time.monotonic() < end:
            self._drain()
            if self.txq:
                time.sleep(0.001)

    def pump_telemetry(self) -> None:
        """Forward APPLIED reports and snapshots once a host has said HELLO; before that they
        wait in the engine's bounded queue (which drops the oldest and counts them)."""
        if not self.session:
            return
        for gen, t_us in self.engine.poll_applied():
            self.send(MsgType.APPLIED, wire.encode_applied(gen, t_us))
        room = (TX_TELEMETRY_LIMIT - len(self.txq)) // 256     # backpressure: snapshots
        if room <= 0:                                          # wait in the engine's queue
            return
        for snap in self.engine.poll_telemetry(min(64, room)):
            payload = wire.encode_telemetry(snap.t_us, snap.generation, snap.mean_energy,
                                            snap.records, snap.trackers["state"])
            if self.send(MsgType.TELEMETRY, payload, droppable=True) is not None:
                self.counts["telemetry_sent"] += 1
            if snap.energies is not None:
                self._energies(snap)

    def _energies(self, snap) -> None:
        """ENERGIES at most once per ``energy_period_us`` of event time, from the snapshots
        that carry ``energies = (kind index, per-connection array)``."""
        t = int(snap.t_us)
        if self.next_energy_t is not None and t < self.next_energy_t:
            return
        self.next_energy_t = t + self.energy_period_us
        kind, values = snap.energies
        if self.send(MsgType.ENERGIES, wire.encode_energies(t, kind, values),
                     droppable=True) is not None:
            self.counts["energies_sent"] += 1

    def _beat(self) -> dict:
        c = self.counts
        rc = self.reader.counts
        return dict(uptime_us=int((time.monotonic() - self.t0) * 1e6),
                    rx_frames=c["rx_frames"],
                    rx_errors=rc["crc_errors"] + rc["cobs_errors"] + rc["malformed"] + rc["oversize"],
                    rx_lost=c["rx_lost"], tx_frames=c["tx_frames"], tx_dropped=c["tx_dropped"])

    # ---- receiving ----------------------------------------------------------------
    def handle(self, frame: wire.Frame) -> None:
        self.counts["rx_frames"] += 1
        self._sent = []                              # replies to this frame (for the cache)
        if frame.version != wire.PROTOCOL_VERSION:
            self.counts["version_refused"] += 1
            self._nack(frame, Nack.VERSION_MISMATCH,
                       wire.version_reason(wire.PROTOCOL_VERSION, frame.version))
            return
        if self.guard is not None and frame.type != MsgType.HELLO:
            why = self.guard.check(frame)
            if why is not None:                      # dropped, counted, no answer (no oracle)
                self.counts["auth_" + why] += 1
                return
        if self.guard is None and frame.flags & wire.FLAG_SIGNED:
            self._nack(frame, Nack.BAD_STATE, "signed frame on a link without a key: "
                                              "the tag cannot be checked, refused")
            return
        key = (frame.seq, frame.type, zlib.crc32(frame.payload))
        if key in self.replies:                      # a retry: answer again, do nothing
            self.counts["rx_retries"] += 1
            for raw in self.replies[key]:
                self._send_raw(raw)
            return
        if frame.type == MsgType.HELLO:              # a new session: expect anything next
            self.rx_seq.restart(frame.seq)
        else:
            self.counts["rx_lost"] += self.rx_seq.update(frame.seq)
        try:
            self._dispatch(frame)
        except UpdateRejected as e:
            self._nack(frame, e.code, str(e))
        except wire.WireError as e:
            self._nack(frame, Nack.MALFORMED, str(e))
        except Exception as e:                       # noqa: BLE001 - never crash the firmware
            self.counts["handler_errors"] += 1
            self._nack(frame, Nack.INTERNAL, f"{type(e).__name__}: {e}")
        self.replies[key] = self._sent
        while len(self.replies) > REPLY_CACHE:
            self.replies.popitem(last=False)

    def _reply(self, mtype, payload=b"") -> None:
        raw = self.send(mtype, payload)
        if raw is not None:
            self._sent.append(raw)

    def _ack(self, frame, value: int = 0) -> None:
        self.counts["acks"] += 1
        self._reply(MsgType.ACK, wire.encode_ack(frame.seq, frame.type, value))

    def _nack(self, frame, code: Nack, reason: str) -> None:
        self.counts["nacks"] += 1
        raw = self.send(MsgType.NACK, wire.encode_nack(frame.seq, frame.type, code, reason))
        if raw is not None:
            self._sent.append(raw)

    def _dispatch(self, f: wire.Frame) -> None:
        handler = HANDLERS.get(f.type)
        if handler is None:
            self._nack(f, Nack.UNKNOWN_TYPE, f"message type 0x{f.type:02x} is not a host command")
            return
        handler(self, f)

    # ---- command handlers ------------------------------------------------------------
    def on_hello(self, f) -> None:
        version, _name = wire.decode_hello(f.payload)
        if version != wire.PROTOCOL_VERSION:
            self.counts["version_refused"] += 1
            self._nack(f, Nack.VERSION_MISMATCH, wire.version_reason(wire.PROTOCOL_VERSION, version))
            return
        self._new_session()
        info = dict(self.engine.info())
        info.setdefault("firmware", FIRMWARE_NAME)
        payload = wire.encode_info(info, self.nonce, self.guard is not None)
        if len(payload) > wire.MAX_PAYLOAD and isinstance(info.get("trackers"), list):
            # a big model's tracker ids do not fit one frame: say how many were left out
            info["trackers_omitted"] = len(info.pop("trackers"))
            payload = wire.encode_info(info, self.nonce, self.guard is not None)
        self._reply(MsgType.INFO, payload)

    def _new_session(self) -> None:
        """A host said HELLO: snapshots queued for nobody (produced before this session, or
        unread by a host that left) are discarded and counted, so that the host's stream
        starts now; unwritten frames of the previous session are dropped likewise, except the
        remainder of a frame already partly written."""
        self.session = True
        stale = 0
        for _ in range(64):
            got = self.engine.poll_telemetry(256)
            if not got:
                break
            stale += len(got)
        self.engine.poll_applied()
        self.counts["telemetry_stale"] += stale
        # the frame being written is finished (up to its closing delimiter, the first 0x00
        # still queued), never cut: a cut frame would reach the new host as one CRC error
        keep = self.txq.find(0) + 1
        self.counts["tx_stale_bytes"] += len(self.txq) - keep
        del self.txq[keep:]

    def on_model_begin(self, f) -> None:
        total, crc = wire.decode_model_begin(f.payload)
        if not 0 < total <= MAX_MODEL_BYTES:
            raise UpdateRejected(Nack.OUT_OF_RANGE, f"model of {total} bytes: must be 1..{MAX_MODEL_BYTES}")
        self.upload = dict(total=total, crc=crc, buf=bytearray(total), have=np.zeros(total, bool))
        self._ack(f)

    def on_model_chunk(self, f) -> None:
        offset, data = wire.decode_model_chunk(f.payload)
        up = self.upload
        if up is None:
            raise UpdateRejected(Nack.BAD_STATE, "MODEL_CHUNK without MODEL_BEGIN")
        if offset + len(data) > up["total"]:
            raise UpdateRejected(Nack.OUT_OF_RANGE,
                                 f"chunk {offset}+{len(data)} beyond the announced {up['total']} bytes")
        up["buf"][offset:offset + len(data)] = data
        up["have"][offset:offset + len(data)] = True
        self._ack(f)

    def on_model_commit(self, f) -> None:
        total, crc = wire.decode_model_begin(f.payload)
        up, self.upload = self.upload, None
        if up is None:
            raise UpdateRejected(Nack.BAD_STATE, "MODEL_COMMIT without MODEL_BEGIN")
        if (total, crc) != (up["total"], up["crc"]):
            raise UpdateRejected(Nack.INVALID_MODEL, "MODEL_COMMIT length/CRC differ from MODEL_BEGIN")
        missing = int((~up["have"]).sum())
        if missing:
            raise UpdateRejected(Nack.INVALID_MODEL, f"upload incomplete: {missing} of {total} bytes missing")
        if zlib.crc32(up["buf"]) != crc:
            raise UpdateRejected(Nack.INVALID_MODEL, "model text CRC-32 mismatch after upload")
        try:
            text = up["buf"].decode("utf-8")
        except UnicodeDecodeError as e:
            raise UpdateRejected(Nack.INVALID_MODEL, f"model text is not UTF-8: {e}") from None
        self._ack(f, self.engine.load_model(text))

    def on_param_set(self, f) -> None:
        name, value = wire.decode_param_set(f.payload)
        self._ack(f, self.engine.set_param(name, value))

    def on_param_get(self, f) -> None:
        names = wire.decode_param_get(f.payload)
        params = self.engine.get_params()
        unknown = [n for n in names if n not in params]
        if unknown:
            raise UpdateRejected(Nack.UNKNOWN_NAME, f"unknown parameter(s) {', '.join(unknown)}; "
                                                 f"known: {', '.join(params)}")
        items = {n: params[n] for n in (names or params)}
        self._reply_parts(MsgType.PARAM_VALUE, f, items)

    def on_stats(self, f) -> None:
        if f.payload:
            raise wire.WireError(f"STATS: a request has an empty payload, got {len(f.payload)} bytes")
        items = {k: _scalar(v) for k, v in _flatten(self.engine.stats()).items()}
        items.update({f"link.{k}": v for k, v in self.stats().items()})
        self._reply_parts(MsgType.STATS, f, items)

    def _reply_parts(self, mtype, f, items: dict) -> None:
        parts = wire.split_kv(items)
        for i, p in enumerate(parts):
            self._reply(mtype, wire.encode_reply_part(f.seq, i, len(parts), p))

    def on_simple(self, f) -> None:
        if f.payload:
            raise wire.WireError(f"{MsgType(f.type).name}: expects an empty payload, got {len(f.payload)} bytes")
        if f.type == MsgType.START:
            self.engine.start()
        elif f.type == MsgType.STOP:
            self.engine.stop()
        elif f.type == MsgType.RESET:
            self.upload = None
            self.engine.reset()
        elif f.type == MsgType.ACQUIRE:
            self._ack(f, self.engine.acquire())
            return
        self._ack(f)


HANDLERS = {
    MsgType.HELLO: LinkServer.on_hello,
    MsgType.MODEL_BEGIN: LinkServer.on_model_begin,
    MsgType.MODEL_CHUNK: LinkServer.on_model_chunk,
    MsgType.MODEL_COMMIT: LinkServer.on_model_commit,
    MsgType.PARAM_SET: LinkServer.on_param_set,
    MsgType.PARAM_GET: LinkServer.on_param_get,
    MsgType.STATS: LinkServer.on_stats,
    MsgType.START: LinkServer.on_simple,
    MsgType.STOP: LinkServer.on_simple,
    MsgType.RESET: LinkServer.on_simple,
    MsgType.ACQUIRE: LinkServer.on_simple,
    MsgType.HEARTBEAT: LinkServer.on_simple,
}


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _scalar(v):
    if isinstance(v, np.generic):
        v = v.item()
    return v if isinstance(v, (bool, int, float, str)) else str(v)


def _port_fd(port):
    """The file descriptor to poll for writability, if the port has one."""
    try:
        return port.fileno()
    except Exception:                                # noqa: BLE001 - no fd on this port type
        sock = getattr(port, "_socket", None)
        return sock.fileno() if sock is not None else None


def serve(port, engine, key: bytes | None = None, stop_event: threading.Event | None = None,
          switch_interval: float | None = 0.0005, **kw) -> dict:
    """Serve one host link until ``stop_event`` is set; returns the link counters.

    The link thread needs the GIL for every read, reply and telemetry frame; with Python's
    default 5 ms switch interval a busy simulation thread delays each of those steps by up
    to 5 ms, so ``serve`` lowers the process's interval to ``switch_interval`` seconds
    (None: leave it alone)."""
    if switch_interval is not None:
        sys.setswitchinterval(min(sys.getswitchinterval(), switch_interval))
    return LinkServer(port, engine, key=key, **kw).serve(stop_event)
