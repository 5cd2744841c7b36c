"""firmware_sim.link + transport driven by hostctl.Device over real pty pairs and TCP sockets,
against the real deterministic engine of tests/support/engine.py."""
import os
import random
import threading
import time

import numpy as np
import pytest

from firmware_sim import link, transport
from hostctl import Device, Nacked, NoAnswer, NoSuchPort, VersionMismatch
from springtrack import model as _model
from springtrack import wire
from springtrack.params import ENERGY_KINDS, Params
from springtrack.wire import MsgType
from support.engine import SimEngine
from support.link import Served, raw_host, read_frames
from support.wait import wait_for


@pytest.fixture
def served():
    eng = SimEngine()
    s = Served(eng)
    yield s
    s.close()
    eng.close()


# ---- commands ------------------------------------------------------------------------
def test_info_over_pty(served):
    with Device(served.path) as dev:
        assert dev.info["protocol_version"] == wire.PROTOCOL_VERSION
        assert dev.info["model"] == "face26" and len(dev.info["trackers"]) == 26
        assert dev.info["width"] == 304 and dev.info["max_trackers"] == 64
        assert dev.info["firmware"] == "test-sim-engine 1"
        assert not dev.info["auth_required"]


def test_set_get_and_nacks_leave_state_untouched(served):
    eng = served.engine
    with Device(served.path) as dev:
        g = dev.set(alpha_position=0.05)
        assert g == 2
        eng.step()                                      # the engine applies it between events
        assert dev.get("alpha_position") == {"alpha_position": 0.05}
        assert set(dev.get()) == set(eng.get_params())
        before = (eng.generation, eng.get_params())
        for kv, code, text in [({"nope": 1.0}, "unknown_name", "unknown parameter"),
                               ({"alpha_position": 3.0}, "out_of_range", "out of range"),
                               ({"alpha_position": "big"}, "wrong_type", "must be a number")]:
            with pytest.raises(Nacked, match=code) as e:
                dev.set(**kv)
            assert text in e.value.reason
        with pytest.raises(Nacked, match="unknown_name"):
            dev.get("nope")
        assert (eng.generation, eng.get_params()) == before
        st = dev.stats()
        assert st["link.nacks"] == 4 and st["link.acks"] == 1
        assert st["events_tracked"] == eng.counters["events_tracked"]


def test_model_upload_validated_and_atomic(served):
    eng = served.engine
    grid = _model.grid3x3()
    with Device(served.path) as dev:
        gen = dev.load_model(grid)
        eng.step()
        assert eng.model.name == "grid3x3" and eng.model.digest() == grid.digest()
        assert dev.hello()["model"] == "grid3x3"
        bad = grid.to_toml().replace("stiffness = 0.001", "stiffness = -1.0", 1)
        with pytest.raises(Nacked, match="invalid_model.*stiffness must not be negative"):
            dev.load_model(bad)
        eng.step()
        assert eng.model.digest() == grid.digest() and eng.generation == gen


def test_info_of_a_64_tracker_model_omits_ids_that_do_not_fit(served):
    eng = served.engine
    trackers = [_model.TrackerSpec(f"a_rather_long_tracker_name_{k:02d}", 10.0 + 4 * k, 100.0,
                                   (4.0, 0.0, 4.0)) for k in range(64)]
    big = _model.ShapeModel("big", 304, 240, trackers, [])
    with Device(served.path) as dev:
        dev.load_model(big)
        eng.step()
        info = dev.hello()
        assert info["model"] == "big" and info["trackers_omitted"] == 64
        assert "trackers" not in info


def test_model_commit_checks_length_crc_and_order(served):
    eng = served.engine
    with Device(served.path) as dev:
        text = _model.grid3x3().to_toml().encode()
        with pytest.raises(Nacked, match="bad_state"):
            dev._command(MsgType.MODEL_CHUNK, wire.encode_model_chunk(0, text[:10]))
        with pytest.raises(Nacked, match="bad_state"):
            dev._command(MsgType.MODEL_COMMIT, wire.encode_model_begin(text))
        dev._command(MsgType.MODEL_BEGIN, wire.encode_model_begin(text))
        dev._command(MsgType.MODEL_CHUNK, wire.encode_model_chunk(0, text[:100]))
        with pytest.raises(Nacked, match="100 of|missing"):
            dev._command(MsgType.MODEL_COMMIT, wire.encode_model_begin(text))
        dev._command(MsgType.MODEL_BEGIN, wire.encode_model_begin(text))
        with pytest.raises(Nacked, match="out_of_range"):
            dev._command(MsgType.MODEL_CHUNK, wire.encode_model_chunk(len(text) - 2, b"abc"))
        forged = text[:-1] + b"X"
        for off in range(0, len(forged), 512):
            dev._command(MsgType.MODEL_CHUNK, wire.encode_model_chunk(off, forged[off:off + 512]))
        with pytest.raises(Nacked, match="CRC-32 mismatch"):
            dev._command(MsgType.MODEL_COMMIT, wire.encode_model_begin(text))
        with pytest.raises(Nacked, match="out_of_range"):
            dev._command(MsgType.MODEL_BEGIN, struct_begin(10**9, 0))
    assert eng.generation == 1 and eng.model.name == "face26"


