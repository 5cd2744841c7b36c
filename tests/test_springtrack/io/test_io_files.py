"""open()/write(): detection by content, every file format, and bad files."""
from __future__ import annotations

import os

import numpy as np
import pytest

import springtrack.io as sio
from springtrack.events import EVENT_DTYPE, make


@pytest.fixture
def events():
    rng = np.random.default_rng(3)
    n = 5000
    return make(np.sort(rng.integers(0, 3_000_000, n)), rng.integers(0, 304, n),
                rng.integers(0, 240, n), rng.integers(0, 2, n))


@pytest.mark.parametrize("name,fmt,expect", [
    ("a.raw", None, "evt2"), ("a.es", None, "es"), ("a.dat", None, "dat"),
    ("a.ccam", None, "ccam"), ("a.npy", None, "npy"), ("a.csv", None, "csv"),
    ("a.bin", "evt3", "evt3"), ("a.bin", "es-atis", "es"), ("a.raw", "evt3", "evt3")])
def test_write_open_round_trip(tmp_path, events, name, fmt, expect):
    path = tmp_path / name
    sio.write(path, events, 304, 240, format=fmt)
    r = sio.open(path)
    assert r.format == expect
    if expect not in ("npy", "csv"):
        assert (r.width, r.height) == (304, 240)
    got = r.read()
    want = events.copy()
    if expect == "es":
        pass                                   # absolute t kept (stream counts from 0)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.concatenate(list(r.chunks(777))), want)
    assert r.stats.total_anomalies == 0
    if fmt == "es-atis":
        assert r.event_type == "atis"


def test_detection_ignores_misleading_extension(tmp_path, events):
    path = tmp_path / "recording.dat"
    sio.write(path, events, 304, 240, format="evt2")
    assert sio.open(path).format == "evt2"
    es_path = tmp_path / "recording.raw"
    sio.write(es_path, events, 304, 240, format="es")
    assert sio.open(es_path).format == "es"


def test_npy_packed_dtype_converted(tmp_path, events):
    packed = np.zeros(len(events), dtype=[("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")])
    for f in "txyp":
        packed[f] = events[f]
    np.save(tmp_path / "p.npy", packed)
    got = sio.open(tmp_path / "p.npy").read()
    assert got.dtype == EVENT_DTYPE
    np.testing.assert_array_equal(got, events)


def test_npy_without_fields(tmp_path):
    np.save(tmp_path / "bad.npy", np.zeros(4))
    with pytest.raises(sio.DecodeError, match="missing t, x, y, p"):
        sio.open(tmp_path / "bad.npy").read()


@pytest.mark.parametrize("field,value,match", [
    ("x", -1, "event 2: x=-1 out of range 0..65535"),
    ("x", 70000, "event 2: x=70000 out of range 0..65535"),
    ("p", 7, "event 2: p=7 out of range 0..1"),
    ("t", np.nan, "event 2: t=nan is not a finite number"),
    ("t", 2.5, "event 2: t=2.5 is not a whole number"),
    ("t", 2.0 ** 63, r"event 2: t=9.2\d+e\+18 out of range"),
])
def test_npy_values_are_checked_like_csv_rows(tmp_path, field, value, match):
    """A .npy in other types (int32 x, float t, ...) is converted only if every value fits
    the event record: the checks of every event source (springtrack.events.as_events)."""
    arr = np.zeros(4, [("t", "<f8"), ("x", "<i4"), ("y", "<i4"), ("p", "<i2")])
    arr["t"] = [1, 2, 3, 4]
    arr[field][2] = value
    np.save(tmp_path / "v.npy", arr)
    with pytest.raises(sio.DecodeError, match=f"v.npy: {match}"):
        sio.open(tmp_path / "v.npy").read()
    arr[field][2] = 3 if field == "t" else 1
    np.save(tmp_path / "v.npy", arr)
    assert sio.open(tmp_path / "v.npy").read()["t"].tolist() == [1, 2, 3, 4]


