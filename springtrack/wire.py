"""The host-link wire protocol, shared by the firmware (``firmware_sim.link``) and the
host (``hostctl``).  Byte-by-byte description: docs/protocol.md.

A frame on the wire is ``COBS(body) 0x00``; the body is::

    version u8 | type u8 | flags u8 | seq u16 | payload ... | [counter u64 | tag 16B] | crc32 u32

All integers little-endian.  ``flags`` bit 0 (SIGNED) says a signature trailer follows
the payload: a 64-bit monotonically increasing counter and the first 16 bytes of
HMAC-SHA256(key, nonce || header || payload || counter) (MAVLink-2-style signing; the
session nonce comes from INFO).  The CRC is CRC-32 (IEEE 802.3, ``zlib.crc32``) over
everything before it.  The header layout and the NACK payload are frozen across protocol
versions so that two ends of different versions can still refuse each other politely.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import struct
import time
import zlib
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from .io.cobs import CobsError, cobs_decode, cobs_encode   # noqa: F401 - the framing
from .io.errors import WireError
# the tracker snapshots' payloads (TELEMETRY, ENERGIES) and the payload bound
from .io.telemetry import (ACT_SCALE, ENERGY_HDR, ENERGY_PERIOD_US, FLOAT32_MAX,  # noqa: F401
                           MAX_PAYLOAD, NUMERIC_FIELDS, POS_MAX, POS_SCALE, RHO_SCALE,
                           SIGMA_SCALE, TELE_HDR, TELE_RUN, TELE_TRACKER, TELE_VELOCITY,
                           VEL_UNIT, VELOCITY_TAG, decode_energies, decode_telemetry,
                           encode_energies, encode_telemetry, float32_code,
                           quantise_trackers, quantise_velocities, state_runs)
from .track import STATE_NAMES, TRACK_DTYPE, TRACKING_CODE   # noqa: F401 - decoded TELEMETRY

PROTOCOL_VERSION = 1

HEADER = struct.Struct("<BBBH")          # version, type, flags, seq
CRC = struct.Struct("<I")
COUNTER = struct.Struct("<Q")
TAG_LEN = 16
SIG_LEN = COUNTER.size + TAG_LEN
FLAG_SIGNED = 0x01
MAX_BODY = HEADER.size + MAX_PAYLOAD + SIG_LEN + CRC.size
MAX_ENCODED = MAX_BODY + MAX_BODY // 254 + 2   # COBS worst case: one code byte per 254
MODEL_CHUNK_SIZE = 512
NONCE_LEN = 8
MIN_KEY_BYTES = 16        # shortest link key either end accepts (128 bits)


class MsgType(IntEnum):
    HELLO = 0x01          # H->F  open a session, name the host's protocol version
    INFO = 0x02           # F->H  versions, geometry, capacities, model, nonce
    ACK = 0x03            # F->H  a command succeeded
    NACK = 0x04           # F->H  a command was refused (code + reason)
    MODEL_BEGIN = 0x10    # H->F  total length + CRC-32 of the model TOML
    MODEL_CHUNK = 0x11    # H->F  offset + bytes
    MODEL_COMMIT = 0x12   # H->F  validate and apply atomically
    MODEL_GET = 0x13      # H->F request (empty) / F->H the running model's TOML, in parts
    PARAM_SET = 0x20      # H->F  name + typed value
    PARAM_GET = 0x21      # H->F  names (none = all)
    PARAM_VALUE = 0x22    # F->H  names + typed values
    APPLIED = 0x23        # F->H  generation + event time at which an update took effect
    START = 0x30
    STOP = 0x31
    RESET = 0x32          # also clears the ``faulted`` state
    ACQUIRE = 0x34        # H->F  search for every model instance again (acquisition)
    STATS = 0x33          # H->F request (empty) / F->H counters
    SHUTDOWN = 0x35       # H->F  end the firmware program cleanly (ACKed first)
    TELEMETRY = 0x40      # F->H  one compact tracker snapshot
    ENERGIES = 0x41       # F->H  per-connection energies, at a lower rate than TELEMETRY
    HEARTBEAT = 0x50      # both: liveness; the firmware's carries its link counters
    LOG = 0x60            # F->H  level + text
    ERROR = 0x61          # F->H  unsolicited error: Fault code + text
    NOTICE = 0x62         # F->H  a state change every session should know: Notice code + text


HOST_COMMANDS = frozenset({MsgType.HELLO, MsgType.MODEL_BEGIN, MsgType.MODEL_CHUNK,
                           MsgType.MODEL_COMMIT, MsgType.PARAM_SET, MsgType.PARAM_GET,
                           MsgType.START, MsgType.STOP, MsgType.RESET, MsgType.STATS,
                           MsgType.ACQUIRE, MsgType.SHUTDOWN, MsgType.HEARTBEAT,
                           MsgType.MODEL_GET})
# what a read-only session (Role.MONITOR) may send; everything else is the operator's
MONITOR_COMMANDS = frozenset({MsgType.HELLO, MsgType.PARAM_GET, MsgType.STATS,
                              MsgType.HEARTBEAT, MsgType.MODEL_GET})


class Role(IntEnum):
    """A host session's role, asked for in HELLO (docs/protocol.md, "Sessions")."""
    OPERATOR = 0          # may change the configuration and run state; one at a time
    MONITOR = 1           # read-only: telemetry, STATS, PARAM_GET, HEARTBEAT


