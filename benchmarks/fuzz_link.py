"""Fuzz the firmware's link parser: >= 1,000,000 random and mutated frames against a running
firmware process over a pty; the firmware must stay alive, keep answering, and end with
the configuration it started with.  The summary replaces the "Link fuzzing" section of
docs/benchmarks.md.

    .venv/bin/python benchmarks/fuzz_link.py [--frames 1000000] [--seed 1]
                                             [--target firmware-sim|test-engine]

Frame classes (equal shares, seeded):

* ``garbage``  random bytes (zeros included) and a delimiter;
* ``mutated``  a valid host command with 1-4 mutations (bit flip, byte replace, insert,
  delete, truncate, duplicate a slice) - almost all must fail COBS or CRC;
* ``random``   a well-formed frame (valid COBS and CRC) of a random type 0-255 with a
  random payload - reaches the message parsers; START/STOP/RESET only with non-empty
  (malformed) payloads, so that no valid state change is sent by chance;
* ``hostile``  well-formed frames built to be refused: PARAM_SET of unknown names,
  out-of-range / NaN / inf / wrong-type values, oversize names; MODEL_* out of order,
  with lying lengths or CRCs; foreign protocol versions; SIGNED flags with junk trailers.

Every 20,000 frames a HELLO probe must be answered within 2 s.
"""
from __future__ import annotations

import argparse
import random
import struct
import sys
import time
import zlib

import serial

from link import ROOT, Firmware, default_target, load_average, machine

sys.path.insert(0, str(ROOT))
from hostctl import Device  # noqa: E402
from springtrack import model as _model  # noqa: E402
from springtrack import wire  # noqa: E402
from springtrack.wire import MsgType  # noqa: E402

SECTION = "## Link fuzzing"
MUTATING = (MsgType.START, MsgType.STOP, MsgType.RESET, MsgType.SHUTDOWN)


def valid_commands() -> list[bytes]:
    text = _model.grid3x3().to_toml().encode()
    bodies = [
        (MsgType.HELLO, wire.encode_hello("fuzz")),
        (MsgType.PARAM_SET, wire.encode_param_set("alpha_position", 5.0)),
        (MsgType.PARAM_SET, wire.encode_param_set("nope", 1)),
        (MsgType.PARAM_GET, wire.encode_param_get(["alpha_position", "energy_scale"])),
        (MsgType.PARAM_GET, wire.encode_param_get([])),
        (MsgType.MODEL_BEGIN, wire.encode_model_begin(text)),
        (MsgType.MODEL_CHUNK, wire.encode_model_chunk(0, text[:400])),
        (MsgType.MODEL_COMMIT, wire.encode_model_begin(b"x" + text)),
        (MsgType.STATS, b""),
        (MsgType.HEARTBEAT, b""),
    ]
    return [wire.encode_frame(t, i, p) for i, (t, p) in enumerate(bodies)]


def mutate(rng: random.Random, frame: bytes) -> bytes:
    b = bytearray(frame[:-1])
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(6)
        i = rng.randrange(len(b)) if b else 0
        if op == 0 and b:
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1 and b:
            b[i] = rng.randrange(256)
        elif op == 2:
            b.insert(i, rng.randrange(256))
        elif op == 3 and len(b) > 1:
            del b[i]
        elif op == 4 and len(b) > 1:
            del b[rng.randrange(1, len(b)):]
        elif op == 5 and b:
            j = rng.randrange(i, len(b) + 1)
            b[i:i] = b[i:j]
    return bytes(b) + b"\x00"


def rand_bytes(rng: random.Random, n: int) -> bytes:
    return rng.getrandbits(8 * n).to_bytes(n, "little") if n else b""


def random_frame(rng: random.Random, seq: int) -> bytes:
    mtype = rng.randrange(256)
    payload = rand_bytes(rng, rng.choice((0, 1, 2, 4, 8, rng.randrange(64), rng.randrange(1024))))
    if mtype in MUTATING and not payload:
        payload = b"\x01"
    return wire.encode_frame(mtype, seq, payload)


BAD_VALUES = [float("nan"), float("inf"), -float("inf"), -1.0, 1e300, "alpha", True,
              2**62, -2**62, ""]


