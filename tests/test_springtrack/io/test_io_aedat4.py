"""AEDAT 4: the real DVXplorer recording against its facts and against the `aedat` package
event for event; our writer read back by both; corrupt, truncated and hostile files."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import springtrack.io as sio
from springtrack.events import EVENT_DTYPE, make
from springtrack.io import aedat4

COMPRESSIONS = ["NONE", "LZ4", "LZ4_HIGH", "ZSTD", "ZSTD_HIGH"]


def aedat_events(path) -> np.ndarray:
    """The events of the `aedat` package's decoder (Rust), as EVENT_DTYPE."""
    aedat = pytest.importorskip("aedat")
    packets = [p["events"] for p in aedat.Decoder(str(path)) if "events" in p]
    ref = np.concatenate(packets)
    return make(ref["t"].astype(np.int64), ref["x"], ref["y"], ref["on"])


def test_sample_facts(data_file):
    r = sio.open(data_file("sample.aedat4"))
    assert (r.format, r.width, r.height) == ("aedat4", 320, 240)
    assert r.header["compression"] == "LZ4" and r.header["geometry_source"] == "info node"
    assert r.header["streams"].startswith("0 events (EVTS 320x240, DVXplorer")
    ev = r.read()
    assert len(ev) == 111_954
    assert ev["t"][0] == 1_605_537_493_718_345 and ev["t"][-1] == 1_605_537_494_308_262
    assert ev["x"].max() == 319 and ev["y"].max() == 239
    s = r.stats
    assert s.total_anomalies == 0 and s.events == len(ev) and s.pending_bytes == 0
    # the IMU stream is skipped and counted; the data table at the end is not a packet
    assert s.info["event_packets"] == 59 and s.info["imu_packets"] == 59
    assert s.info["data_table_bytes"] > 0 and s.words == 118


def test_sample_equals_aedat_package(data_file):
    path = data_file("sample.aedat4")
    np.testing.assert_array_equal(sio.open(path).read(), aedat_events(path))


@pytest.mark.slow
def test_sample_any_chunking(data_file):
    r = sio.open(data_file("sample.aedat4"))
    whole = r.read()
    for size in (1, 7, 4096, 1 << 20):
        if size == 1:
            data = data_file("sample.aedat4").read_bytes()[r.offset:r.offset + 60_000]
            dec = r.decoder()
            ev = np.concatenate([dec.decode(data[i:i + 1]) for i in range(len(data))])
            assert len(ev) > 1000
            np.testing.assert_array_equal(ev, whole[:len(ev)])
            continue
        np.testing.assert_array_equal(np.concatenate(list(r.chunks(size))), whole)


@pytest.mark.slow
@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_writer_read_by_aedat_package(tmp_path, data_file, compression):
    ev = sio.open(data_file("sample.aedat4")).read()
    path = tmp_path / "out.aedat4"
    path.write_bytes(aedat4.encode(ev, 320, 240, compression, packet_events=5000))
    r = sio.open(path)
    assert r.header["compression"] == compression
    np.testing.assert_array_equal(r.read(), ev)
    np.testing.assert_array_equal(aedat_events(path), ev)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.integers(0, 1 << 20), st.integers(0, 345), st.integers(0, 259),
                          st.integers(0, 1)), max_size=300),
       st.sampled_from(COMPRESSIONS), st.integers(1, 70), st.lists(st.integers(0, 5000),
                                                                   max_size=8))
def test_round_trip_any_split(rows, compression, per_packet, cuts):
    rows.sort()
    ev = make(*(np.array(c, np.int64) for c in zip(*rows))) if rows else np.empty(0, EVENT_DTYPE)
    data = aedat4.encode(ev, 346, 260, compression, packet_events=per_packet)
    h = aedat4.parse_header(data)
    dec = sio.decoder("aedat4", width=346, height=260, compression=compression)
    body = data[h["offset"]:]
    parts, prev = [], 0
    for c in sorted(set(cuts)) + [len(body)]:
        parts.append(dec.decode(body[prev:max(prev, c)]))
        prev = max(prev, c)
    np.testing.assert_array_equal(np.concatenate(parts), ev)
    assert dec.finish() == 0 and dec.stats.total_anomalies == 0


def _file(tmp_path, ev, **kw):
    data = aedat4.encode(ev, 320, 240, **kw)
    return data, aedat4.parse_header(data)["offset"]