class Fault(IntEnum):
    """ERROR frame codes: something went wrong inside the firmware (not a refused command,
    which is a NACK).  The text says what; the code says which kind."""
    THREAD_FAULT = 1      # an unexpected exception in a firmware thread: counted, restarted
    THREAD_STOPPED = 2    # a thread failed too often: the tracking loop is stopped (faulted)
    NONFINITE_STATE = 3   # the tracker state became non-finite: snapshots dropped, trackers reset
    STALLED = 4           # watchdog: transfers wait but the loop processed nothing
    UPDATE_FAILED = 5     # an accepted update could not be applied: the previous one kept
    SOURCE_FAILED = 6     # the camera source failed (e.g. a replay file unreadable mid-stream)
    TELEMETRY = 7         # a snapshot or energy frame could not be encoded: dropped


class Notice(IntEnum):
    """NOTICE frame codes: state changes every session is told about."""
    STREAM_ENDED = 1      # the source has no more data; the loop is idle, START replays it
    ROLE_CHANGED = 2      # this session's role changed (an operator took over)
    SHUTTING_DOWN = 3     # the firmware program is exiting
    SESSION_CLOSING = 4   # this connection is being closed (idle, failed authentication)


class Nack(IntEnum):
    """Why a command was refused.  The code that detects a problem raises an error carrying
    its code (``springtrack.params`` errors, ``firmware_sim.engine.UpdateRejected``)."""
    UNKNOWN_NAME = 1      # no parameter (or bias) of that name
    OUT_OF_RANGE = 2      # a value the name does not accept
    WRONG_TYPE = 3        # a value of the wrong type (a string for a number, 1.5 for a count)
    BUSY = 4              # the device could not take it now
    INVALID_MODEL = 5     # the model (or its upload) does not validate
    MALFORMED = 6         # the payload does not decode
    UNKNOWN_TYPE = 7      # not a host command
    VERSION_MISMATCH = 8  # the frame's protocol version is not the firmware's
    BAD_STATE = 9         # not now (e.g. MODEL_CHUNK without MODEL_BEGIN)
    INTERNAL = 10         # an exception inside the firmware's handler
    SENSOR_MISMATCH = 11  # the model's [sensor] is not the camera's, or trackers lie outside it
    TOO_LONG = 12         # a name longer than the protocol carries (INFO_NAME_BUDGET)
    FORBIDDEN = 13        # not allowed in this session's role (a monitor), or all sessions busy


class CrcError(WireError):
    pass


# ---- signing (MAVLink 2 style, HMAC-SHA256) ------------------------------------------
def make_tag(key: bytes, nonce: bytes, header: bytes, payload: bytes, counter: int) -> bytes:
    return hmac.new(key, nonce + header + payload + COUNTER.pack(counter),
                    hashlib.sha256).digest()[:TAG_LEN]


def check_key(key: bytes | None) -> None:
    """A link key has at least MIN_KEY_BYTES bytes (None: no key); ValueError otherwise."""
    if key is not None and len(key) < MIN_KEY_BYTES:
        raise ValueError(f"a link key of {len(key)} bytes is too short: at least "
                         f"{MIN_KEY_BYTES} bytes (e.g. `openssl rand -hex 32 > link.key`)")


