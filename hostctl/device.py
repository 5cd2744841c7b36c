"""``hostctl.Device``: the host end of the link (protocol: springtrack.wire, docs/protocol.md).

    with Device("/dev/pts/5") as dev:          # or "socket://127.0.0.1:7000", "/dev/ttyACM0"
        print(dev.info["model"])
        dev.load_model("face26")
        dev.set(alpha_position=0.05)
        for snap in dev.telemetry(seconds=1.0):
            print(snap.t_us, snap.trackers["x"])

Single-threaded: frames are read whenever a method waits.  Commands are retried with the
same sequence number after ``timeout`` seconds (the firmware answers a repeat from its
reply cache without executing it twice); after ``retries`` retries :class:`NoAnswer`.
A session is an operator (the default) or a read-only monitor (``role=Role.MONITOR``);
while it waits for telemetry it pings the firmware every ``keepalive_s`` seconds so that
an idle-timeout (docs/protocol.md, "Sessions") never closes it.  On a keyed link the
HELLO is followed by a signed ping: no answer to it raises :class:`AuthFailed` (the
firmware drops frames whose signature does not verify without a word: a wrong key).
ERROR and NOTICE frames from the firmware are kept in ``errors`` and ``notices``.
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import serial

from springtrack import wire
from springtrack.mcu import words as wire_image
from springtrack.wire import MsgType, Nack, Notice, Role

TELEMETRY_QUEUE = 20_000
KEEPALIVE_S = 5.0         # a ping at least this often while waiting for telemetry


class HostctlError(Exception):
    """A link failure the CLI reports with a non-zero exit code."""
    exit_code = 1


class NoSuchPort(HostctlError):
    exit_code = 3


class NoAnswer(HostctlError):
    exit_code = 4


class VersionMismatch(HostctlError):
    exit_code = 5

    def __init__(self, message: str, host: int, firmware: int):
        super().__init__(message)
        self.host, self.firmware = host, firmware


class AuthFailed(HostctlError):
    """The device answered HELLO but not the signed frame after it: the key is wrong (or
    this address is locked out after failed attempts)."""
    exit_code = 7


class Nacked(HostctlError):
    exit_code = 6

    def __init__(self, command: str, refusal: wire.Refusal):
        super().__init__(f"{command} refused ({refusal.code_name}): {refusal.reason}")
        self.command, self.code, self.reason = command, refusal.code, refusal.reason
        self.refusal = refusal


@dataclass
class Snapshot:
    """One telemetry frame: ``trackers`` is an array of :data:`springtrack.wire.TRACK_DTYPE`."""
    t_us: int
    generation: int
    mean_energy: float
    trackers: np.ndarray
    seq: int
    host_time: float


class Device:
    def __init__(self, port, timeout: float = 0.5, retries: int = 3, key: bytes | None = None,
                 name: str = "hostctl", baudrate: int = 3_000_000,
                 version: int = wire.PROTOCOL_VERSION, role: Role = Role.OPERATOR,
                 keepalive_s: float = KEEPALIVE_S):
        self.timeout, self.retries, self.key, self.version = timeout, retries, key, version
        wire.check_key(key)
        self.role = Role(role)
        self.keepalive_s = keepalive_s
        self.last_tx = time.monotonic()
        self._pings: set = set()           # seqs of keepalive pings (their ACKs are dropped)
        self.url = port if isinstance(port, str) else getattr(port, "name", repr(port))
        self.port = _open(port, baudrate) if isinstance(port, str) else port
        self.reader = wire.FrameReader(hunting=True)
        self.rx_seq = wire.SeqTracker()
        self.tx_seq = int.from_bytes(np.random.default_rng().bytes(2), "little")
        self.signer: wire.Signer | None = None
        self.snapshots: deque = deque()
        self.replies: dict = {}            # request seq -> [(frame, decoded reply), ...]
        self.info_reply: wire.Frame | None = None
        self.applied: dict[int, int] = {}  # generation -> event time it took effect
        self.firmware_link: dict = {}      # last HEARTBEAT counters of the firmware
        self.logs: deque = deque(maxlen=200)
        self.errors: deque = deque(maxlen=200)     # ERROR reports (wire.Report, Fault codes)
        self.notices: deque = deque(maxlen=200)    # NOTICE reports (Notice codes)
        self.stream_ended = False                  # a NOTICE said the source ran out
        self.counts = dict(commands=0, retries=0, telemetry=0, telemetry_overflow=0,
                           unexpected=0, foreign_version=0, energies=0, stale_snapshots=0,
                           errors=0, notices=0, keepalives=0)
        self.energies: tuple | None = None   # last ENERGIES: (t_us, kind, per-connection array)
        # every ENERGIES in arrival order (the last 200): several may arrive in one read
        self.energies_log: deque = deque(maxlen=200)
        self.info: dict = {}
        try:
            self._write(b"\x00")           # terminate whatever the firmware holds
            if hasattr(self.port, "reset_input_buffer"):
                self.port.reset_input_buffer()
            self.hello(name)
        except BaseException:
            self.close()
            raise

    # ---- context manager ----------------------------------------------------------
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        try:
            self.port.close()
        except Exception:                  # noqa: BLE001 - closing a dead port is fine
            pass

    # ---- verbs ------------------------------------------------------------------------
    def hello(self, name: str = "hostctl") -> dict:
        self.info_reply = None
        self._request(MsgType.HELLO, wire.encode_hello(name, self.version, self.role),
                      signed=False, done=lambda seq: self.info_reply is not None)
        self.info = wire.decode_info(self.info_reply.payload)
        if self.info["auth_required"] and not self.key:
            raise HostctlError(f"{self.url}: the device requires a key (HMAC signing); "
                               f"give --key-file or $HOSTCTL_KEY (API: key=)")
        self.signer = (wire.Signer(self.key, self.info["nonce"])
                       if self.key and self.info["auth_required"] else None)
        if self.signer is not None:
            self._authenticate()
        return self.info

    def _authenticate(self) -> None:
        """A signed ping right after HELLO: the session gets its role and telemetry with its
        first authentic frame; no answer means the firmware dropped it (a wrong key)."""
        try:
            self._command(MsgType.HEARTBEAT)
        except NoAnswer:
            raise AuthFailed(f"{self.url}: the device answered HELLO but not the signed ping "
                             f"after it: the key is most likely wrong (the device drops "
                             f"frames whose signature does not verify, without an answer); "
                             f"check --key-file / $HOSTCTL_KEY") from None
        except (HostctlError, OSError) as e:      # OSError: the peer closed (broken pipe)
            raise AuthFailed(f"{self.url}: the device closed the link during authentication "
                             f"({e}): a wrong key (a connection from an address locked out "
                             f"after failed attempts is closed at its first)") from None

    def load_model(self, model) -> int:
        """Upload a model (ShapeModel, preset name, TOML path or TOML text); returns the
        generation it will carry.  The firmware validates on commit and swaps atomically."""
        text = _model_text(model).encode("utf-8")
        if self.info.get("model_format") == wire_image.MODEL_FORMAT_WORDS:
            text, nc = _local_check("MODEL_COMMIT", wire_image.words_image, text)
            gen = self._upload(text)
            self.info["connections"] = nc
            return gen
        return self._upload(text)

    def _upload(self, text: bytes) -> int:
        """MODEL_BEGIN, the chunks, MODEL_COMMIT: the generation the upload carries."""
        self._command(MsgType.MODEL_BEGIN, wire.encode_model_begin(text))
        step = wire.MODEL_CHUNK_SIZE            # chunks are pipelined: sent together, ACKed
        # a words firmware reads a UART a byte at a time: two chunks in flight keep the
        # line's buffer from filling (a write that blocks past the write timeout fails)
        words = self.info.get("model_format") == wire_image.MODEL_FORMAT_WORDS
        self._pipelined(MsgType.MODEL_CHUNK,    # together, missing ACKs retried one by one
                        [wire.encode_model_chunk(off, text[off:off + step])
                         for off in range(0, len(text), step)], window=2 if words else 8)
        return self._command(MsgType.MODEL_COMMIT, wire.encode_model_begin(text))

    def set(self, name: str | None = None, value=None, **params) -> int:
        """Set one or more parameters, all or nothing (:meth:`set_all`); returns the
        generation of the last change."""
        if name is not None:
            params = {name: value, **params}
        gens = self.set_all(params)
        return list(gens.values())[-1] if gens else 0

    def set_all(self, params: dict) -> dict:
        """Set the parameters ``params`` (name -> value), all or nothing; returns the
        generation of each change.  Several at once: their current values are read first
        (an unknown name is refused before anything changes); if the device refuses one,
        those already set are set back to their values before, and the refusal (Nacked)
        says so."""
        before = self.get(*params) if len(params) > 1 else {}
        gens: dict = {}
        for k, v in params.items():
            try:
                gens[k] = self._command(MsgType.PARAM_SET, wire.encode_param_set(k, v))
            except Nacked as e:
                if not before:
                    raise
                failed = []
                for d in reversed(list(gens)):
                    try:
                        self._command(MsgType.PARAM_SET, wire.encode_param_set(d, before[d]))
                    except HostctlError:
                        failed.append(d)
                undo = (f"{', '.join(failed)} could NOT be set back" if failed else
                        f"nothing changed ({', '.join(gens)} set back)" if gens else
                        "nothing changed")
                raise Nacked(e.command, e.refusal._replace(reason=f"{e.reason}; {undo}")) from None
        return gens

    def get(self, *names) -> dict:
        return self._parts(MsgType.PARAM_GET, wire.encode_param_get(names), MsgType.PARAM_VALUE)

    def stats(self) -> dict:
        return self._parts(MsgType.STATS, b"", MsgType.STATS)

    def get_model(self) -> str:
        """The device's running model (uploaded, learned or its own) as TOML text."""
        return wire.decode_model_text(self._parts(MsgType.MODEL_GET, b"", MsgType.MODEL_GET))

    def start(self) -> None:
        """Start (or, after the source ended, replay) the stream."""
        self.stream_ended = False
        self._command(MsgType.START)

    def stop(self) -> None:
        self._command(MsgType.STOP)

    def reset(self) -> None:
        """Restart the trackers from the model; also clears the device's ``faulted`` state."""
        self._command(MsgType.RESET)

    def shutdown(self) -> None:
        """End the firmware program (it ACKs first, then stops every thread and exits)."""
        self._command(MsgType.SHUTDOWN)

    def acquire(self) -> int:
        """Make the firmware search for its model again (ACQUIRE; a firmware started with
        --acquire, else HostctlError for the NACK); returns the generation it carries.
        Telemetry shows each tracker's instance ``searching`` until it is found."""
        return self._command(MsgType.ACQUIRE)

    def ping(self) -> float:
        """Round-trip time of a HEARTBEAT command, seconds."""
        t = time.perf_counter()
        self._command(MsgType.HEARTBEAT)
        return time.perf_counter() - t

    def link_counters(self) -> dict:
        c = dict(self.counts)
        c.update(self.reader.counts)
        c["lost"] = self.rx_seq.lost
        c.update({f"firmware.{k}": v for k, v in self.firmware_link.items()})
        return c

    # ---- telemetry ----------------------------------------------------------------------
    def poll(self, timeout: float = 0.0) -> None:
        """Read and dispatch whatever arrives within ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while True:
            self._keepalive()
            self._read_once(max(0.0, end - time.monotonic()))
            if time.monotonic() >= end:
                return

    def _keepalive(self) -> None:
        """A ping (not waited for) if nothing was sent for ``keepalive_s`` seconds."""
        if self.keepalive_s is None or time.monotonic() - self.last_tx < self.keepalive_s:
            return
        seq = self.tx_seq
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        self._pings.add(seq)
        if len(self._pings) > 64:
            self._pings.clear()
        self.counts["keepalives"] += 1
        self._write(wire.encode_frame(MsgType.HEARTBEAT, seq, version=self.version,
                                      signer=self.signer))

    def _write(self, raw: bytes) -> None:
        self.last_tx = time.monotonic()
        try:
            self.port.write(raw)
        except (serial.SerialException, OSError) as e:
            raise HostctlError(f"{self.url}: link failed: {e}{self._closing_note()}") from None

    def _closing_note(self) -> str:
        for n in reversed(self.notices):
            if n.code == Notice.SESSION_CLOSING:
                return f" (the device said: {n.text})"
        return ""

    def telemetry(self, seconds: float | None = None, count: int | None = None):
        """Iterator of :class:`Snapshot` for ``seconds`` of wall time and/or ``count`` snapshots
        (forever if both are None)."""
        end = None if seconds is None else time.monotonic() + seconds
        n = 0
        while (end is None or time.monotonic() < end) and (count is None or n < count):
            if not self.snapshots:
                self._keepalive()
                self._read_once(0.05 if end is None else max(0.0, min(0.05, end - time.monotonic())))
            while self.snapshots and (count is None or n < count):
                n += 1
                yield self.snapshots.popleft()

    # ---- request machinery --------------------------------------------------------------
    def _command(self, mtype, payload: bytes = b"") -> int:
        seq = self._request(mtype, payload, done=lambda s: s in self.replies)
        return self._check_ack(mtype, self.replies.pop(seq)[0])

    def _pipelined(self, mtype, payloads, window: int = 8) -> None:
        """Send up to ``window`` commands before waiting for their ACKs (the firmware's
        reply cache holds 16, so a retried one is still answered from it)."""
        for k in range(0, len(payloads), window):
            seqs = []
            for p in payloads[k:k + window]:
                seq = self.tx_seq
                self.tx_seq = (self.tx_seq + 1) & 0xFFFF
                self.replies.pop(seq, None)
                self.counts["commands"] += 1
                self._write(wire.encode_frame(mtype, seq, p, version=self.version,
                                              signer=self.signer))
                seqs.append((seq, p))
            end = time.monotonic() + self.timeout
            while time.monotonic() < end and not all(q in self.replies for q, _ in seqs):
                self._read_once(end - time.monotonic())
            for seq, p in seqs:
                if seq not in self.replies:       # lost: retry this one with its own seq
                    self._request(mtype, p, done=lambda s: s in self.replies, seq=seq)
                self._check_ack(mtype, self.replies.pop(seq)[0])

    def _check_ack(self, mtype, reply) -> int:
        """The ACK's value, or the NACK raised; ``reply`` is a (frame, decoded) pair."""
        frame, msg = reply
        if isinstance(msg, wire.Refusal):
            self._raise_nack(mtype, frame, msg)
        if not isinstance(msg, wire.Ack):
            raise HostctlError(f"{self.url}: {MsgType(mtype).name} answered by "
                               f"{MsgType(frame.type).name}, not ACK")
        return msg.value

    def _raise_nack(self, mtype, frame, refusal: wire.Refusal):
        if refusal.code == Nack.VERSION_MISMATCH:     # sent in the firmware's own version
            raise VersionMismatch(f"{self.url}: {refusal.reason}", self.version, frame.version)
        raise Nacked(MsgType(mtype).name, refusal)

    def _parts(self, mtype, payload: bytes, reply_type) -> dict:
        def complete(seq):
            got = [msg for _, msg in self.replies.get(seq, [])]
            if not got or isinstance(got[0], wire.Refusal):
                return bool(got)
            parts = [m for m in got if isinstance(m, wire.ReplyPart)]
            return bool(parts) and {m.part for m in parts} >= set(range(parts[0].parts))
        seq = self._request(mtype, payload, done=complete)
        replies = self.replies.pop(seq)
        if isinstance(replies[0][1], wire.Refusal):
            self._check_ack(mtype, replies[0])
        out = {}
        for _, msg in replies:
            if isinstance(msg, wire.ReplyPart):
                out.update(msg.items)
        return out

    def _request(self, mtype, payload: bytes, done, signed: bool = True,
                 seq: int | None = None) -> int:
        first = 0
        if seq is None:
            seq = self.tx_seq
            self.tx_seq = (self.tx_seq + 1) & 0xFFFF
            self.replies.pop(seq, None)
            self.counts["commands"] += 1
        else:                                   # already sent once (pipelined): a retry
            first = 1
        for attempt in range(first, self.retries + 1):
            if attempt:
                self.counts["retries"] += 1
            signer = self.signer if signed else None     # a retry is re-signed (fresh counter)
            self._write(wire.encode_frame(mtype, seq, payload, version=self.version,
                                          signer=signer))
            end = time.monotonic() + self.timeout
            while time.monotonic() < end:
                self._read_once(end - time.monotonic())
                got = self.replies.get(seq)
                refused = bool(got) and isinstance(got[0][1], wire.Refusal)
                if done(seq) or refused:
                    if mtype == MsgType.HELLO and refused:
                        self._raise_nack(mtype, *got[0])
                    return seq
        raise NoAnswer(f"{self.url}: no answer to {MsgType(mtype).name} after "
                       f"{self.retries + 1} tries of {self.timeout:g} s each "
                       f"({(self.retries + 1) * self.timeout:g} s)")

    def _read_once(self, timeout: float) -> None:
        """Wait up to ``timeout`` (at most 50 ms) for a byte, then take everything available
        (``in_waiting`` is not a byte count on every pyserial port, e.g. socket://)."""
        try:
            wire.set_read_timeout(self.port, round(max(0.0, min(timeout, 0.05)), 3))
            data = self.port.read(1)
            if data:
                wire.set_read_timeout(self.port, 0)
                data += self.port.read(65536)
        except (serial.SerialException, OSError) as e:
            raise HostctlError(f"{self.url}: link failed: {e}{self._closing_note()}") from None
        if data:
            for frame in self.reader.feed(data):
                self._dispatch(frame)

    def _dispatch(self, f: wire.Frame) -> None:
        if f.type == MsgType.INFO:         # a new session: the firmware discarded what it
            self.rx_seq.restart()          # had not written yet, that is not a loss, and
            self.counts["stale_snapshots"] += len(self.snapshots)     # what arrived before
            self.snapshots.clear()         # INFO belongs to an earlier session
        self.rx_seq.update(f.seq)
        if f.version != self.version:
            self.counts["foreign_version"] += 1
            if f.type == MsgType.NACK:          # frozen layout: readable across versions
                try:
                    self._store_reply(f)
                except wire.WireError:
                    self.reader.counts["malformed"] += 1
            return
        try:
            if f.type == MsgType.TELEMETRY:
                t, gen, me, tr = wire.decode_telemetry(f.payload)
                if len(self.snapshots) >= TELEMETRY_QUEUE:
                    self.snapshots.popleft()
                    self.counts["telemetry_overflow"] += 1
                self.snapshots.append(Snapshot(t, gen, me, tr, f.seq, time.time()))
                self.counts["telemetry"] += 1
            elif f.type in wire.REPLY_TYPES:
                self._store_reply(f)
            elif f.type == MsgType.INFO:
                self.info_reply = f
            elif f.type == MsgType.ENERGIES:
                self.energies = wire.decode_energies(f.payload)
                self.energies_log.append(self.energies)
                self.counts["energies"] += 1
            elif f.type == MsgType.APPLIED:
                gen, t_us = wire.decode_applied(f.payload)
                self.applied[gen] = t_us
            elif f.type == MsgType.HEARTBEAT:
                self.firmware_link = wire.decode_heartbeat(f.payload)
            elif f.type == MsgType.LOG:
                self.logs.append(wire.decode_log(f.payload))
            elif f.type == MsgType.ERROR:
                self.errors.append(wire.decode_error(f.payload))
                self.counts["errors"] += 1
            elif f.type == MsgType.NOTICE:
                self._notice(wire.decode_notice(f.payload))
            else:
                self.counts["unexpected"] += 1
        except wire.WireError:
            self.reader.counts["malformed"] += 1

    def _notice(self, n: wire.Report) -> None:
        self.notices.append(n)
        self.counts["notices"] += 1
        if n.code == Notice.STREAM_ENDED:
            self.stream_ended = True
        elif n.code == Notice.ROLE_CHANGED:
            self.role = Role.MONITOR

    def _store_reply(self, f) -> None:
        """File an ACK, NACK, PARAM_VALUE or STATS part under the request's seq."""
        msg = wire.decode_reply(f)
        if msg.seq in self._pings and not isinstance(msg, wire.ReplyPart):
            self._pings.discard(msg.seq)         # a keepalive's ACK: nobody waits for it
            return
        self.replies.setdefault(msg.seq, []).append((f, msg))