def struct_begin(total, crc):
    return wire.MODEL_HDR.pack(total, crc)


def test_repeated_command_is_answered_but_executed_once(served):
    eng = served.engine
    with Device(served.path) as dev:
        seq = dev.tx_seq
    host = raw_host(served.path)
    try:
        host.write(wire.encode_frame(MsgType.HELLO, seq, wire.encode_hello()))
        assert read_frames(host, 1)[0].type == MsgType.INFO
        frame = wire.encode_frame(MsgType.PARAM_SET, seq + 1, wire.encode_param_set("energy_gain", 0.1))
        host.write(frame)
        first = read_frames(host, 1)
        host.write(frame)                               # the retry of a lost ACK
        second = read_frames(host, 1)
        assert wire.decode_ack(first[0].payload) == wire.decode_ack(second[0].payload) == \
            (seq + 1 & 0xFFFF, MsgType.PARAM_SET, 2)
        assert first[0].seq == second[0].seq            # the cached frame, byte for byte
        assert eng.generation == 2
        assert served.server.counts["rx_retries"] == 1
    finally:
        host.close()


def test_lost_host_frames_are_counted(served):
    host = raw_host(served.path)
    try:
        host.write(wire.encode_frame(MsgType.HELLO, 100, wire.encode_hello()))
        host.write(wire.encode_frame(MsgType.STOP, 101))
        host.write(wire.encode_frame(MsgType.STOP, 105))   # 102..104 lost
        assert len(read_frames(host, 3)) == 3
        assert served.server.counts["rx_lost"] == 3
    finally:
        host.close()


def test_hostile_frames_get_nacks_and_change_nothing(served):
    """Every host message type with random payloads and random unknown types."""
    eng = served.engine
    rng = random.Random(7)
    host = raw_host(served.path)
    try:
        host.write(wire.encode_frame(MsgType.HELLO, 0, wire.encode_hello()))
        read_frames(host, 1)
        before = (eng.generation, eng.get_params(), eng.model.digest(), eng.running)
        n = 0
        for i in range(1, 400):
            mtype = rng.choice([t for t in MsgType if t not in (MsgType.HELLO, MsgType.START,
                                                                 MsgType.RESET)] + [0, 0x7F, 0xFF])
            payload = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40)))
            if mtype in (MsgType.STOP, MsgType.HEARTBEAT, MsgType.STATS):
                payload = payload or b"\x01"             # non-empty: malformed
            if mtype == MsgType.PARAM_GET:
                payload = b"\x01\x04nope"
            host.write(wire.encode_frame(mtype, i, payload))
            n += 1
        replies = read_frames(host, n, timeout=5)
        assert len(replies) == n
        assert [(f.type, f.payload) for f in replies if f.type != MsgType.NACK] == []
        assert (eng.generation, eng.get_params(), eng.model.digest(), eng.running) == before
        assert served.server.counts["handler_errors"] == 0
    finally:
        host.close()
    with Device(served.path) as dev:                    # still alive and answering
        dev.ping()


def test_signed_frame_on_a_keyless_link_is_refused(served):
    eng = served.engine
    host = raw_host(served.path)
    try:
        host.write(wire.encode_frame(MsgType.HELLO, 1, wire.encode_hello()))
        nonce = wire.decode_info(read_frames(host, 1)[0].payload)["nonce"]
        host.write(wire.encode_frame(MsgType.PARAM_SET, 2, wire.encode_param_set("alpha_position", 0.3),
                                     signer=wire.Signer(b"k", nonce)))
        reply = read_frames(host, 1)[0]
        assert reply.type == MsgType.NACK
        assert wire.decode_nack(reply.payload)[2] == wire.Nack.BAD_STATE
        assert eng.generation == 1
    finally:
        host.close()