def hostile_frame(rng: random.Random, seq: int) -> bytes:
    k = rng.randrange(9)
    if k == 0:
        name = rng.choice(["alpha_position", "alpha_covariance", "p_threshold", "spring_period",
                           "energy_kind", "sigma_min_px"])
        value = rng.choice(BAD_VALUES)
        if name == "energy_kind":
            value = rng.choice([1.0, "bogus", "", True])
        if name == "p_threshold" and value == "":
            value = 0.0
        return wire.encode_frame(MsgType.PARAM_SET, seq, wire.encode_param_set(name, value))
    if k == 1:
        name = "".join(rng.choice("abcxyz_\u00e9\u4e2d") for _ in range(rng.randrange(1, 60)))
        return wire.encode_frame(MsgType.PARAM_SET, seq, wire.encode_param_set(name, 0.1))
    if k == 2:                                      # typed value with a bad tag / length
        payload = wire._text("alpha_position") + bytes([rng.choice(b"xyzsb\xff")]) + rand_bytes(rng, rng.randrange(10))
        return wire.encode_frame(MsgType.PARAM_SET, seq, payload)
    if k == 3:                                      # chunk / commit without or with lying begin
        return wire.encode_frame(rng.choice((MsgType.MODEL_CHUNK, MsgType.MODEL_COMMIT)), seq,
                                 struct.pack("<II", rng.randrange(2**32), rng.randrange(2**32)))
    if k == 4:                                      # begin with absurd length
        return wire.encode_frame(MsgType.MODEL_BEGIN, seq,
                                 struct.pack("<II", rng.choice((0, 2**32 - 1, 10**9)), 0))
    if k == 5:                                      # a foreign protocol version
        return wire.encode_frame(rng.randrange(256), seq, rand_bytes(rng, 8),
                                 version=rng.choice((0, 2, 255)))
    if k == 6:                                      # SIGNED flag with a junk trailer
        body = wire.HEADER.pack(1, MsgType.PARAM_SET, wire.FLAG_SIGNED, seq) + \
            wire.encode_param_set("alpha_position", 0.3) + rand_bytes(rng, rng.choice((3, 24)))
        return wire.cobs_encode(body + struct.pack("<I", zlib.crc32(body))) + b"\x00"
    if k == 7:                                      # PARAM_GET with lying counts
        return wire.encode_frame(MsgType.PARAM_GET, seq, bytes([rng.randrange(256)]) + rand_bytes(rng, 5))
    return wire.encode_frame(MsgType.HELLO, seq, struct.pack("<H", rng.choice((0, 2, 65535)))
                             + rand_bytes(rng, rng.randrange(4)))


def note_internal(f, internal: dict) -> None:
    """Tally the reasons of INTERNAL NACKs: exceptions the firmware caught in a handler."""
    try:
        _, mtype, code, reason = wire.decode_nack(f.payload)
    except wire.WireError:
        return
    if code == wire.Nack.INTERNAL:
        key = f"0x{mtype:02x}: {reason[:120]}"
        internal[key] = internal.get(key, 0) + 1


def probe(port, reader: wire.FrameReader, seq: int, timeout: float = 2.0) -> bool:
    port.write(wire.encode_frame(MsgType.HELLO, seq, wire.encode_hello("probe")))
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for f in reader.feed(port.read(max(1, port.in_waiting))):
            if f.type == MsgType.INFO:
                return True
    return False


