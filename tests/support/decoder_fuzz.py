"""Fuzzing of the streaming decoders and the file-format detection, shared by
tests/test_springtrack/io/test_io_fuzz.py (a seconds-long slice) and benchmarks/fuzz_decoders.py (1,000,000
inputs per decoder, recorded in docs/formats.md).

For every decoder (ccam, evt2, evt21 in both word orders, evt3, es dvs/atis, dat, aedat4
with LZ4 / Zstandard / no compression), :func:`fuzz_decoder` runs random and mutated
inputs: random byte strings, and windows of valid streams (the real recordings where
available -- EVT 2.1: the EVT 3.0 recording re-encoded --, else our encoders' output) with
bytes flipped, replaced, inserted, deleted or truncated.  Each input is decoded with a fresh decoder, split at 0-3 random
points; every 50th input is also decoded whole and compared.  Checks: no exception, no
crash (a segfault kills the run), events inside the geometry, no more events than the
words can encode (MAX_EVENTS_PER_WORD), counters consistent (words -- packets for AEDAT 4
--, events, pending bytes).  :func:`fuzz_headers` puts truncated,
bit-flipped and mutated file headers through springtrack.io.open(): only DecodeError (or
success) is allowed.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

import springtrack.io as sio
from springtrack.events import make
from springtrack.io import aedat4, ccam, dat, es, evt2, evt21, evt3

from . import REPO
DATA = Path(os.environ.get("SPRINGTRACK_DATA", REPO.parent / "shared" / "data"))

DECODERS = {
    "ccam": {"keep_exposure": True},
    "evt2": {"width": 640, "height": 480},
    "evt3": {"width": 1280, "height": 720},
    "es-dvs": {"event_type": "dvs", "width": 320, "height": 240},
    "es-atis": {"event_type": "atis", "width": 304, "height": 240, "keep_exposure": True},
    "dat": {"width": 640, "height": 480},
    "evt21": {"width": 1280, "height": 720},
    "evt21-legacy": {"width": 1280, "height": 720, "legacy": True},
    "aedat4": {"width": 320, "height": 240, "compression": "LZ4",
               "streams": {0: "EVTS", 2: "IMUS", 3: "TRIG"}},
    "aedat4-zstd": {"width": 320, "height": 240, "compression": "ZSTD"},
    "aedat4-none": {"width": 320, "height": 240, "compression": "NONE"},
}

# the most events one word can carry (Event Stream: per byte; EVT 3.0: a VECT_12 word
# after its base, EVT 2.1: a 32-bit mask): a decoder emitting more invents them
MAX_EVENTS_PER_WORD = {"ccam": 1, "evt2": 1, "evt3": 12, "es": 1, "dat": 1, "evt21": 32}


def seeds(rng) -> dict:
    """A valid byte stream per decoder to mutate."""
    n = 20_000
    ev = make(np.sort(rng.integers(0, 50_000_000, n)), rng.integers(0, 304, n),
              rng.integers(0, 240, n), rng.integers(0, 2, n))
    flags = rng.random(n) < 0.2
    out = {"ccam": ccam.encode(ev, flags), "evt2": evt2.encode(ev), "evt3": evt3.encode(ev),
           "es-dvs": es.encode(ev, "dvs"), "es-atis": es.encode(ev, "atis", flags),
           "dat": dat.encode(ev)}
    dense = ev
    for key, name in (("evt2", "evt2_sample.raw"), ("evt3", "evt3_sample.raw"),
                      ("es-dvs", "dvs.es"), ("aedat4", "sample.aedat4")):
        path = DATA / name
        if path.is_file():
            info = sio.sniff(path)
            out[key] = path.read_bytes()[info.offset:]
            if key == "evt3":
                dense = sio.open(path).read()
    out["evt21"], out["evt21-legacy"] = evt21.encode(dense), evt21.encode(dense, True)
    small = make(np.sort(rng.integers(0, 1 << 50, 3000)), rng.integers(0, 320, 3000),
                 rng.integers(0, 240, 3000), rng.integers(0, 2, 3000))
    for key, comp in (("aedat4", "LZ4"), ("aedat4-zstd", "ZSTD"), ("aedat4-none", "NONE")):
        if key not in out:
            data = aedat4.encode(small, 320, 240, comp, packet_events=40)
            out[key] = data[aedat4.parse_header(data)["offset"]:]
    return out


def payload_unit(fmt, dec, data) -> int:
    """Words a decoder must report for ``data``: packets for AEDAT 4 (its framing is
    checked by tests/test_springtrack/io/test_io_aedat4.py), else whole words."""
    return dec.stats.words if fmt == "aedat4" else len(data) // dec.word_size


def mutate(rng, base: bytes) -> bytes:
    n = int(rng.integers(1, 600))
    start = int(rng.integers(0, max(1, len(base) - n)))
    buf = bytearray(base[start:start + n])
    for _ in range(int(rng.integers(1, 6))):
        op = int(rng.integers(0, 5))
        if not buf:
            break
        i = int(rng.integers(0, len(buf)))
        if op == 0:
            buf[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            buf[i] = int(rng.integers(0, 256))
        elif op == 2:
            buf[i:i] = bytes(rng.integers(0, 256, int(rng.integers(1, 8)), dtype=np.uint8))
        elif op == 3:
            del buf[i:i + int(rng.integers(1, 8))]
        else:
            del buf[i:]
    return bytes(buf)


def check(name, opts, data, cuts, compare):
    fmt = name.split("-")[0]
    dec = sio.decoder(fmt, **opts)
    parts, prev = [], 0
    for c in cuts:
        parts.append(dec.decode(data[prev:c]))
        prev = c
    parts.append(dec.decode(data[prev:]))
    pending = dec.finish()
    ev = np.concatenate(parts)
    s = dec.stats
    w = opts.get("width") or (304 if fmt == "ccam" else 0)
    if w and len(ev) and (ev["x"].max() >= w or ev["y"].max() >= (opts.get("height") or 240)):
        raise AssertionError("event outside the geometry")
    if s.events != len(ev) or s.words != payload_unit(fmt, dec, data):
        raise AssertionError(f"counters: {s}")
    if fmt in MAX_EVENTS_PER_WORD and len(ev) > MAX_EVENTS_PER_WORD[fmt] * s.words:
        raise AssertionError(f"{len(ev)} events from {s.words} words")
    if (pending > 0) != (s.anomalies["truncated"] > 0):
        raise AssertionError("pending bytes not counted as truncated")
    if compare:
        ref = sio.decoder(fmt, **opts).decode(data)
        if not np.array_equal(ref, ev):
            raise AssertionError("split decode differs from whole decode")


def fuzz_decoder(name, opts, base, n, rng):
    t0 = time.perf_counter()
    pool = rng.integers(0, 256, 1 << 22, dtype=np.uint8).tobytes()
    failures = 0
    first = None
    for i in range(n):
        if i & 1:
            data = mutate(rng, base)
        else:
            size = int(rng.integers(0, 400))
            off = int(rng.integers(0, len(pool) - size))
            data = pool[off:off + size]
        k = int(rng.integers(0, 4))
        cuts = sorted(rng.integers(0, len(data) + 1, k).tolist()) if k else []
        try:
            check(name, opts, data, cuts, i % 50 == 0)
        except Exception as e:      # noqa: BLE001 - every failure is recorded
            failures += 1
            if first is None:
                first = f"{type(e).__name__}: {e} (input {data[:40]!r}..., cuts {cuts})"
    return failures, first, time.perf_counter() - t0


HEADERS = [b"% evt 2.0\n% format EVT2;height=480;width=640\n% end\n",
           b"% evt 3.0\n% geometry 1280x720\n",
           b"Event Stream\x02\x00\x00\x01\x40\x01\xf0\x00",
           b"Event Stream\x02\x00\x00\x02\x30\x01\xf0\x00",
           b"% Version 2\n% Width 640\n% Height 480\n\x0c\x08",
           b"t,x,y,p\n1,2,3,1\n",
           b"% evt 2.1\n% format EVT21;height=320;width=320\n% end\n",
           b"% evt 2.1\n% end\n",
           aedat4.encode(make([0], [1], [1], [1]), 320, 240)[:-40]]


def flip(rng, base: bytes) -> bytes:
    """1-5 bit flips anywhere in ``base`` (its length and offsets kept)."""
    buf = bytearray(base)
    for _ in range(int(rng.integers(1, 6))):
        buf[int(rng.integers(0, len(buf)))] ^= 1 << int(rng.integers(0, 8))
    return bytes(buf)


def fuzz_headers(n, rng):
    failures, first = 0, None
    with tempfile.TemporaryDirectory(dir="/dev/shm" if os.path.isdir("/dev/shm") else None) as d:
        path = Path(d) / "f.bin"
        for i in range(n):
            base = HEADERS[i % len(HEADERS)] + bytes(rng.integers(0, 256, 64, dtype=np.uint8))
            kind = i // len(HEADERS) % 4
            path.write_bytes(base[:int(rng.integers(0, 40))] if kind == 0
                             else flip(rng, base) if kind == 1 else mutate(rng, base))
            try:
                r = sio.open(path)
                r.read()
            except sio.DecodeError:
                pass
            except Exception as e:  # noqa: BLE001
                failures += 1
                if first is None:
                    first = f"{type(e).__name__}: {e} (file {path.read_bytes()[:60]!r})"
    return failures, first