def read_key_file(path) -> bytes:
    """A link key from a file: its bytes without surrounding whitespace (the rule of both
    ``firmware-sim run --key-file`` and ``hostctl --key-file``); ValueError naming the
    file if it is empty or shorter than MIN_KEY_BYTES."""
    with open(path, "rb") as f:
        key = f.read().strip()
    if not key:
        raise ValueError(f"{path}: empty key file")
    try:
        check_key(key)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    return key


class Signer:
    """Signs host frames for one session: counter = max(now in µs, last + 1)."""

    def __init__(self, key: bytes, nonce: bytes):
        self.key, self.nonce, self.last = bytes(key), bytes(nonce), 0

    def next_counter(self) -> int:
        self.last = max(time.time_ns() // 1000, self.last + 1)
        return self.last


class ReplayGuard:
    """Firmware side: accepts a signed frame only if its tag verifies and its counter is
    above every counter accepted before in this session (so replays are refused)."""

    def __init__(self, key: bytes, nonce: bytes):
        self.key, self.nonce, self.last = bytes(key), bytes(nonce), 0

    def check(self, frame: "Frame") -> str | None:
        """None if the frame is authentic and fresh, else the reason it is not."""
        if frame.tag is None:
            return "unsigned"
        want = make_tag(self.key, self.nonce, frame.header, frame.payload, frame.counter)
        if not hmac.compare_digest(want, frame.tag):
            return "bad_tag"
        if frame.counter <= self.last:
            return "replay"
        self.last = frame.counter
        return None


# ---- frames ------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Frame:
    version: int
    type: int
    flags: int
    seq: int
    payload: bytes
    counter: int | None = None
    tag: bytes | None = None

    @property
    def header(self) -> bytes:
        return HEADER.pack(self.version, self.type, self.flags, self.seq)


def encode_body(mtype: int, seq: int, payload: bytes = b"", *, version: int = PROTOCOL_VERSION,
                signer: Signer | None = None) -> bytes:
    """The un-stuffed frame body (header, payload, optional signature, CRC-32)."""
    if len(payload) > MAX_PAYLOAD:
        raise WireError(f"payload of {len(payload)} bytes exceeds MAX_PAYLOAD={MAX_PAYLOAD}")
    flags = FLAG_SIGNED if signer is not None else 0
    header = HEADER.pack(version, int(mtype), flags, seq & 0xFFFF)
    body = header + payload
    if signer is not None:
        counter = signer.next_counter()
        body += COUNTER.pack(counter) + make_tag(signer.key, signer.nonce, header, payload, counter)
    return body + CRC.pack(zlib.crc32(body))


def encode_frame(mtype: int, seq: int, payload: bytes = b"", **kw) -> bytes:
    """A complete wire frame: COBS-stuffed body plus the 0x00 delimiter."""
    return cobs_encode(encode_body(mtype, seq, payload, **kw)) + b"\x00"


def decode_body(body: bytes) -> Frame:
    if len(body) < HEADER.size + CRC.size:
        raise WireError(f"frame of {len(body)} bytes is shorter than header + CRC")
    (crc,) = CRC.unpack_from(body, len(body) - CRC.size)
    if zlib.crc32(body[:-CRC.size]) != crc:
        raise CrcError("CRC-32 mismatch")
    version, mtype, flags, seq = HEADER.unpack_from(body)
    payload = body[HEADER.size:-CRC.size]
    counter = tag = None
    if flags & FLAG_SIGNED:
        if len(payload) < SIG_LEN:
            raise WireError("SIGNED flag set but the frame is too short for a signature")
        (counter,) = COUNTER.unpack_from(payload, len(payload) - SIG_LEN)
        tag = payload[-TAG_LEN:]
        payload = payload[:-SIG_LEN]
    if len(payload) > MAX_PAYLOAD:
        raise WireError(f"payload of {len(payload)} bytes exceeds MAX_PAYLOAD={MAX_PAYLOAD}")
    return Frame(version, mtype, flags, seq, payload, counter, tag)


def decode_frame(enc: bytes) -> Frame:
    """Decode one stuffed frame (without its delimiter)."""
    return decode_body(cobs_decode(enc))


class FrameReader:
    """Splits a byte stream at 0x00 delimiters and decodes frames; a bad frame is dropped
    and counted, and decoding resumes at the next delimiter (resynchronisation)."""

    def __init__(self, hunting: bool = False):
        """``hunting``: the reader attached to a running stream; bytes before the first
        delimiter are the tail of a frame sent before, skipped without counting an error."""
        self.buf = bytearray()
        self.skipping = hunting
        self.counts = dict(frames=0, bytes=0, crc_errors=0, cobs_errors=0,
                           malformed=0, oversize=0)

    def feed(self, data: bytes) -> list[Frame]:
        self.counts["bytes"] += len(data)
        self.buf += data
        out = []
        while True:
            end = self.buf.find(0)
            if end < 0:
                break
            chunk = bytes(self.buf[:end])
            del self.buf[:end + 1]
            if self.skipping:
                self.skipping = False
                continue
            if chunk:
                frame = self._decode(chunk)
                if frame is not None:
                    out.append(frame)
        if len(self.buf) > MAX_ENCODED:          # no delimiter in sight: drop, resync later
            self.counts["oversize"] += 1
            self.buf.clear()
            self.skipping = True
        return out

    def _decode(self, chunk: bytes) -> Frame | None:
        if len(chunk) > MAX_ENCODED:
            self.counts["oversize"] += 1
            return None
        try:
            frame = decode_frame(chunk)
        except CobsError:
            self.counts["cobs_errors"] += 1
            return None
        except CrcError:
            self.counts["crc_errors"] += 1
            return None
        except WireError:
            self.counts["malformed"] += 1
            return None
        self.counts["frames"] += 1
        return frame


class SeqTracker:
    """Counts frames lost in one direction from gaps in the 16-bit sequence numbers: the gap
    ``(seq - last - 1) mod 2^16``; gaps of 2^15 or more are reordering, not loss.  Gaps
    above ``max_gap`` (a direction that cannot lose that many, such as a host's commands)
    are a peer that skipped ahead (random or hostile sequence numbers): counted in
    ``jumps``, not as lost frames."""

    def __init__(self, max_gap: int = 0x7FFF):
        self.last: int | None = None
        self.lost = 0
        self.duplicates = 0
        self.jumps = 0
        self.max_gap = max_gap

    def restart(self, seq: int | None = None) -> None:
        """A new session: expect anything next (``seq``: the frame that opened it)."""
        self.last = seq

    def update(self, seq: int) -> int:
        """Returns the number of frames missing before ``seq`` (0 if in order)."""
        if self.last is None:
            self.last = seq
            return 0
        gap = (seq - self.last - 1) & 0xFFFF
        if gap == 0xFFFF:            # same seq again
            self.duplicates += 1
            return 0
        self.last = seq
        if gap >= 0x8000:            # far behind: a stale or reordered frame, not a loss
            return 0
        if gap > self.max_gap:
            self.jumps += 1
            return 0
        self.lost += gap
        return gap


# ---- payload codecs ----------------------------------------------------------------
class _Cursor:
    """Bounds-checked reader over a payload; every error names the message and field."""

    def __init__(self, data: bytes, what: str):
        self.data, self.pos, self.what = data, 0, what

    def take(self, n: int, field: str) -> bytes:
        if self.pos + n > len(self.data):
            raise WireError(f"{self.what}: truncated at {field} (need {n} bytes at offset "
                            f"{self.pos}, payload is {len(self.data)})")
        b = self.data[self.pos:self.pos + n]
        self.pos += n
        return b

    def unpack(self, fmt: str, field: str):
        s = struct.Struct("<" + fmt)
        return s.unpack(self.take(s.size, field))

    def u8(self, field):
        return self.take(1, field)[0]

    def text(self, field, lenfmt="B") -> str:
        (n,) = self.unpack(lenfmt, field + " length")
        try:
            return self.take(n, field).decode("utf-8")
        except UnicodeDecodeError:
            raise WireError(f"{self.what}: {field} is not valid UTF-8") from None

    def rest(self) -> bytes:
        b = self.data[self.pos:]
        self.pos = len(self.data)
        return b

    def done(self):
        if self.pos != len(self.data):
            raise WireError(f"{self.what}: {len(self.data) - self.pos} unexpected trailing bytes")


def _text(s: str, lenfmt: str = "B") -> bytes:
    b = s.encode("utf-8")
    limit = 255 if lenfmt == "B" else 65535
    if len(b) > limit:
        raise WireError(f"string of {len(b)} bytes too long for a {lenfmt} length: {s[:40]!r}...")
    return struct.pack("<" + lenfmt, len(b)) + b


# typed values: tag byte then value (i: int64, f: float64, s: u8-length UTF-8, b: bool u8)
def encode_value(v) -> bytes:
    if isinstance(v, (bool, np.bool_)):
        return b"b" + bytes([1 if v else 0])
    if isinstance(v, (int, np.integer)):
        if not -2**63 <= int(v) < 2**63:
            raise WireError(f"integer {v} does not fit int64")
        return b"i" + struct.pack("<q", int(v))
    if isinstance(v, (float, np.floating)):
        return b"f" + struct.pack("<d", float(v))
    if isinstance(v, str):
        return b"s" + _text(v)
    raise WireError(f"cannot encode a {type(v).__name__} value {v!r}")


def _read_value(c: _Cursor, field: str):
    tag = c.take(1, field + " type")
    if tag == b"b":
        b = c.u8(field)
        if b > 1:
            raise WireError(f"{c.what}: {field}: bool byte must be 0 or 1, got {b}")
        return bool(b)
    if tag == b"i":
        return c.unpack("q", field)[0]
    if tag == b"f":
        return c.unpack("d", field)[0]
    if tag == b"s":
        return c.text(field)
    raise WireError(f"{c.what}: {field}: unknown value type {tag!r}")


def encode_kv(items: dict) -> bytes:
    """u8 count, then (u8-length name, typed value) pairs."""
    if len(items) > 255:
        raise WireError(f"{len(items)} entries exceed 255 per message")
    return bytes([len(items)]) + b"".join(_text(str(k)) + encode_value(v) for k, v in items.items())


def decode_kv(payload: bytes, what: str = "key/value list") -> dict:
    c = _Cursor(payload, what)
    n = c.u8("count")
    out = {}
    for i in range(n):
        name = c.text(f"entry {i} name")
        out[name] = _read_value(c, f"entry {i} ({name!r}) value")
    c.done()
    return out


def split_kv(items: dict, budget: int = MAX_PAYLOAD - 8) -> list[dict]:
    """Split a dict into pieces whose :func:`encode_kv` fits ``budget`` bytes."""
    parts, cur, size = [], {}, 1
    for k, v in items.items():
        n = len(_text(str(k))) + len(encode_value(v))
        if cur and (size + n > budget or len(cur) == 255):
            parts.append(cur)
            cur, size = {}, 1
        cur[k] = v
        size += n
    parts.append(cur)
    return parts


# HELLO: u16 protocol version, u8-length UTF-8 host name, [u8 role] (absent: operator)
class Hello(NamedTuple):
    version: int          # the host's protocol version
    name: str             # the host's name (for logs)
    role: Role            # the role it asks for


def encode_hello(name: str = "hostctl", version: int = PROTOCOL_VERSION,
                 role: Role = Role.OPERATOR) -> bytes:
    return struct.pack("<H", version) + _text(name) + bytes([int(role)])


def decode_hello(payload: bytes) -> Hello:
    c = _Cursor(payload, "HELLO")
    (version,) = c.unpack("H", "version")
    name = c.text("host name")
    role = Role.OPERATOR
    if c.pos < len(c.data):
        code = c.u8("role")
        if code not in _ROLE_VALUES:
            raise WireError(f"HELLO: unknown role {code} (known: "
                            f"{', '.join(f'{int(r)} {r.name.lower()}' for r in Role)})")
        role = Role(code)
    c.done()
    return Hello(version, name, role)


_ROLE_VALUES = frozenset(int(r) for r in Role)


# ACK: u16 acked seq, u8 acked type, u32 value (model generation, or 0)
ACK = struct.Struct("<HBI")


class Ack(NamedTuple):
    seq: int              # the acknowledged command's sequence number
    type: int             # ... and message type
    value: int            # model generation for MODEL_COMMIT / PARAM_SET, else 0


def encode_ack(seq: int, mtype: int, value: int = 0) -> bytes:
    return ACK.pack(seq & 0xFFFF, int(mtype), int(value) & 0xFFFFFFFF)


def decode_ack(payload: bytes) -> Ack:
    if len(payload) != ACK.size:
        raise WireError(f"ACK: payload is {len(payload)} bytes, expected {ACK.size}")
    return Ack(*ACK.unpack(payload))


# NACK (frozen across versions): u16 seq, u8 type, u8 code, u16-length UTF-8 reason
class Refusal(NamedTuple):
    seq: int              # the refused command's sequence number
    type: int             # ... and message type
    code: int             # a Nack value (a newer firmware may send codes this host lacks)
    reason: str

    @property
    def code_name(self) -> str:
        return Nack(self.code).name.lower() if self.code in _NACK_VALUES else f"code {self.code}"


_NACK_VALUES = frozenset(int(c) for c in Nack)


def encode_nack(seq: int, mtype: int, code: Nack, reason: str) -> bytes:
    r = reason.encode("utf-8")[:MAX_PAYLOAD - 8].decode("utf-8", "ignore")
    return struct.pack("<HBB", seq & 0xFFFF, int(mtype) & 0xFF, int(code)) + _text(r, "H")


def decode_nack(payload: bytes) -> Refusal:
    c = _Cursor(payload, "NACK")
    seq, mtype, code = c.unpack("HBB", "header")
    reason = c.text("reason", "H")
    c.done()
    return Refusal(seq, mtype, code, reason)


# VERSION_MISMATCH NACKs carry their reason as "firmware=N host=M: text"
def version_reason(firmware: int, host: int) -> str:
    return (f"firmware=v{firmware} host=v{host}: protocol version mismatch "
            f"(firmware speaks v{firmware}, host sent v{host})")


# INFO: u16 protocol version, 8-byte session nonce, u8 flags (bit0 auth required,
# bit1 running), u32 generation, u16-length UTF-8 JSON of the engine's info() dict.
# The model's name is the one free-length text INFO must carry (a big model's tracker ids
# are left out when they do not fit): it may take INFO_NAME_BUDGET bytes of the JSON, half
# the payload, so that INFO fits one frame whatever else the engine reports (about 300
# bytes: firmware, backend, geometry, capacities, hash, generation, period).
INFO_NAME_BUDGET = MAX_PAYLOAD // 2


def info_name_bytes(name: str) -> int:
    """Bytes ``name`` takes in INFO's JSON: 1 per ASCII character, 6 per other character
    (\\uXXXX), 12 outside the Basic Multilingual Plane, 2 for '"' and '\\'."""
    return len(json.dumps(name)) - 2


INFO_FIXED = 2 + NONCE_LEN + 5 + 2         # version, nonce, flags, generation, JSON length
INFO_CUT_BYTES = 128                       # INFO's last resort: longer strings cut to this


def encode_info(info: dict, nonce: bytes, auth_required: bool,
                version: int = PROTOCOL_VERSION) -> bytes:
    """INFO, always within MAX_PAYLOAD: when the JSON does not fit, the tracker ids are
    replaced by ``trackers_omitted: n`` (hostctl then names trackers t00, t01, ...), then
    strings longer than INFO_CUT_BYTES are cut to it (listed in ``truncated``: the last
    resort, for a name past INFO_NAME_BUDGET that a firmware would have refused); a dict
    that still does not fit raises WireError."""
    flags = (1 if auth_required else 0) | (2 if info.get("running") else 0)
    js = _info_json(info)
    if INFO_FIXED + len(js) > MAX_PAYLOAD and isinstance(info.get("trackers"), list):
        info = dict(info)
        info["trackers_omitted"] = len(info.pop("trackers"))
        js = _info_json(info)
    if INFO_FIXED + len(js) > MAX_PAYLOAD:
        info = dict(info)
        cut = sorted(k for k, v in info.items()
                     if isinstance(v, str) and len(v.encode("utf-8")) > INFO_CUT_BYTES)
        for k in cut:
            info[k] = info[k].encode("utf-8")[:INFO_CUT_BYTES].decode("utf-8", "ignore")
        info["truncated"] = cut
        js = _info_json(info)
    if INFO_FIXED + len(js) > MAX_PAYLOAD:
        raise WireError(f"INFO: {len(js)} bytes of JSON do not fit one frame")
    return (struct.pack("<H", version) + bytes(nonce).ljust(NONCE_LEN, b"\0")[:NONCE_LEN]
            + struct.pack("<BI", flags, int(info.get("generation", 0)) & 0xFFFFFFFF)
            + struct.pack("<H", len(js)) + js)


def _info_json(info: dict) -> bytes:
    return json.dumps(info, separators=(",", ":"), sort_keys=True,
                      default=_json_default).encode("utf-8")


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, bytes):
        return o.hex()
    return str(o)


