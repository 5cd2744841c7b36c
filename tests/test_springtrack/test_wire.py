"""springtrack.wire: COBS, CRC, frames, codecs, telemetry budget, signing, fuzzing."""
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from springtrack import model, wire
from springtrack.wire import MsgType


# ---- COBS -------------------------------------------------------------------------
def test_cobs_hand_computed_cases():
    # examples from Cheshire & Baker / the Wikipedia table
    assert wire.cobs_encode(b"\x00") == b"\x01\x01"
    assert wire.cobs_encode(b"\x00\x00") == b"\x01\x01\x01"
    assert wire.cobs_encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"
    assert wire.cobs_encode(b"\x11\x22\x33\x44") == b"\x05\x11\x22\x33\x44"
    assert wire.cobs_encode(b"\x11\x00\x00\x00") == b"\x02\x11\x01\x01\x01"
    data = bytes(range(1, 255))                         # 254 non-zero bytes
    assert wire.cobs_encode(data) == b"\xff" + data + b"\x01"
    assert wire.cobs_decode(b"\xff" + data) == data       # the variant without the final code


@given(st.binary(max_size=2000))
@settings(deadline=None)
def test_cobs_roundtrip_and_no_zero(data):
    enc = wire.cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + len(data) // 254 + 1
    assert wire.cobs_decode(enc) == data


@given(st.binary(max_size=300))
@settings(deadline=None)
def test_cobs_decode_never_crashes(data):
    try:
        wire.cobs_decode(data)
    except wire.CobsError:
        pass


def test_cobs_rejects_truncated_block():
    with pytest.raises(wire.CobsError, match="needs 4 bytes"):
        wire.cobs_decode(b"\x05\x11\x22")


# ---- frames -------------------------------------------------------------------------
def test_frame_layout_byte_by_byte():
    f = wire.encode_frame(MsgType.START, 0x1234, b"")
    body = wire.cobs_decode(f[:-1])
    assert f[-1] == 0 and 0 not in f[:-1]
    assert body[:5] == bytes([wire.PROTOCOL_VERSION, 0x30, 0x00, 0x34, 0x12])
    assert body[5:] == struct.pack("<I", zlib.crc32(body[:5]))


@given(st.sampled_from(list(MsgType)), st.integers(0, 0xFFFF), st.binary(max_size=wire.MAX_PAYLOAD))
@settings(max_examples=200, deadline=None)
def test_frame_roundtrip(mtype, seq, payload):
    f = wire.FrameReader().feed(wire.encode_frame(mtype, seq, payload))
    assert len(f) == 1
    assert (f[0].type, f[0].seq, f[0].payload, f[0].version) == (mtype, seq, payload, 1)
    assert len(wire.encode_frame(mtype, seq, payload)) <= wire.framed_size(len(payload))


def test_oversized_payload_refused():
    with pytest.raises(wire.WireError, match="MAX_PAYLOAD"):
        wire.encode_frame(MsgType.LOG, 1, bytes(wire.MAX_PAYLOAD + 1))


@given(st.lists(st.binary(max_size=60), min_size=1, max_size=8), st.data())
@settings(max_examples=200, deadline=None)
def test_reader_resyncs_after_any_corruption(payloads, data):
    """Flip one byte inside frame k: frame k is dropped and counted, all others survive."""
    frames = [wire.encode_frame(MsgType.LOG, i, p) for i, p in enumerate(payloads)]
    k = data.draw(st.integers(0, len(frames) - 1))
    pos = data.draw(st.integers(0, len(frames[k]) - 2))
    xor = data.draw(st.integers(1, 255))
    bad = bytearray(frames[k])
    bad[pos] ^= xor
    stream = b"".join(frames[:k]) + bytes(bad) + b"".join(frames[k + 1:])
    r = wire.FrameReader()
    # feed in random-sized pieces
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=5)))
    got = []
    for a, b in zip([0] + cuts, cuts + [len(stream)]):
        got += r.feed(stream[a:b])
    want = [i for i in range(len(frames)) if i != k]
    assert [f.seq for f in got] == want
    c = r.counts
    errors = c["crc_errors"] + c["cobs_errors"] + c["malformed"]
    # a flip to 0x00 splits frame k into two bad pieces (one may be a harmless empty one)
    assert errors == 1 if bad[pos] != 0 else 1 <= errors <= 2