def _open(url: str, baudrate: int):
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=0.05, write_timeout=2.0)
    except (serial.SerialException, ValueError, OSError) as e:
        raise NoSuchPort(f"{url}: cannot open port: {e}") from None


def _local_check(command: str, convert, *args):
    """``convert(*args)``; a model or parameter it refuses raises :class:`Nacked` with the
    code and reason the firmware would give (for a words firmware the host checks first)."""
    try:
        return convert(*args)
    except (ValueError, TypeError, RecursionError) as e:
        code = getattr(e, "code", Nack.INVALID_MODEL if command == "MODEL_COMMIT"
                       else Nack.OUT_OF_RANGE)
        raise Nacked(command, wire.Refusal(0, 0, int(code), str(e))) from None


def _model_text(model) -> str:
    from springtrack.model import ShapeModel, load_model
    if isinstance(model, ShapeModel):
        return model.to_toml()
    s = str(model)
    if "\n" in s:                         # TOML text: validated by the firmware on commit
        return s
    try:
        is_file = Path(s).is_file()
    except OSError:                       # not a path (too long a name)
        is_file = False
    if is_file:
        return Path(s).read_text()
    return load_model(s).to_toml()


__all__ = ["Device", "Snapshot", "HostctlError", "NoSuchPort", "NoAnswer", "VersionMismatch",
           "Nacked", "AuthFailed", "Role"]