def decode_info(payload: bytes) -> dict:
    c = _Cursor(payload, "INFO")
    (version,) = c.unpack("H", "version")
    nonce = c.take(NONCE_LEN, "nonce")
    flags, generation = c.unpack("BI", "flags")
    try:
        info = json.loads(c.text("info JSON", "H"))
    except json.JSONDecodeError as e:
        raise WireError(f"INFO: info JSON is invalid: {e}") from None
    c.done()
    if not isinstance(info, dict):
        raise WireError("INFO: info JSON is not an object")
    info.update(protocol_version=version, nonce=nonce, auth_required=bool(flags & 1),
                running=bool(flags & 2), generation=generation)
    return info


# MODEL_BEGIN: u32 total length, u32 CRC-32 of the whole text; MODEL_CHUNK: u32 offset,
# bytes; MODEL_COMMIT: u32 total length, u32 CRC-32 (checked again before applying)
MODEL_HDR = struct.Struct("<II")


def encode_model_begin(text: bytes) -> bytes:
    return MODEL_HDR.pack(len(text), zlib.crc32(text))


def decode_model_begin(payload: bytes) -> tuple[int, int]:
    if len(payload) != MODEL_HDR.size:
        raise WireError(f"MODEL_BEGIN/COMMIT: payload is {len(payload)} bytes, expected 8")
    return MODEL_HDR.unpack(payload)


