"""Host sessions over TCP: an operator and read-only monitors at once, takeover, idle and
pending timeouts, nothing but HELLO/INFO before authentication, authentication failures
counted for the device's lifetime, logged, rate-limited; the limits on keys and names.
In-process against the link hub (short timeouts), and with firmware and host as separate
processes where the reproduction involves them."""
from __future__ import annotations

import socket
import subprocess
import time

import pytest

from firmware_sim import link
from firmware_sim.throttle import LOG_EVERY_S
from hostctl import AuthFailed, Device, Nacked, Role
from springtrack import model as _model
from springtrack import wire
from springtrack.wire import MsgType, Nack, Notice

from support.fwproc import Firmware, firmware_cmd, hostctl_cmd
from support.engine import SimEngine
from support.wait import wait_for
from support.link import TcpServed

KEY = b"0123456789abcdef0123456789abcdef"


@pytest.fixture
def served(request):
    s = TcpServed(SimEngine(), **getattr(request, "param", {}))
    yield s
    s.close()


def raw(url):
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    return socket.create_connection((host, int(port)), timeout=5)


def frames_until_closed(sock, timeout=10.0):
    """Every frame the firmware sends until it closes the connection."""
    r = wire.FrameReader()
    got, end = [], time.monotonic() + timeout
    sock.settimeout(0.2)
    while time.monotonic() < end:
        try:
            data = sock.recv(65536)
        except socket.timeout:
            continue
        if not data:
            return got
        got += r.feed(data)
    raise AssertionError(f"the connection was not closed within {timeout} s: {got}")


def notices(frames):
    return [wire.decode_notice(f.payload) for f in frames if f.type == MsgType.NOTICE]


@pytest.mark.parametrize("served", [dict(pending_timeout_s=0.5)], indirect=True)
def test_an_idle_connection_does_not_lock_out_the_real_host_and_is_closed(served):
    idle = raw(served.url)                          # connects, says nothing
    with Device(served.url) as dev:                 # the real host works meanwhile
        assert dev.set(alpha_position=0.05) == 2
        got = frames_until_closed(idle)
        (n,) = notices(got)
        assert n.code == Notice.SESSION_CLOSING and "no authenticated HELLO" in n.text
        assert served.hub.counts["pending_timeouts"] == 1
        dev.ping()
    idle.close()


@pytest.mark.parametrize("served", [dict(idle_timeout_s=1.0)], indirect=True)
def test_idle_timeout_closes_a_silent_session_and_keepalive_keeps_one_open(served):
    served.engine.run()
    with Device(served.url, keepalive_s=0.3) as dev:
        dev.start()
        silent = raw(served.url)
        silent.sendall(wire.encode_frame(MsgType.HELLO, 1,
                                         wire.encode_hello("silent", role=Role.MONITOR)))
        list(dev.telemetry(seconds=2.5))            # pings every 0.3 s while it waits
        got = frames_until_closed(silent)
        assert MsgType.TELEMETRY in [f.type for f in got]      # it was a session
        assert "idle for 1 s" in notices(got)[-1].text
        assert served.hub.counts["idle_timeouts"] == 1
        dev.ping()                                  # the pinging one is still open
        assert dev.counts["keepalives"] >= 3
    silent.close()


def test_an_operator_and_monitors_at_once_and_the_takeover_rule(served):
    served.engine.run()
    with Device(served.url, name="op1") as op1, \
            Device(served.url, name="mon", role=Role.MONITOR) as mon:
        assert mon.info["role"] == "monitor" and op1.info["role"] == "operator"
        op1.start()
        assert op1.set(energy_gain=0.06) == 2
        assert len(list(mon.telemetry(seconds=10, count=20))) == 20      # both receive
        assert len(list(op1.telemetry(seconds=10, count=20))) == 20
        with pytest.raises(Nacked, match="forbidden.*monitor") as e:
            mon.set(energy_gain=0.5)
        assert e.value.code == Nack.FORBIDDEN
        assert mon.get("energy_gain") == {"energy_gain": 0.06} and mon.stats()["session.role"] == "monitor"
        with Device(served.url, name="op2") as op2:     # a new operator takes over
            assert op2.set(energy_gain=0.07) == 3
            with pytest.raises(Nacked, match="forbidden"):
                op1.set(energy_gain=0.5)
            assert op1.role == Role.MONITOR
            assert [n.code for n in op1.notices] == [Notice.ROLE_CHANGED]
            st = op2.stats()
            assert st["link.operator_takeovers"] == 1 and st["session.operator"] is True
            assert st["link.sessions"] == 3 and st["link.forbidden"] == 2
        list(op1.telemetry(seconds=10, count=5))        # a monitor still receives