def packets(data, offset):
    """(start, stream id, size) of every packet."""
    out, pos = [], offset
    while pos + 8 <= len(data):
        sid = int.from_bytes(data[pos:pos + 4], "little", signed=True)
        size = int.from_bytes(data[pos + 4:pos + 8], "little")
        out.append((pos, sid, size))
        pos += 8 + size
    return out


EV = make(np.arange(3000) * 10, np.arange(3000) % 320, np.arange(3000) % 240,
          np.arange(3000) % 2)


def test_corrupt_packets_are_counted_and_skipped(tmp_path):
    data, off = _file(tmp_path, EV, compression="LZ4", packet_events=1000)
    pk = packets(data, off)
    assert len(pk) == 3
    bad = bytearray(data)
    start, _, size = pk[1]
    bad[start + 8 + size // 2:start + 8 + size // 2 + 16] = b"\xff" * 16   # inside packet 2
    path = tmp_path / "bad.aedat4"
    path.write_bytes(bytes(bad))
    r = sio.open(path)
    ev = r.read()
    np.testing.assert_array_equal(ev, np.concatenate([EV[:1000], EV[2000:]]))
    assert r.stats.anomalies["corrupt_packets"] == 1 and r.stats.info["event_packets"] == 2


def test_unknown_stream_and_other_types(tmp_path):
    data, off = _file(tmp_path, EV, compression="NONE", packet_events=1000)
    start = packets(data, off)[0][0]
    bad = bytearray(data)
    bad[start:start + 4] = (7).to_bytes(4, "little")         # a stream id the header lacks
    dec = sio.decoder("aedat4", width=320, height=240, compression="NONE",
                      streams={0: "EVTS", 3: "TRIG"})
    ev = dec.decode(bytes(bad[off:]))
    assert len(ev) == 2000 and dec.stats.anomalies["unknown_type"] == 1
    bad[start:start + 4] = (3).to_bytes(4, "little")         # now a trigger stream's packet
    dec = sio.decoder("aedat4", width=320, height=240, compression="NONE",
                      streams={0: "EVTS", 3: "TRIG"})
    assert len(dec.decode(bytes(bad[off:]))) == 2000
    assert dec.stats.info["trigger_packets"] == 1 and dec.stats.total_anomalies == 0


def test_geometry_and_time_anomalies():
    with pytest.raises(ValueError, match="non-decreasing"):
        aedat4.encode(make([5, 4], [1, 2], [1, 2], [1, 0]), 400, 240)
    ok = make([5, 6, 7, 8], [1, 319, 2, 3], [1, 2, 3, 4], [1, 0, 1, 0])
    data = bytearray(aedat4.encode(ok, 400, 240, "NONE"))
    off = aedat4.parse_header(bytes(data))["offset"]
    first = off + 8 + 32                                     # the first Event struct
    data[first + 16 * 2:first + 16 * 2 + 8] = (4).to_bytes(8, "little")   # t 7 -> 4
    data[first + 16 * 3 + 10:first + 16 * 3 + 12] = (-1).to_bytes(2, "little", signed=True)
    dec = sio.decoder("aedat4", width=300, height=240, compression="NONE")
    out = dec.decode(bytes(data[off:]))
    assert out["x"].tolist() == [1, 2] and out["t"].tolist() == [5, 4]
    assert dec.stats.anomalies["out_of_geometry"] == 2       # x = 319 >= 300, y = -1
    assert dec.stats.anomalies["time_backwards"] == 1        # kept as recorded


def test_truncated_file_and_lost_framing(tmp_path):
    data, off = _file(tmp_path, EV, compression="ZSTD", packet_events=1000)
    path = tmp_path / "cut.aedat4"
    path.write_bytes(data[:-5])
    r = sio.open(path)
    assert len(r.read()) == 2000 and r.stats.anomalies["truncated"] == 1
    assert r.stats.pending_bytes == 0 and r.stats.events == 2000
    bad = bytearray(data)
    start = packets(data, off)[1][0]
    bad[start + 4:start + 8] = (0xFFFF_FFF0).to_bytes(4, "little")   # an absurd size
    path.write_bytes(bytes(bad))
    r = sio.open(path)
    assert len(r.read()) == 1000
    a = r.stats.anomalies
    assert a["corrupt_packets"] == 1 and a["unframed_bytes"] == len(data) - start


def test_decompression_bomb_is_refused():
    zstandard = pytest.importorskip("zstandard")
    dec = sio.decoder("aedat4", compression="ZSTD")
    payload = zstandard.ZstdCompressor().compress(b"\0" * (1 << 22))   # 4 MiB of zeros
    assert len(payload) * aedat4.MAX_RATIO < 1 << 22
    ev = dec.decode((0).to_bytes(4, "little") + len(payload).to_bytes(4, "little") + payload)
    assert len(ev) == 0 and dec.stats.anomalies["corrupt_packets"] == 1


@pytest.mark.parametrize("content,match", [
    (b"#!AER-DAT4.0\r\n\x10", "truncated before its length"),
    (b"#!AER-DAT4.0\r\n\xff\xff\xff\x7f", "over"),
    (b"#!AER-DAT4.0\r\n\x40\x00\x00\x00" + b"\0" * 10, "IOHeader truncated"),
    (b"#!AER-DAT4.0\r\n\x08\x00\x00\x00" + b"\xff" * 8, "IOHeader unreadable"),
])
def test_header_errors(tmp_path, content, match):
    path = tmp_path / "bad.aedat4"
    path.write_bytes(content)
    with pytest.raises(sio.DecodeError, match=match):
        sio.open(path)


@pytest.mark.parametrize("xml,match", [
    ("<dv><node", "not XML"),
    ("<dv></dv>", "no 'outInfo'"),
    ('<dv><node name="outInfo"></node></dv>', "lists no streams"),
    ('<dv><node name="outInfo"><node name="x"/></node></dv>', "not an integer"),
    ('<dv><node name="outInfo"><node name="0"><attr key="typeIdentifier">EVTS</attr>'
     '</node></node></dv>', "no integer sizeX"),
    ('<dv><node name="outInfo"><node name="2"><attr key="typeIdentifier">IMUS</attr>'
     '</node></node></dv>', "no events"),
])
def test_info_node_errors(tmp_path, xml, match):
    header = aedat4._flatbuffer_header("LZ4", xml)
    path = tmp_path / "bad.aedat4"
    path.write_bytes(aedat4.MAGIC + len(header).to_bytes(4, "little") + header)
    with pytest.raises(sio.DecodeError, match=match):
        sio.open(path)


def test_geometry_from_info_node(tmp_path):
    path = tmp_path / "davis.aedat4"
    path.write_bytes(aedat4.encode(EV[:10], 346, 260))
    r = sio.open(path)
    assert (r.width, r.height) == (346, 260) and len(r.read()) == 10


def _valid_packets():
    ev = make(np.arange(50) * 3, np.arange(50) * 7 % 400, np.arange(50) % 240, np.arange(50) % 2)
    data = aedat4.encode(ev, 400, 240, "NONE", packet_events=9)
    return data[aedat4.parse_header(data)["offset"]:]


VALID = _valid_packets()


@st.composite
def hostile(draw):
    """Random bytes, or our packets with bytes overwritten (offsets, sizes, events)."""
    if draw(st.booleans()):
        return draw(st.binary(max_size=2000))
    buf = bytearray(VALID)
    for _ in range(draw(st.integers(1, 6))):
        i = draw(st.integers(0, len(buf) - 1))
        buf[i] = draw(st.integers(0, 255))
    return bytes(buf[:draw(st.integers(0, len(buf)))])


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(hostile(), st.sampled_from(["NONE", "LZ4", "ZSTD"]),
       st.lists(st.integers(0, 2000), max_size=8))
def test_any_bytes_decode_consistently(data, compression, cuts):
    opts = {"width": 320, "height": 240, "compression": compression}
    whole = sio.decoder("aedat4", **opts)
    ref = whole.decode(data)
    pend = whole.finish()
    dec = sio.decoder("aedat4", **opts)
    parts, prev = [], 0
    for c in sorted(set(cuts)) + [len(data)]:
        parts.append(dec.decode(data[prev:max(prev, c)]))
        prev = max(prev, c)
    assert dec.finish() == pend
    np.testing.assert_array_equal(np.concatenate(parts), ref)
    assert dec.stats == whole.stats and whole.stats.events == len(ref)
    assert np.all(ref["x"] < 320) and np.all(ref["y"] < 240)
    assert whole.stats.anomalies["truncated"] == (pend > 0)