def encode_model_chunk(offset: int, data: bytes) -> bytes:
    return struct.pack("<I", offset) + data


def decode_model_chunk(payload: bytes) -> tuple[int, bytes]:
    if len(payload) < 4:
        raise WireError("MODEL_CHUNK: payload shorter than its 4-byte offset")
    return struct.unpack_from("<I", payload)[0], payload[4:]


# PARAM_SET: u8-length name + typed value.  PARAM_GET: u8 count + u8-length names.
def encode_param_set(name: str, value) -> bytes:
    return _text(name) + encode_value(value)


def decode_param_set(payload: bytes) -> tuple[str, object]:
    c = _Cursor(payload, "PARAM_SET")
    name = c.text("name")
    value = _read_value(c, f"value of {name!r}")
    c.done()
    return name, value


def encode_param_get(names) -> bytes:
    names = list(names)
    if len(names) > 255:
        raise WireError("PARAM_GET: at most 255 names per request")
    return bytes([len(names)]) + b"".join(_text(n) for n in names)


def decode_param_get(payload: bytes) -> list[str]:
    c = _Cursor(payload, "PARAM_GET")
    names = [c.text(f"name {i}") for i in range(c.u8("count"))]
    c.done()
    return names


# PARAM_VALUE / STATS replies: u16 request seq, u8 part, u8 parts, key/value list
REPLY_HDR = struct.Struct("<HBB")