def snapshot_state(path) -> dict:
    with Device(path, timeout=1.0) as dev:
        return dict(params=dev.get(), model=dev.info.get("model"),
                    model_hash=dev.info.get("model_hash"), stats=dev.stats())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--target", choices=("firmware-sim", "test-engine"), default=default_target())
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    pool = valid_commands()
    # a long, cheap scene so the firmware outlives the run; face26 tracking keeps running
    fw = Firmware(args.target, source=("--source", "sim:grid_inplane", "--preset", "face26"),
                  seconds=1e5)
    load0 = load_average()
    counts = dict(garbage=0, mutated=0, random=0, hostile=0)
    failures = []
    t0 = time.monotonic()
    try:
        with Device(fw.path) as dev:
            dev.start()
        before = snapshot_state(fw.path)
        port = serial.serial_for_url(fw.path, timeout=0.01, write_timeout=10)
        reader = wire.FrameReader()
        replies = {}
        internal = {}                   # reason of each INTERNAL NACK -> count
        kinds = list(counts)
        batch = bytearray()
        for i in range(args.frames):
            kind = kinds[i % 4]
            counts[kind] += 1
            seq = i & 0xFFFF
            if kind == "garbage":
                batch += rand_bytes(rng, rng.randrange(1, 80)) + b"\x00"
            elif kind == "mutated":
                batch += mutate(rng, rng.choice(pool))
            elif kind == "random":
                batch += random_frame(rng, seq)
            else:
                batch += hostile_frame(rng, seq)
            if len(batch) > 8192 or i == args.frames - 1:
                port.write(bytes(batch))
                batch.clear()
                while port.in_waiting:
                    for f in reader.feed(port.read(port.in_waiting)):
                        replies[f.type] = replies.get(f.type, 0) + 1
                        if f.type == MsgType.NACK:
                            note_internal(f, internal)
            if i % 20_000 == 19_999:
                if not fw.alive() or not probe(port, reader, 0xFFFF):
                    failures.append(f"no answer to the probe after {i + 1} frames")
                    break
                print(f"{i + 1} frames, {time.monotonic() - t0:.0f} s", file=sys.stderr)
        time.sleep(0.5)
        while port.in_waiting:
            for f in reader.feed(port.read(port.in_waiting)):
                replies[f.type] = replies.get(f.type, 0) + 1
                if f.type == MsgType.NACK:
                    note_internal(f, internal)
        port.close()
        alive = fw.alive()
        after = snapshot_state(fw.path) if alive else {}
    finally:
        fw.close()
    wall = time.monotonic() - t0
    if not alive:
        failures.append(f"firmware process died (exit code {fw.proc.returncode})")
    else:
        for key in ("params", "model", "model_hash"):
            if before[key] != after[key]:
                failures.append(f"state changed: {key} {before[key]!r} -> {after[key]!r}")
    handler_errors = after.get("stats", {}).get("link.handler_errors", 0)
    st = after.get("stats", {})
    link_keys = ["rx_frames", "rx_cobs_errors", "rx_crc_errors", "rx_malformed", "rx_oversize",
                 "nacks", "acks", "version_refused", "auth_unsigned", "handler_errors",
                 "tx_dropped"]
    fw_counts = ", ".join(f"{k} {st.get('link.' + k, '?')}" for k in link_keys)
    nacks = replies.get(MsgType.NACK, 0)
    cmd = f".venv/bin/python benchmarks/fuzz_link.py --frames {args.frames} --seed {args.seed} --target {args.target}"
    verdict = "PASS" if not failures else "FAIL: " + "; ".join(failures)
    text = "\n".join([
        SECTION, "",
        f"Machine: {machine()}.  Command: `{cmd}` ({time.strftime('%Y-%m-%d')}), "
        f"{wall:.0f} s wall, firmware `{args.target}` in its own process (sim:grid_inplane, "
        f"face26 tracking running), over a pty.  Load average at start {load0}, at end "
        f"{load_average()} (shared machine).", "",
        f"* frames sent: {sum(counts.values())} ({', '.join(f'{k} {v}' for k, v in counts.items())})",
        f"* firmware link counters after the run (this session): {fw_counts}",
        f"* NACKs received by the fuzzer: {nacks}; probes answered every 20,000 frames",
        f"* configuration (parameters, model name and hash) before == after: "
        f"{'yes' if alive and not any(f.startswith('state') for f in failures) else 'NO'}",
        f"* result: **{verdict}** (zero crashes, no state change, every probe answered)",
        f"* internal errors (exceptions inside firmware handlers, caught, NACKed `internal`, "
        f"state unchanged): {handler_errors}" + ("" if not internal else "; reasons seen:"),
        *(f"  * {n}x `{r}`" for r, n in sorted(internal.items(), key=lambda kv: -kv[1])[:8]),
        ""])
    print(text)
    if not args.no_write:
        from link import write_section
        write_section(text, SECTION)
    return 0 if not failures else 1


if __name__ == "__main__":
    sys.exit(main())