def test_a_keyed_link_reveals_nothing_but_info_before_authentication():
    s = TcpServed(SimEngine(), key=KEY)
    try:
        s.engine.run()
        s.engine.start()
        sock = raw(s.url)
        sock.sendall(wire.encode_frame(MsgType.HELLO, 1, wire.encode_hello()))
        sock.sendall(wire.encode_frame(MsgType.STATS, 2))          # unsigned: dropped
        r = wire.FrameReader()
        got, end = [], time.monotonic() + 1.5
        sock.settimeout(0.1)
        while time.monotonic() < end:
            try:
                got += r.feed(sock.recv(65536))
            except socket.timeout:
                pass
        assert [f.type for f in got] == [MsgType.INFO]             # no telemetry, no beat
        info = wire.decode_info(got[0].payload)
        assert info["auth_required"]
        signer = wire.Signer(KEY, info["nonce"])
        sock.sendall(wire.encode_frame(MsgType.HEARTBEAT, 3, signer=signer))
        got, end = [], time.monotonic() + 10
        while time.monotonic() < end and MsgType.TELEMETRY not in [f.type for f in got]:
            try:
                got += r.feed(sock.recv(65536))
            except socket.timeout:
                pass
        assert got[0].type == MsgType.ACK and MsgType.TELEMETRY in [f.type for f in got]
        sock.close()
        assert s.hub.counts["auth_unsigned"] == 1
    finally:
        s.close()


def test_auth_failures_are_counted_for_the_lifetime_logged_with_the_peer_and_limited():
    s = TcpServed(SimEngine(), key=KEY)
    try:
        t0 = time.monotonic()
        with pytest.raises(AuthFailed, match="key is most likely wrong"):
            Device(s.url, key=b"a wrong key of enough bytes!", timeout=0.2, retries=3)
        with Device(s.url, key=KEY) as dev:             # a new connection: still counted
            st = dev.stats()
            assert st["link.auth_bad_tag"] == 4 and st["session.auth_bad_tag"] == 0
        auth = [line for line in s.lines if "authentication failure" in line]
        assert auth and all("127.0.0.1" in line and "bad_tag" in line for line in auth)
        assert len(auth) <= 1 + (time.monotonic() - t0) / LOG_EVERY_S   # rate-limited
        # MAX_AUTH_FAILURES bad frames on one connection: closed, the address locked out
        sock = raw(s.url)
        sock.sendall(wire.encode_frame(MsgType.HELLO, 1, wire.encode_hello()))
        bad = wire.Signer(b"not the key, sixteen bytes long", b"12345678")
        for k in range(link.MAX_AUTH_FAILURES):
            sock.sendall(wire.encode_frame(MsgType.STATS, 2 + k, signer=bad))
        got = frames_until_closed(sock)
        assert f"{link.MAX_AUTH_FAILURES} authentication failures" in notices(got)[-1].text
        assert s.hub.counts["auth_disconnects"] == 1
        # locked out: a connection is on probation, closed at its first failed
        # authentication; the operator, with the key, on the same address gets in
        with pytest.raises(AuthFailed, match="key"):
            Device(s.url, key=b"a wrong key of enough bytes!", timeout=0.5, retries=3)
        assert s.hub.counts["auth_disconnects"] == 2 and s.hub.counts["auth_lockouts"] == 1
        with Device(s.url, key=KEY) as dev:
            assert s.hub.counts["auth_lockouts"] == 2
            assert dev.stats()["link.auth_bad_tag"] == 4 + link.MAX_AUTH_FAILURES + 1
    finally:
        s.close()