def test_reader_counts_each_error_kind():
    r = wire.FrameReader()
    good = wire.encode_frame(MsgType.START, 1)
    body = bytearray(wire.encode_body(MsgType.START, 2))
    body[0] ^= 0xFF
    assert r.feed(wire.cobs_encode(bytes(body)) + b"\x00") == []
    assert r.counts["crc_errors"] == 1
    assert r.feed(b"\x05\x01\x00") == []                  # block claims 4 bytes, 1 present
    assert r.counts["cobs_errors"] == 1
    assert r.feed(wire.cobs_encode(b"\x01\x02") + b"\x00") == []   # too short for a header
    assert r.counts["malformed"] == 1
    assert r.feed(b"\x00\x00") == []                      # empty frames are padding, not errors
    assert [f.seq for f in r.feed(good)] == [1]
    assert r.counts["frames"] == 1


def test_reader_drops_runaway_garbage_and_resyncs():
    r = wire.FrameReader()
    assert r.feed(b"\x07" * (wire.MAX_ENCODED + 10)) == []
    assert r.counts["oversize"] == 1
    assert r.feed(b"\x07" * 50 + b"\x00") == []           # tail of the runaway frame
    assert [f.seq for f in r.feed(wire.encode_frame(MsgType.STOP, 9))] == [9]


def test_hunting_reader_skips_the_tail_it_attached_to_without_an_error():
    tail = wire.encode_frame(MsgType.LOG, 1, b"abcdef")[4:]
    r = wire.FrameReader(hunting=True)
    assert [f.seq for f in r.feed(tail + wire.encode_frame(MsgType.LOG, 2))] == [2]
    assert r.counts["crc_errors"] + r.counts["cobs_errors"] + r.counts["malformed"] == 0
    r = wire.FrameReader()
    assert [f.seq for f in r.feed(tail + wire.encode_frame(MsgType.LOG, 2))] == [2]
    assert r.counts["crc_errors"] + r.counts["cobs_errors"] + r.counts["malformed"] == 1


@given(st.binary(max_size=400))
@settings(max_examples=300, deadline=None)
def test_reader_never_crashes_on_random_bytes(data):
    r = wire.FrameReader()
    for f in r.feed(data):
        assert isinstance(f, wire.Frame)


def test_seq_tracker_counts_gaps_with_wraparound():
    s = wire.SeqTracker()
    assert [s.update(q) for q in (65533, 65534, 1, 2, 2, 5)] == [0, 0, 2, 0, 0, 2]
    assert (s.lost, s.duplicates) == (4, 1)
    s.restart(100)                       # a new session: no gap from 5 to 100
    assert [s.update(q) for q in (101, 103)] == [0, 1] and s.lost == 5


# ---- payload codecs -------------------------------------------------------------------
values = st.one_of(st.booleans(), st.integers(-2**63, 2**63 - 1),
                   st.floats(allow_nan=False), st.text(max_size=40))


@given(st.dictionaries(st.text(min_size=1, max_size=30), values, max_size=20))
@settings(deadline=None)
def test_kv_roundtrip(d):
    assert wire.decode_kv(wire.encode_kv(d)) == d
    parts = wire.split_kv(d, budget=200)
    merged = {}
    for p in parts:
        assert len(wire.encode_kv(p)) <= 200 or len(p) == 1
        merged.update(p)
    assert merged == d


@given(st.text(max_size=30), values)
@settings(deadline=None)
def test_param_set_roundtrip(name, v):
    n, got = wire.decode_param_set(wire.encode_param_set(name, v))
    assert n == name and got == v and type(got) is type(v)