def test_corrupted_bytes_are_dropped_counted_and_resynced(served):
    host = raw_host(served.path)
    try:
        good = wire.encode_frame(MsgType.HELLO, 1, wire.encode_hello())
        bad = bytearray(wire.encode_frame(MsgType.STOP, 2))
        bad[2] ^= 0x40
        host.write(b"\x13\x37garbage\x00" + bytes(bad) + os.urandom(3000).replace(b"\x00", b"\x01")
                   + b"\x00" + good)
        assert read_frames(host, 1)[0].type == MsgType.INFO
        c = served.server.stats()
        assert c["rx_crc_errors"] + c["rx_cobs_errors"] + c["rx_malformed"] == 2
        assert c["rx_oversize"] == 1
    finally:
        host.close()


def test_version_mismatch_refused_politely(served):
    with pytest.raises(VersionMismatch) as e:
        Device(served.path, version=2)
    assert "firmware=v1" in str(e.value) and "host=v2" in str(e.value)
    assert (e.value.host, e.value.firmware) == (2, 1)
    assert e.value.exit_code != 0


def test_no_answer_names_port_and_wait():
    pty = transport.PtyPort()                           # nobody serves it
    try:
        with pytest.raises(NoAnswer, match=rf"{pty.path}: no answer to HELLO after 2 tries of 0.1 s"):
            Device(pty.path, timeout=0.1, retries=1)
    finally:
        pty.close()


def test_no_such_port():
    with pytest.raises(NoSuchPort, match="/dev/does-not-exist: cannot open"):
        Device("/dev/does-not-exist")


# ---- telemetry -------------------------------------------------------------------------
def test_telemetry_stream_and_applied_generation(served):
    eng = served.engine.run()
    with Device(served.path) as dev:
        dev.start()
        snaps = list(dev.telemetry(count=150))
        gen = dev.set(energy_scale=3.0)
        snaps += list(dev.telemetry(count=150))
        assert dev.link_counters()["lost"] == 0
    t = np.array([s.t_us for s in snaps])
    assert np.all(np.diff(t) == 1000)                   # 1 kHz of event time, none lost
    assert all(s.trackers.shape == (26,) for s in snaps)
    t_applied = dev.applied[gen]
    gens = np.array([s.generation for s in snaps])
    # the snapshot at t covers events before t: the new generation from t_applied + 1 ms on
    assert np.all(gens[t > t_applied] == gen) and np.all(gens[t <= t_applied] == 1)
    assert served.server.counts["tx_dropped"] == 0
    # ENERGIES at 10 Hz of event time: 300 snapshots -> 3 frames (a 4th may have been read
    # ahead with the last snapshots), each for the 40 face26 connections
    assert 3 <= dev.counts["energies"] <= 4
    t_e, kind, energies = dev.energies
    # the kind that feeds the criteria: face26 names none, so the default
    assert kind == ENERGY_KINDS.index(Params().energy_kind)
    assert energies.shape == (40,) and t_e % 1000 == 0
    assert (t_e - t[0]) % 100_000 == 0


def test_hello_discards_snapshots_queued_for_nobody(served):
    eng = served.engine
    for _ in range(100):                                # produced before any host
        eng.step()
    with Device(served.path) as dev:
        for _ in range(5):
            eng.step()
        snaps = list(dev.telemetry(seconds=10, count=5))
        assert [s.t_us for s in snaps] == [101_000, 102_000, 103_000, 104_000, 105_000]
        assert dev.stats()["link.telemetry_stale"] == 100


def test_hello_finishes_the_frame_being_written_instead_of_cutting_it():
    """A host that attaches while a frame is half written must not see a CRC error: on HELLO
    the firmware drops its unwritten frames but completes the one already started."""
    eng = SimEngine()
    port = transport.PtyPort()
    server = link.LinkServer(port, eng)
    host = raw_host(port.path)
    try:
        server.session = True
        beat = b"\x00" + wire.encode_frame(MsgType.HEARTBEAT, 7, wire.encode_heartbeat(
            uptime_us=1, rx_frames=2, rx_errors=0, rx_lost=0, tx_frames=3, tx_dropped=0))
        cut = len(beat) // 2
        port.write(beat[:cut])                 # on the wire: the first half of a frame,
        server.txq += beat[cut:] + beat        # queued: its second half and one more frame
        reader = wire.FrameReader(hunting=True)
        host.write(wire.encode_frame(MsgType.HELLO, 1, wire.encode_hello()))
        got, end = [], time.monotonic() + 5
        while time.monotonic() < end and MsgType.INFO not in [f.type for f in got]:
            server.step()
            got += reader.feed(host.read(max(1, host.in_waiting)))
        assert [f.type for f in got] == [MsgType.HEARTBEAT, MsgType.INFO]
        assert reader.counts["crc_errors"] + reader.counts["cobs_errors"] == 0
        assert server.counts["tx_stale_bytes"] == len(beat)      # the whole frame behind it
    finally:
        host.close()
        port.close()
        eng.close()