def test_trackers_take_only_checked_events():
    from springtrack import Tracker
    from springtrack.events import EventError
    ev = np.zeros(3, [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")])
    ev["x"][1] = -1
    with pytest.raises(EventError, match="event 1: x=-1"):
        Tracker("grid3x3").process(ev)
    own = np.zeros(3, EVENT_DTYPE)
    own["p"][2] = 7
    with pytest.raises(EventError, match="event 2: p=7"):
        Tracker("grid3x3").process(own)


def test_a_percent_header_over_1_mib_is_refused(tmp_path):
    """'%' lines past MAX_HEADER bytes are not decoded as events (786 434 of them, before)."""
    from springtrack.io.detect import MAX_HEADER
    line = b"% comment " + b"x" * 100 + b"\n"
    path = tmp_path / "long.raw"
    path.write_bytes(b"% evt 2.0\n" + line * (MAX_HEADER // len(line) + 5) + bytes(64))
    with pytest.raises(sio.DecodeError, match="go on past 1048576 bytes"):
        sio.open(path)
    # a header just under the limit, then its payload, still opens
    path.write_bytes(b"% evt 2.0\n" + line * (MAX_HEADER // len(line) - 2) + b"% end\n"
                     + bytes(64))
    assert sio.open(path).format == "evt2"


def test_csv_errors_name_the_line(tmp_path):
    (tmp_path / "a.csv").write_text("t,x,y,p\n1,2,3,1\n2,3,4,7\n")
    with pytest.raises(sio.DecodeError, match="line 3: p=7"):
        sio.open(tmp_path / "a.csv").read()
    (tmp_path / "b.csv").write_text("t,x,y,p\n1,2,3\n")
    with pytest.raises(sio.DecodeError, match="b.csv"):
        sio.open(tmp_path / "b.csv").read()
    (tmp_path / "c.csv").write_text("t,x,y,p\n")
    assert len(sio.open(tmp_path / "c.csv").read()) == 0


def test_unreadable_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        sio.open(tmp_path / "missing.raw")
    with pytest.raises(IsADirectoryError):
        sio.open(tmp_path)
    (tmp_path / "empty.raw").write_bytes(b"")
    with pytest.raises(sio.DecodeError, match="empty file"):
        sio.open(tmp_path / "empty.raw")
    (tmp_path / "garbage.raw").write_bytes(os.urandom(1000).replace(b"%", b"!") + b"x")
    with pytest.raises(sio.DecodeError, match="unknown format"):
        sio.open(tmp_path / "garbage.raw")


@pytest.mark.parametrize("content,match", [
    (b"% date today\n\x00\x00", "names no encoding"),
    (b"% evt 4.0\n", "EVT 2.0, EVT 2.1 and EVT 3.0"),
    (b"% evt 2.0\n% format EVT2;height=abc;width=10\n", "not an integer"),
    (b"% evt 2.0\n% geometry 0x10\n", "out of range"),
    (b"% evt 2.0\n% unterminated", "no end of line"),
    (b"Event Stream\x01\x00\x00\x01\x40\x01\xf0\x00", "version 1.0.0 not supported"),
    (b"Event Stream\x02\x00\x00\x00", "type generic not supported"),
    (b"Event Stream\x02\x00\x00\x01\x40", "truncated"),
    (b"% Version 2\n% Width 10\n% Height 10\n\x0c\x04", "event size 4"),
])
def test_bad_headers(tmp_path, content, match):
    path = tmp_path / "f.bin"
    path.write_bytes(content)
    with pytest.raises(sio.DecodeError, match=match):
        sio.open(path)


def test_header_that_lies_about_geometry(tmp_path, events):
    data = sio.encode_file(events, 304, 240, "evt2")
    lie = data.replace(b"height=240;width=304", b"height=100;width=100").replace(
        b"geometry 304x240", b"geometry 100x100")
    (tmp_path / "lie.raw").write_bytes(lie)
    r = sio.open(tmp_path / "lie.raw")
    got = r.read()
    inside = (events["x"] < 100) & (events["y"] < 100)
    np.testing.assert_array_equal(got, events[inside])
    assert r.stats.anomalies["out_of_geometry"] == int((~inside).sum())


@pytest.mark.parametrize("fmt", ["evt2", "evt3", "es", "es-atis", "dat", "ccam"])
def test_truncated_and_garbage_payloads(tmp_path, events, fmt):
    data = sio.encode_file(events, 304, 240, fmt)
    rng = np.random.default_rng(7)
    for cut in rng.integers(30, len(data), 5):
        (tmp_path / "t.bin").write_bytes(data[:cut])
        r = sio.open(tmp_path / "t.bin", format=None if fmt != "ccam" else "ccam")
        got = r.read()
        assert len(got) <= len(events)
        np.testing.assert_array_equal(got, events[:len(got)])
    corrupt = bytearray(data)
    pos = rng.integers(len(data) // 2, len(data), 200)
    for p in pos:
        corrupt[p] = rng.integers(0, 256)
    (tmp_path / "g.bin").write_bytes(bytes(corrupt))
    r = sio.open(tmp_path / "g.bin", format=None if fmt != "ccam" else "ccam")
    got = r.read()
    assert r.stats.words > 0 and np.all(got["x"] < 304) and np.all(got["y"] < 240)


def test_writer_rejects_bad_input(tmp_path, events):
    with pytest.raises(ValueError, match="outside the 100x100 geometry"):
        sio.write(tmp_path / "a.raw", events, 100, 100)
    with pytest.raises(ValueError, match="non-decreasing"):
        sio.write(tmp_path / "a.raw", events[::-1], 304, 240)
    with pytest.raises(ValueError, match="extension"):
        sio.write(tmp_path / "a.xyz", events, 304, 240)
    with pytest.raises(ValueError, match="pass width and height"):
        sio.write(tmp_path / "a.es", events)
    with pytest.raises(ValueError, match="304x240"):
        sio.write(tmp_path / "a.ccam", events, 640, 480)


def test_backwards_time_in_a_file_is_counted(tmp_path):
    words = np.array([0x8000_0100, 0x1000_0000, 0x8000_00F0, 0x1000_0801], dtype="<u4")
    (tmp_path / "b.raw").write_bytes(b"% evt 2.0\n" + words.tobytes())
    r = sio.open(tmp_path / "b.raw")
    ev = r.read()
    assert list(ev["t"]) == [0x100 * 64, 0x101 * 64]     # rebased one unit past 0x100
    assert r.stats.anomalies["time_backwards"] == 1


def test_long_header_and_empty_payload(tmp_path, events):
    data = sio.encode_file(events, 304, 240, "evt2")
    long = b"% comment " + b"x" * 100_000 + b"\n" + data
    (tmp_path / "long.raw").write_bytes(long)
    r = sio.open(tmp_path / "long.raw")
    assert (r.width, r.height) == (304, 240) and "comment" in r.header
    np.testing.assert_array_equal(r.read(), events)
    (tmp_path / "hdr.raw").write_bytes(b"% evt 3.0\n% end\n")
    r = sio.open(tmp_path / "hdr.raw")
    assert r.format == "evt3" and len(r.read()) == 0 and list(r.chunks()) == []


def test_size_hint(tmp_path, events):
    sio.write(tmp_path / "a.raw", events, 304, 240)
    hint = sio.open(tmp_path / "a.raw").size_hint
    assert len(events) <= hint <= 2 * len(events)       # one TIME_HIGH word per ~64 us
    sio.write(tmp_path / "a.npy", events)
    assert sio.open(tmp_path / "a.npy").size_hint == len(events)


def test_es_writer_refuses_absurd_time_offsets(tmp_path):
    ev = make([10**12], [1], [1], [1])          # an absolute epoch time in us
    with pytest.raises(ValueError, match="subtract the first timestamp"):
        sio.write(tmp_path / "a.es", ev, 304, 240)


def test_large_decoder_outputs_start_on_a_huge_page():
    """Decoder outputs of 4 MiB and more start on a 2 MiB boundary (huge pages back all of
    them); smaller ones are plain arrays."""
    from springtrack.events import EVENT_DTYPE, HUGE_PAGE, empty_output
    big = empty_output(300_000)                    # 4.8 MB
    assert big.dtype == EVENT_DTYPE and big.shape == (300_000,) and big.flags.c_contiguous
    assert big.ctypes.data % HUGE_PAGE == 0 and big.flags.writeable
    big[-1] = (1, 2, 3, 1)                         # the whole length is usable
    assert tuple(big[-1]) == (1, 2, 3, 1)
    small = empty_output(1000)
    assert small.base is None and small.shape == (1000,)