def test_codecs_roundtrip_by_hand():
    assert wire.decode_hello(wire.encode_hello("me", 7)) == (7, "me", wire.Role.OPERATOR)
    assert wire.decode_hello(wire.encode_hello("me", 7, wire.Role.MONITOR)).role == wire.Role.MONITOR
    assert wire.decode_hello(wire.encode_hello("me")[:-1]).role == wire.Role.OPERATOR   # v1 hosts
    assert wire.decode_ack(wire.encode_ack(70000, MsgType.PARAM_SET, 5)) == (70000 & 0xFFFF, 0x20, 5)
    assert wire.decode_nack(wire.encode_nack(3, 0x20, wire.Nack.OUT_OF_RANGE, "α too big")) == \
        (3, 0x20, 2, "α too big")
    assert wire.decode_param_get(wire.encode_param_get(["a", "bb"])) == ["a", "bb"]
    assert wire.decode_model_begin(wire.encode_model_begin(b"abc")) == (3, zlib.crc32(b"abc"))
    assert wire.decode_model_chunk(wire.encode_model_chunk(512, b"xy")) == (512, b"xy")
    hb = dict(uptime_us=2**40, rx_frames=1, rx_errors=2, rx_lost=3, tx_frames=4, tx_dropped=5)
    assert wire.decode_heartbeat(wire.encode_heartbeat(**hb)) == hb
    assert wire.decode_log(wire.encode_log(2, "hi")) == (2, "hi")
    info = wire.decode_info(wire.encode_info({"model": "face26", "generation": 4, "running": True},
                                             b"12345678", True))
    assert info["model"] == "face26" and info["generation"] == 4 and info["running"]
    assert info["nonce"] == b"12345678" and info["auth_required"] and info["protocol_version"] == 1
    # every reply names the request's seq through its decoder
    def reply(mtype, payload):
        return wire.decode_reply(wire.decode_body(wire.encode_body(mtype, 99, payload)))
    assert reply(MsgType.ACK, wire.encode_ack(7, MsgType.PARAM_SET, 3)) == wire.Ack(7, 0x20, 3)
    refusal = reply(MsgType.NACK, wire.encode_nack(8, 0x20, wire.Nack.OUT_OF_RANGE, "too big"))
    assert refusal == wire.Refusal(8, 0x20, 2, "too big") and refusal.code_name == "out_of_range"
    assert wire.Refusal(8, 0x20, 200, "").code_name == "code 200"     # from a newer firmware
    part = reply(MsgType.STATS, wire.encode_reply_part(9, 1, 2, {"a": 1}))
    assert part == wire.ReplyPart(9, 1, 2, {"a": 1})
    with pytest.raises(wire.WireError, match="not a reply"):
        reply(MsgType.TELEMETRY, b"")


@pytest.mark.parametrize("decoder", [wire.decode_hello, wire.decode_ack, wire.decode_nack,
                                     wire.decode_param_set, wire.decode_param_get, wire.decode_kv,
                                     wire.decode_info, wire.decode_model_begin,
                                     wire.decode_model_chunk, wire.decode_heartbeat,
                                     wire.decode_log, wire.decode_telemetry,
                                     wire.decode_energies, wire.decode_applied])
@given(payload=st.binary(max_size=80))
@settings(max_examples=100, deadline=None)
def test_decoders_raise_only_wire_errors(decoder, payload):
    try:
        decoder(payload)
    except wire.WireError:
        pass


def test_decoder_errors_name_message_and_field():
    with pytest.raises(wire.WireError, match=r"PARAM_SET: truncated at value of 'ab'"):
        wire.decode_param_set(b"\x02abf\x00")
    with pytest.raises(wire.WireError, match="unexpected trailing"):
        wire.decode_hello(wire.encode_hello("x") + b"z")


# ---- telemetry ------------------------------------------------------------------------
def face26_snapshot():
    a = model.face26().arrays()
    tr = np.zeros(26, wire.TRACK_DTYPE)
    for k in ("x", "y", "sxx", "sxy", "syy"):
        tr[k] = a[k]
    tr["sxy"] = 0.3 * np.sqrt(tr["sxx"] * tr["syy"])
    tr["activity"] = np.geomspace(0.5, 5000, 26)
    tr["active"] = np.arange(26) % 2 == 0
    tr["sensitive"] = np.arange(26) % 3 == 0
    return tr


def test_face26_snapshot_fits_256_bytes_framed():
    p = wire.encode_telemetry(2**40 + 5, 70001, 123.25, wire.quantise_trackers(face26_snapshot()))
    assert len(p) == 15 + 26 * 8 == 223
    assert len(wire.encode_frame(MsgType.TELEMETRY, 1, p)) <= wire.framed_size(223) == 234 <= 256


def test_telemetry_quantisation_bounds():
    tr = face26_snapshot()
    payload = wire.encode_telemetry(2**40 + 5, 70001, 123.25, wire.quantise_trackers(tr))
    t, gen, me, out = wire.decode_telemetry(payload)
    assert (t, gen, me) == (2**40 + 5, 70001 & 0xFFFF, 123.25)
    assert np.all(np.abs(out["x"] - tr["x"]) <= 1 / 32 + 1e-12)
    assert np.all(np.abs(out["y"] - tr["y"]) <= 1 / 32 + 1e-12)
    assert np.array_equal(out["active"], tr["active"])
    assert np.array_equal(out["sensitive"], tr["sensitive"])
    assert np.all(np.abs(np.sqrt(out["sxx"]) - np.sqrt(tr["sxx"])) <= 1 / 8 + 1e-12)
    rho = out["sxy"] / np.sqrt(out["sxx"] * out["syy"])
    assert np.all(np.abs(rho - 0.3) <= 0.5 / 127 + 1e-9)
    ratio = (1 + out["activity"]) / (1 + tr["activity"])       # log-scale: 1/32 octave
    assert np.all(np.abs(np.log2(ratio)) <= 1 / 32 + 1e-12)