def test_telemetry_is_dropped_not_blocking_when_host_is_away():
    """6000 snapshots (1.4 MB) while the host reads nothing: the pty fills, the link keeps
    serving commands, snapshots back up into the engine's bounded queue, which drops the
    oldest and counts them."""
    eng = SimEngine()
    s = Served(eng)
    try:
        host = raw_host(s.path)
        host.write(wire.encode_frame(MsgType.HELLO, 1, wire.encode_hello()))
        host.write(wire.encode_frame(MsgType.START, 2))
        # the session is open: snapshots are for this host, not discarded as stale
        wait_for(lambda: s.server.session and eng.running, what="the session open, running")
        assert s.server.session and eng.running
        for _ in range(6000):
            eng.step()
        host.write(wire.encode_frame(MsgType.HEARTBEAT, 3))
        deadline = time.monotonic() + 30
        r = wire.FrameReader()
        acks = []
        while time.monotonic() < deadline and not acks:
            acks = [f for f in r.feed(host.read(65536)) if f.type == MsgType.ACK
                    and wire.decode_ack(f.payload)[0] == 3]
        assert acks, "the link server blocked instead of dropping telemetry"
        assert eng.counters["telemetry_dropped"] > 0    # backpressure into the engine's queue
        host.close()
    finally:
        s.close()
        eng.close()


# ---- TCP and signing -------------------------------------------------------------------
def test_non_loopback_bind_requires_a_key():
    with pytest.raises(ValueError, match="without a key"):
        transport.TcpServer("0.0.0.0", 0)
    with pytest.raises(ValueError, match="--key-file"):
        transport.TcpServer("0.0.0.0", 0)
    with pytest.raises(ValueError, match="1 bytes is too short: at least 16"):
        transport.TcpServer("0.0.0.0", 0, key=b"x")
    srv = transport.TcpServer("0.0.0.0", 0, key=b"0123456789abcdef")
    srv.close()


def serve_tcp(engine, key=None):
    srv = transport.TcpServer("127.0.0.1", 0, key=key)
    box = {}

    def run():
        port = srv.accept(5)
        box["server"] = link.LinkServer(port, engine, key=key)
        box["server"].serve(box["stop"])
        port.close()
    box["stop"] = threading.Event()
    th = threading.Thread(target=run, daemon=True)
    th.start()
    return srv, th, box


def test_tcp_unsigned_session():
    eng = SimEngine()
    srv, th, box = serve_tcp(eng)
    try:
        with Device(srv.url) as dev:
            assert dev.set(alpha_position=0.1) == 2
        th.join(3)                                      # peer closed -> serve returns
        assert not th.is_alive()
    finally:
        box["stop"].set()
        srv.close()


def test_tcp_signed_session_drops_unsigned_forged_and_replayed_frames():
    key = b"0123456789abcdef0123456789abcdef"
    eng = SimEngine()
    srv, th, box = serve_tcp(eng, key=key)
    try:
        with pytest.raises(Exception, match="requires a key"):
            Device(srv.url)
        th.join(3)
        srv2, th2, box2 = serve_tcp(eng, key=key)
        with Device(srv2.url, key=key) as dev:
            assert dev.info["auth_required"]
            assert dev.set(alpha_position=0.1) == 2
            nonce = dev.info["nonce"]
            # a frame signed earlier, replayed byte for byte
            replay = wire.encode_frame(MsgType.PARAM_SET, 9, wire.encode_param_set("alpha_position", 0.3),
                                       signer=wire.Signer(key, nonce))
            dev.port.write(replay)
            dev.port.write(replay)
            dev.port.write(wire.encode_frame(MsgType.PARAM_SET, 10, wire.encode_param_set("alpha_position", 0.4)))
            dev.port.write(wire.encode_frame(MsgType.PARAM_SET, 11, wire.encode_param_set("alpha_position", 0.5),
                                             signer=wire.Signer(b"wrong key", nonce)))
            dev.ping()         # answered once the four frames before it were handled (one
            c = box2["server"].counts               # link thread, frames in order)
            assert (c["auth_replay"], c["auth_unsigned"], c["auth_bad_tag"]) == (1, 1, 1)
            assert eng.generation == 3                  # only the first copy was executed
            assert dev.set(alpha_position=0.2) == 4     # the session goes on
        box2["stop"].set()
        srv2.close()
    finally:
        box["stop"].set()
        srv.close()