class ReplyPart(NamedTuple):
    seq: int              # the request's sequence number
    part: int             # 0 .. parts - 1
    parts: int
    items: dict


def encode_reply_part(seq: int, part: int, parts: int, items: dict) -> bytes:
    return REPLY_HDR.pack(seq & 0xFFFF, part, parts) + encode_kv(items)


def decode_reply_part(payload: bytes, what: str) -> ReplyPart:
    if len(payload) < REPLY_HDR.size:
        raise WireError(f"{what}: payload shorter than its 4-byte header")
    seq, part, parts = REPLY_HDR.unpack_from(payload)
    return ReplyPart(seq, part, parts, decode_kv(payload[REPLY_HDR.size:], what))


REPLY_TYPES = (MsgType.ACK, MsgType.NACK, MsgType.PARAM_VALUE, MsgType.STATS,
               MsgType.MODEL_GET)
MODEL_TEXT_PIECE = 200      # MODEL_GET's TOML: items toml.NNNN of <= 200 chars (<= 800 bytes)


def encode_model_text(text: str) -> dict:
    """A model's TOML as MODEL_GET reply items, in order (``split_kv`` parts them)."""
    step = MODEL_TEXT_PIECE
    return {f"toml.{i // step:04d}": text[i:i + step] for i in range(0, len(text), step)}