def test_telemetry_clamps_and_saturates():
    tr = np.zeros(3, wire.TRACK_DTYPE)
    tr["x"] = [-5.0, 5000.0, 0.0]
    tr["y"] = [1.0625, 2047.9375, 0]
    tr["sxx"] = [100.0 ** 2, 1.0, 0.0]
    tr["syy"] = [1.0, 1.0, 0.0]
    tr["activity"] = [0.0, 1e9, 1.0]
    _, _, _, out = wire.decode_telemetry(wire.encode_telemetry(0, 0, 0.0, wire.quantise_trackers(tr)))
    assert list(out["x"]) == [0.0, wire.POS_MAX, 0.0]
    assert list(out["y"]) == [1.0625, 2047.9375, 0.0]
    assert out["sxx"][0] == (255 / 4) ** 2 and out["sxy"][2] == 0
    assert out["activity"][0] == 0.0 and out["activity"][2] == 1.0
    assert out["activity"][1] == 2 ** (255 / 16) - 1


@pytest.mark.parametrize("field", wire.NUMERIC_FIELDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_tracker_state_has_no_code_and_is_never_sent_as_a_number(field, bad):
    tr = np.zeros(3, wire.TRACK_DTYPE)
    tr["sxx"] = tr["syy"] = 4.0
    tr[field][1] = bad
    with pytest.raises(wire.WireError, match=f"non-finite tracker state \\({field}\\)"):
        wire.quantise_trackers(tr)


@pytest.mark.parametrize("energy, want", [(1e300, np.inf), (-1e39, -np.inf), (3.5e38, np.inf),
                                          (1e38, np.float32(1e38)), (np.nan, np.nan)])
def test_mean_energy_beyond_float32_saturates_instead_of_raising(energy, want):
    recs = wire.quantise_trackers(np.zeros(2, wire.TRACK_DTYPE))
    _, _, me, _ = wire.decode_telemetry(wire.encode_telemetry(5, 1, energy, recs))
    assert (np.isnan(me) and np.isnan(want)) or me == want
    _, _, e = wire.decode_energies(wire.encode_energies(5, 0, [energy, 1.0]))
    assert (np.isnan(e[0]) and np.isnan(want)) or e[0] == want


def test_info_always_fits_one_frame():
    """A model name too long for a frame (the firmware refuses it at upload, this is the
    last line) is cut, and INFO still decodes."""
    info = dict(model="m" * 1200, model_hash="ab" * 32, trackers=[f"t{k}" for k in range(64)],
                generation=3, firmware="x")
    p = wire.encode_info(info, b"12345678", False)
    assert len(p) <= wire.MAX_PAYLOAD
    got = wire.decode_info(p)
    assert got["model"] == "m" * wire.INFO_CUT_BYTES and got["truncated"] == ["model"]
    assert got["trackers_omitted"] == 64 and got["model_hash"] == "ab" * 32


def test_energies_roundtrip_float32():
    e = np.array([0.0, 1.5, 1e-3, 123456.789])
    t, kind, got = wire.decode_energies(wire.encode_energies(77, 1, e))
    assert (t, kind) == (77, 1) and np.allclose(got, e, rtol=1e-7)
    assert wire.decode_applied(wire.encode_applied(5, -3)) == (5, -3)


# ---- signing ----------------------------------------------------------------------------
def test_signed_frames_verify_and_replays_are_refused():
    key, nonce = b"k" * 32, b"n" * 8
    signer = wire.Signer(key, nonce)
    guard = wire.ReplayGuard(key, nonce)
    raw = wire.encode_frame(MsgType.PARAM_SET, 5, wire.encode_param_set("a", 1.0), signer=signer)
    f = wire.FrameReader().feed(raw)[0]
    assert f.flags & wire.FLAG_SIGNED and len(f.tag) == 16
    assert f.payload == wire.encode_param_set("a", 1.0)
    assert guard.check(f) is None
    assert guard.check(f) == "replay"
    assert wire.ReplayGuard(b"x" * 32, nonce).check(f) == "bad_tag"
    assert wire.ReplayGuard(key, b"m" * 8).check(f) == "bad_tag"
    assert guard.check(wire.FrameReader().feed(wire.encode_frame(MsgType.START, 6))[0]) == "unsigned"
    later = wire.FrameReader().feed(wire.encode_frame(MsgType.START, 6, signer=signer))[0]
    assert guard.check(later) is None


def test_tampered_signed_payload_fails_tag_even_with_fixed_crc():
    key, nonce = b"k" * 32, b"n" * 8
    body = bytearray(wire.encode_body(MsgType.PARAM_SET, 5, wire.encode_param_set("a", 1.0),
                                      signer=wire.Signer(key, nonce)))
    body[7] ^= 1                                     # change the name, then fix the CRC
    body[-4:] = struct.pack("<I", zlib.crc32(bytes(body[:-4])))
    f = wire.decode_body(bytes(body))
    assert wire.ReplayGuard(key, nonce).check(f) == "bad_tag"


def test_telemetry_carries_the_instance_states_in_an_optional_trailer():
    tr = face26_snapshot()
    rec = wire.quantise_trackers(tr)
    plain = wire.encode_telemetry(7, 1, 0.5, rec)
    assert wire.encode_telemetry(7, 1, 0.5, rec, np.ones(26, np.uint8)) == plain   # all tracking
    assert (wire.decode_telemetry(plain)[3]["state"] == 1).all()
    st = np.array([1] * 10 + [2] * 10 + [0] * 6, np.uint8)
    p = wire.encode_telemetry(7, 1, 0.5, rec, st)
    assert len(p) == len(plain) + 1 + 3 * 3
    assert np.array_equal(wire.decode_telemetry(p)[3]["state"], st)
    for bad in (p[:-1], p + b"\x00", plain + bytes([1, 1, 25, 0]),       # short, long, 25 of 26
                plain + bytes([1, 7, 26, 0])):                          # an unknown state
        with pytest.raises(wire.WireError, match="TELEMETRY"):
            wire.decode_telemetry(bad)


def test_telemetry_carries_the_velocities_in_an_optional_block():
    """The motion model's velocities (eq. M7) within VEL_UNIT / 2 px/s, saturated at the
    i16 code's end; still trackers (the model off) send the frame they always sent; the
    block and the states trailer together; a block cut short is a WireError."""
    tr = face26_snapshot()
    rec = wire.quantise_trackers(tr)
    plain = wire.encode_telemetry(7, 1, 0.5, rec)
    assert wire.encode_telemetry(7, 1, 0.5, rec, None, wire.quantise_velocities(tr)) == plain
    assert (wire.decode_telemetry(plain)[3][["vx", "vy"]].tolist() == [(0.0, 0.0)] * 26)
    tr["vx"] = np.linspace(-13_000.0, 20_003.0, 26)
    tr["vy"] = -np.geomspace(0.1, 300_000.0, 26)                  # the last beyond the code
    vel = wire.quantise_velocities(tr)
    st = np.array([1] * 20 + [2] * 6, np.uint8)
    p = wire.encode_telemetry(7, 1, 0.5, rec, st, vel)
    assert len(p) == len(plain) + 1 + 26 * 4 + 1 + 2 * 3
    out = wire.decode_telemetry(p)[3]
    assert np.all(np.abs(out["vx"] - tr["vx"]) <= wire.VEL_UNIT / 2)
    assert np.all(np.abs(out["vy"][:-1] - tr["vy"][:-1]) <= wire.VEL_UNIT / 2)
    assert out["vy"][-1] == -0x7FFF * wire.VEL_UNIT
    assert np.array_equal(out["state"], st)
    assert np.array_equal(wire.decode_telemetry(wire.encode_telemetry(7, 1, 0.5, rec, None, vel))[3]["vx"],
                          out["vx"])
    for bad in (plain + bytes([wire.VELOCITY_TAG]) + vel.tobytes()[:-1],
                plain + bytes([wire.VELOCITY_TAG])):
        with pytest.raises(wire.WireError, match="velocity block"):
            wire.decode_telemetry(bad)
    tr["vx"][3] = np.nan
    with pytest.raises(wire.WireError, match="non-finite tracker velocity"):
        wire.quantise_velocities(tr)