@pytest.mark.parametrize("served", [dict(max_sessions=2)], indirect=True)
def test_sessions_are_bounded_an_operator_always_gets_in(served):
    """At most ``max_sessions`` sessions with a role: another monitor is refused (told why),
    an operator gets in and the monitor idle longest makes room; connections without a
    session are bounded too (twice as many), the oldest evicted first."""
    hub = served.hub
    with Device(served.url, name="a") as a, Device(served.url, name="b", role=Role.MONITOR) as b:
        with pytest.raises(Nacked, match="all 2 sessions are in use") as e:
            Device(served.url, role=Role.MONITOR)
        assert e.value.code == Nack.FORBIDDEN and hub.counts["sessions_refused"] == 1
        b.ping()                                        # b was active last: a goes
        with Device(served.url, name="d") as d:         # an operator gets in
            assert hub.counts["sessions_evicted"] == 1 and hub.counts["operator_takeovers"] == 1
            got = frames_until_closed(a.port._socket)
            assert "evicted: an operator needed a session" in notices(got)[-1].text
            d.set(energy_gain=0.05)
            b.ping()
            pending = [raw(served.url) for _ in range(3)]       # 2 sessions + 2 waiting = 4
            wait_for(lambda: hub.counts["pending_timeouts"] >= 1, timeout=10,
                     what="a pending timeout", interval=0.02)
            assert hub.counts["pending_timeouts"] == 1          # the oldest waiting one went
            assert frames_until_closed(pending[0]) == []
            for p in pending:
                p.close()


@pytest.mark.hil
def test_short_keys_are_refused_everywhere(tmp_path):
    with pytest.raises(ValueError, match="at least 16 bytes"):
        link.Hub(SimEngine(), key=b"x")
    with pytest.raises(ValueError, match="at least 16 bytes"):
        Device("loop://", key=b"short")
    k = tmp_path / "one.key"
    k.write_bytes(b"x\n")
    r = subprocess.run(firmware_cmd("--source", "sim:face_occlusion", "--listen", "0.0.0.0:0",
                                    "--key-file", str(k)), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and "listen:" not in r.stdout
    assert f"--key-file {k}: a link key of 1 bytes is too short: at least 16 bytes" in r.stderr
    r = subprocess.run(hostctl_cmd("--port", "socket://127.0.0.1:9", "--key-file", str(k), "info"),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "at least 16 bytes" in r.stderr


# ---- firmware and host as separate processes ----------------------------------------------
@pytest.mark.hil
def test_hil_a_long_model_name_is_refused_and_hello_keeps_working(tmp_path):
    """The reproduction: a 1200-character model name on a keyed link.  The upload gets NACK
    too_long; INFO stays within a frame and every later HELLO is answered."""
    key = tmp_path / "link.key"
    key.write_bytes(KEY)
    m = _model.grid3x3()
    m.name = "n" * 1200
    path = tmp_path / "long.toml"
    path.write_text(m.to_toml())
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", "60",
                  "--listen", "127.0.0.1:0", "--key-file", str(key))
    try:
        r = subprocess.run(hostctl_cmd("--port", fw.path, "--key-file", str(key), "load-model",
                                       str(path)), capture_output=True, text=True, timeout=120)
        assert r.returncode == 6 and "too_long" in r.stderr and "at most 512" in r.stderr
        for _ in range(2):
            with Device(fw.path, key=KEY) as dev:
                assert dev.info["model"] == "face26"
                with pytest.raises(Nacked) as e:
                    dev.load_model(m)
                assert e.value.code == Nack.TOO_LONG
    finally:
        fw.close()
    r = subprocess.run(firmware_cmd("--source", "sim:face_occlusion", "--model", str(path)),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "name of 1200 characters takes 1200 bytes in INFO" in r.stderr


@pytest.mark.hil
def test_hil_wrong_key_and_an_idle_squatter(tmp_path):
    """hostctl with a wrong key exits 7 with a hint; the firmware logs the failures with the
    peer's address; an idle connection does not keep the real host out."""
    key, wrong = tmp_path / "link.key", tmp_path / "wrong.key"
    key.write_bytes(KEY)
    wrong.write_bytes(b"f" * 32)
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", "60",
                  "--listen", "127.0.0.1:0", "--key-file", str(key))
    try:
        squatter = raw(fw.path)
        r = subprocess.run(hostctl_cmd("--port", fw.path, "--key-file", str(wrong), "--timeout",
                                       "0.3", "info"), capture_output=True, text=True, timeout=120)
        assert r.returncode == 7, r.stderr
        assert "the key is most likely wrong" in r.stderr
        r = subprocess.run(hostctl_cmd("--port", fw.path, "--key-file", str(key), "stats"),
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert "link.auth_bad_tag: 4" in r.stdout and "state: streaming" in r.stdout
        squatter.close()
    finally:
        fw.close()
    assert "link: authentication failure (bad_tag) from tcp 127.0.0.1:" in fw.err