def decode_model_text(items: dict) -> str:
    """The TOML text of MODEL_GET's reply items (all parts joined)."""
    keys = sorted(k for k in items if k.startswith("toml."))
    if keys != [f"toml.{i:04d}" for i in range(len(keys))]:
        raise WireError(f"MODEL_GET: the reply's pieces {keys[:3]} are not toml.0000.. in order")
    return "".join(str(items[k]) for k in keys)


def decode_reply(frame: Frame) -> Ack | Refusal | ReplyPart:
    """A reply to a host command (ACK, NACK, PARAM_VALUE or STATS part), each naming the
    request's ``seq``; raises WireError on a malformed payload or another type."""
    if frame.type == MsgType.ACK:
        return decode_ack(frame.payload)
    if frame.type == MsgType.NACK:
        return decode_nack(frame.payload)
    if frame.type in (MsgType.PARAM_VALUE, MsgType.STATS, MsgType.MODEL_GET):
        return decode_reply_part(frame.payload, MsgType(frame.type).name)
    raise WireError(f"message type 0x{frame.type:02x} is not a reply")


# APPLIED: u32 generation, i64 event time (µs) at which it took effect
APPLIED = struct.Struct("<Iq")


def encode_applied(generation: int, t_us: int) -> bytes:
    return APPLIED.pack(int(generation) & 0xFFFFFFFF, int(t_us))


