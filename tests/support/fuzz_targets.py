"""Coverage-guided fuzz targets (atheris, libFuzzer's engine) for every parser of outside
input: the streaming event decoders and file-format detection, the host link's frames and
payloads, and model and parameter TOML.  Shared by tests/support/atheris_run.py (one target
in a process: atheris's loop does not return), which the short CI test
(tests/test_springtrack/test_fuzz_atheris.py, seconds per target) and the long run
(benchmarks/fuzz_atheris.py) start.

A target takes the fuzzer's bytes and either parses them or raises the parser's own clean
error (``allowed``); any other exception, a hang or a crash is a finding.  The decoder
targets check the invariants of tests/support/decoder_fuzz.py (events inside the geometry,
no more than the words can encode, counters, split decoding equal to whole).
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from springtrack import io as sio
from springtrack import model as _model
from springtrack import params as _params
from springtrack import toml_bounds, wire

from . import decoder_fuzz

SEED_BYTES = 4096             # a seed input is at most this long (a window of a valid stream)


@dataclass(frozen=True)
class Target:
    name: str
    run: Callable[[bytes], None]
    seeds: Callable[[], list]          # starting inputs (valid streams, frames, texts)
    allowed: tuple = ()                # the parser's clean errors


# ---- event decoders ---------------------------------------------------------------------
def _decoder_target(name: str, opts: dict) -> Target:
    def run(data: bytes) -> None:
        # the first byte says where the input is cut in two decode() calls
        cut = data[0] * len(data) // 256 if data else 0
        decoder_fuzz.check(name, opts, data[1:], [max(0, cut - 1)] if data else [],
                           compare=True)

    def seeds() -> list:
        base = decoder_fuzz.seeds(np.random.default_rng(0))[name]
        return [b"\x80" + base[:SEED_BYTES], b"\x10" + base[len(base) // 2:][:SEED_BYTES]]
    return Target(f"decoder-{name}", run, seeds)


_SCRATCH = Path(tempfile.gettempdir() if not os.path.isdir("/dev/shm") else "/dev/shm")


def _open_file(data: bytes) -> None:
    """Detection and header parsing by content, then the whole file read."""
    path = _SCRATCH / f"springtrack-fuzz-{os.getpid()}.bin"
    try:
        path.write_bytes(data)
        r = sio.open(path)
        ev = r.read()
        if r.width and len(ev) and (int(ev["x"].max()) >= r.width
                                    or int(ev["y"].max()) >= (r.height or 0)):
            raise AssertionError("event outside the declared geometry")
    finally:
        path.unlink(missing_ok=True)


def _open_seeds() -> list:
    return [h + bytes(64) for h in decoder_fuzz.HEADERS]


# ---- host link ---------------------------------------------------------------------------
def _frames(data: bytes) -> None:
    """A byte stream into the frame reader (COBS, header, CRC, signature trailer): never
    raises; each frame it returns has a consistent header."""
    reader = wire.FrameReader(hunting=bool(data[:1]) and data[0] & 1)
    for frame in reader.feed(data[1:]):
        if not 0 <= frame.seq <= 0xFFFF:
            raise AssertionError(f"seq {frame.seq}")
    c = reader.counts
    if c["bytes"] != max(0, len(data) - 1):
        raise AssertionError(f"counts {c}")


def _frame_seeds() -> list:
    out = []
    for mtype, payload in ((wire.MsgType.HELLO, wire.encode_hello()),
                           (wire.MsgType.PARAM_SET, wire.encode_kv({"alpha_position": 0.1})),
                           (wire.MsgType.ACK, wire.encode_ack(3, wire.MsgType.START)),
                           (wire.MsgType.STATS, b"")):
        out.append(b"\x00" + wire.encode_frame(int(mtype), 7, payload) * 2)
    return out


# every payload decoder of the protocol, by the message it reads
PAYLOADS = (wire.decode_hello, wire.decode_ack, wire.decode_nack, wire.decode_info,
            wire.decode_model_begin, wire.decode_model_chunk, wire.decode_param_set,
            wire.decode_param_get, wire.decode_applied, wire.decode_heartbeat,
            wire.decode_log, wire.decode_error, wire.decode_notice, wire.decode_telemetry,
            wire.decode_energies, wire.decode_kv)


def _payload(data: bytes) -> None:
    """The first byte picks a payload decoder; the rest is its payload."""
    if not data:
        return
    PAYLOADS[data[0] % len(PAYLOADS)](data[1:])


def _payload_seeds() -> list:
    return [bytes([0]) + wire.encode_hello(), bytes([6]) + wire.encode_kv({"a": 1, "b": "x"}),
            bytes([2]) + bytes(8)]


# ---- model and parameter text ------------------------------------------------------------
def _model_text(data: bytes) -> None:
    text = data.decode("utf-8", "replace")
    try:
        m = _model.loads(text, "fuzz")
    except _model.ModelError:
        return
    if _model.loads(m.to_toml()).to_toml() != m.to_toml():
        raise AssertionError("a model does not survive its own TOML")


def _params_text(data: bytes) -> None:
    _params.from_mapping(_params.parse_toml(data.decode("utf-8", "replace"), "fuzz"))


def _toml_bounds(data: bytes) -> None:
    toml_bounds.check(data.decode("utf-8", "replace"))


def _model_seeds() -> list:
    return [_model.grid3x3().to_toml().encode(), _model.face26().to_toml().encode()]


def _params_seeds() -> list:
    return [b"alpha_position = 0.1\nsigma_min_px = 2\n[learn]\nbirth_events = 12\n"]


TARGETS: dict[str, Target] = {
    t.name: t for t in (
        *(_decoder_target(name, opts) for name, opts in decoder_fuzz.DECODERS.items()),
        Target("open-file", _open_file, _open_seeds, (sio.DecodeError,)),
        Target("wire-frames", _frames, _frame_seeds),
        Target("wire-payloads", _payload, _payload_seeds, (wire.WireError,)),
        Target("model-toml", _model_text, _model_seeds),
        Target("params-toml", _params_text, _params_seeds, (_params.ParamError,)),
        Target("toml-bounds", _toml_bounds, _model_seeds, (toml_bounds.TomlBoundsError,)),
    )
}
