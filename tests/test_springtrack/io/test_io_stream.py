"""RAW streams on standard input: decoded as they arrive (a real pipe), the same events as
the file, `springtrack track -` in a separate process, clear errors for what a pipe cannot
carry."""
from __future__ import annotations

import io
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

import springtrack.io as sio
from springtrack.events import make
from springtrack.io.stream import open_stream

RNG = np.random.default_rng(7)
N = 50_000
EV = make(np.sort(RNG.integers(0, 1_000_000, N)), RNG.integers(0, 304, N),
          RNG.integers(0, 240, N), RNG.integers(0, 2, N))


@pytest.mark.parametrize("fmt", ["evt2", "evt21", "evt21-legacy", "evt3", "es", "dat",
                                 "aedat4"])
def test_stream_equals_file(fmt):
    data = sio.encode_file(EV, 304, 240, fmt)
    r = open_stream(io.BytesIO(data))
    assert (r.format, r.width, r.height, r.size_hint) == (fmt.split("-")[0], 304, 240, None)
    chunks = list(r.chunks(4096))
    assert len(chunks) > 10                       # bounded chunks, not one read of it all
    np.testing.assert_array_equal(np.concatenate(chunks), EV)
    assert r.stats.events == N and r.stats.total_anomalies == 0


def test_events_arrive_before_the_stream_ends():
    """A live pipe: the writer holds back the second half until the reader has yielded
    events from the first, so a reader that waited for the end would never see them."""
    data = sio.encode_file(EV, 304, 240, "evt3")
    rfd, wfd = os.pipe()
    first_seen = threading.Event()
    waited = []

    def writer():
        with os.fdopen(wfd, "wb") as w:
            w.write(data[:len(data) // 2])
            w.flush()
            waited.append(first_seen.wait(timeout=60))
            w.write(data[len(data) // 2:])

    th = threading.Thread(target=writer, daemon=True)
    th.start()
    parts = []
    with os.fdopen(rfd, "rb") as f:
        for ev in open_stream(f).chunks(1 << 16):
            parts.append(ev)
            first_seen.set()
    th.join(timeout=60)
    assert waited == [True]
    np.testing.assert_array_equal(np.concatenate(parts), EV)


def test_track_reads_stdin(tmp_path):
    """`springtrack track -` in its own process, fed through a pipe: the same track CSV as
    from the file."""
    path = tmp_path / "rec.raw"
    sio.write(path, EV, 304, 240, format="evt21")
    cmd = [sys.executable, "-m", "springtrack.cli", "track"]
    args = ["--model", "grid3x3", "--no-progress"]
    from_file = subprocess.run(cmd + [str(path), "--out", str(tmp_path / "a.csv")] + args,
                               capture_output=True, text=True, timeout=300)
    assert from_file.returncode == 0, from_file.stderr
    with open(path, "rb") as stdin:
        piped = subprocess.run(cmd + ["-", "--out", str(tmp_path / "b.csv")] + args,
                               stdin=stdin, capture_output=True, text=True, timeout=300)
    assert piped.returncode == 0, piped.stderr
    assert f"events={N}" in piped.stdout
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


@pytest.mark.parametrize("content,match", [
    (b"", "must start with its header"),
    (b"\x00\x01\x02garbage", "must start with its header"),
    (b"% Version 2\n% Width 10\n% Height 10\n% end\n\x00\x04", "event size 4"),
    (b"Event Stream\x02\x00\x00\x01\x40", "truncated"),
    (b"#!AER-DAT4.0\r\n\x40\x00\x00\x00", "IOHeader truncated"),
    (b"% evt 2.0\n% unterminated", "no end of line"),
    (b"% evt 9.0\n% end\n", "not supported"),
])
def test_stream_errors(content, match):
    with pytest.raises(sio.DecodeError, match=match):
        open_stream(io.BytesIO(content))


def test_damaged_stream_is_counted():
    data = sio.encode_file(EV[:1000], 304, 240, "evt2")
    r = open_stream(io.BytesIO(data + b"\xff\xff\xff\x3f" * 3 + b"\x01\x02"))
    assert len(r.read()) == 1000
    assert r.stats.anomalies["unknown_type"] == 3 and r.stats.anomalies["truncated"] == 1