def decode_applied(payload: bytes) -> tuple[int, int]:
    if len(payload) != APPLIED.size:
        raise WireError(f"APPLIED: payload is {len(payload)} bytes, expected {APPLIED.size}")
    return APPLIED.unpack(payload)


# HEARTBEAT (firmware): u64 uptime µs, u32 rx frames, u32 rx errors, u32 rx lost,
# u32 tx frames, u32 tx dropped.  (host): empty.
HEARTBEAT = struct.Struct("<QIIIII")
HEARTBEAT_FIELDS = ("uptime_us", "rx_frames", "rx_errors", "rx_lost", "tx_frames", "tx_dropped")


def encode_heartbeat(**v) -> bytes:
    return HEARTBEAT.pack(*(int(v.get(k, 0)) & (2**64 - 1 if i == 0 else 0xFFFFFFFF)
                            for i, k in enumerate(HEARTBEAT_FIELDS)))


def decode_heartbeat(payload: bytes) -> dict:
    if len(payload) != HEARTBEAT.size:
        raise WireError(f"HEARTBEAT: payload is {len(payload)} bytes, expected {HEARTBEAT.size}")
    return dict(zip(HEARTBEAT_FIELDS, HEARTBEAT.unpack(payload)))


# LOG / ERROR / NOTICE: u8 level or code, u16-length UTF-8 text (at most 1000 bytes)
TEXT_MAX = MAX_PAYLOAD - 24


def encode_log(level: int, text: str) -> bytes:
    t = text.encode("utf-8")[:TEXT_MAX].decode("utf-8", "ignore")
    return bytes([int(level) & 0xFF]) + _text(t, "H")


def _decode_coded_text(payload: bytes, what: str) -> tuple[int, str]:
    c = _Cursor(payload, what)
    code = c.u8("code")
    text = c.text("text", "H")
    c.done()
    return code, text


def decode_log(payload: bytes) -> tuple[int, str]:
    return _decode_coded_text(payload, "LOG")


class Report(NamedTuple):
    """An ERROR (``code`` a Fault) or a NOTICE (``code`` a Notice) from the firmware."""
    code: int             # a newer firmware may send codes this host lacks
    text: str

    def name(self, enum) -> str:
        return enum(self.code).name.lower() if self.code in {int(c) for c in enum} \
            else f"code {self.code}"


def encode_error(code: Fault, text: str) -> bytes:
    return encode_log(int(code), text)


def decode_error(payload: bytes) -> Report:
    return Report(*_decode_coded_text(payload, "ERROR"))


def encode_notice(code: Notice, text: str) -> bytes:
    return encode_log(int(code), text)


def decode_notice(payload: bytes) -> Report:
    return Report(*_decode_coded_text(payload, "NOTICE"))


def set_read_timeout(port, seconds: float) -> None:
    """Set a pyserial port's read timeout only when it changes: pyserial's setter
    reconfigures the port (termios calls) every time, and both ends set it twice a read."""
    if port.timeout != seconds:
        port.timeout = seconds


def framed_size(payload_len: int, signed: bool = False) -> int:
    """Bytes on the wire for a payload of ``payload_len`` bytes, delimiter included, worst case."""
    body = HEADER.size + payload_len + (SIG_LEN if signed else 0) + CRC.size
    return body + body // 254 + 1 + 1
