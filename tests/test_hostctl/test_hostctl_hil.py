"""Hardware-in-the-loop: ``firmware-sim run ... --pty`` as a separate process on the simulated
camera, driven by hostctl (API and CLI) - model upload, parameter change seen in telemetry
at the reported event time, recording compared with ``springtrack track`` on the same
scene, and a byte-mangling pty proxy showing frames dropped, counted and resynchronised."""
import os
import random
import re
import select
import subprocess
import threading
import time

import numpy as np
import pytest
import serial

from firmware_sim import transport
from springtrack.sim.sensor import simulate_all
from hostctl import Device, HostctlError
from hostctl.record import save
from springtrack import cli as st_cli
from springtrack import wire
from springtrack.track import read_csv

from support.fwproc import Firmware, hostctl_cmd
from support.fwproc import SCENE_S, collect_until
from support.wait import wait_for


@pytest.fixture
def realtime_fw():
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", SCENE_S, "--pty")
    yield fw
    fw.close()


@pytest.mark.hil
def test_hil_model_upload_and_param_change_seen_at_reported_time(realtime_fw):
    with Device(realtime_fw.path) as dev:
        assert dev.info["model"] == "face26" and dev.info["protocol_version"] == 1
        g_model = dev.load_model("grid3x3")
        snaps = collect_until(dev, lambda s: g_model in dev.applied and any(
            x.t_us > dev.applied[g_model] + 2000 for x in s))
        ta = dev.applied[g_model]
        after = [s for s in snaps if s.t_us > ta]
        assert after and all(s.generation == g_model and len(s.trackers) == 9 for s in after)
        assert all(s.t_us <= ta for s in snaps if s.generation < g_model)
        assert dev.hello()["model"] == "grid3x3"

        dev.load_model("face26")
        g = dev.set(energy_scale=3.25)
        snaps = collect_until(dev, lambda s: g in dev.applied and any(
            x.t_us > dev.applied[g] + 2000 for x in s))
        tg = dev.applied[g]
        assert all(s.generation == g for s in snaps if s.t_us > tg)
        assert all(s.t_us <= tg for s in snaps if s.generation < g)
        assert dev.get("energy_scale") == {"energy_scale": 3.25}
        g = dev.set(pull_frame="image", cartesian_frame="image")   # string values
        collect_until(dev, lambda s: g in dev.applied and any(x.t_us > dev.applied[g]
                                                              for x in s))
        assert dev.get("pull_frame", "cartesian_frame") == {"pull_frame": "image",
                                                            "cartesian_frame": "image"}
        assert dev.link_counters()["crc_errors"] == 0


@pytest.mark.slow
@pytest.mark.hil
def test_hil_record_matches_springtrack_track(tmp_path):
    """``--port URL --wait-start``: the test opens the pty, connects and sends START; the
    firmware streams 1.5 s of the scene --max-speed, says the stream ended (a NOTICE) and
    keeps serving until the host sends SHUTDOWN; the host records every snapshot and
    compares the recording with ``springtrack track`` on the same events."""
    pty = transport.PtyPort()
    try:
        fw = Firmware("--source", "sim:face_occlusion", "--max-speed", "--seconds", "1.5",
                      "--port", pty.path, "--wait-start", announce=False)
        try:
            snaps = []
            # pyserial flushes the port when the firmware opens it: knock every 50 ms until
            # the link answers; --wait-start holds the tracking loop until START
            with Device(pty, timeout=0.05, retries=400) as dev:
                dev.timeout = 0.5
                info = dev.info
                dev.start()
                while True:
                    got = list(dev.telemetry(seconds=0.3))
                    snaps += got
                    if dev.stream_ended and not got:
                        break
                lost = dev.link_counters()["lost"]
                assert dev.stats()["state"] == "ended" and fw.proc.poll() is None
                dev.shutdown()
            fw.proc.wait(60)
        finally:
            fw.close()
    finally:
        pty.close()
    assert fw.proc.returncode == 0
    rec_path = tmp_path / "rec.csv"
    save(rec_path, snaps, info)
    ev, _ = simulate_all("face_occlusion", 1.5, seed=0)
    np.save(tmp_path / "ev.npy", ev)
    ref_path = tmp_path / "ref.csv"
    assert st_cli.main(["track", str(tmp_path / "ev.npy"), "--model", "face26", "--out",
                        str(ref_path), "--no-progress"]) == 0
    rec, ref = read_csv(rec_path), read_csv(ref_path)
    assert rec.ids == ref.ids
    assert len(rec) == 1499 and lost == 0           # every snapshot of the 1.5 s scene
    assert rec.t_us[-1] == 1_499_000 and np.all(np.diff(rec.t_us) == 1000)
    idx = np.searchsorted(ref.t_us, rec.t_us)
    assert np.all(idx < len(ref)) and np.array_equal(ref.t_us[idx], rec.t_us)
    assert np.max(np.abs(ref.x[idx] - rec.x)) <= 1 / 32 + 1e-6
    assert np.max(np.abs(ref.y[idx] - rec.y)) <= 1 / 32 + 1e-6
    assert np.array_equal(ref.active[idx], rec.active)
    assert np.array_equal(ref.sensitive[idx], rec.sensitive)
    act = np.abs(np.log2((1 + rec.activity) / (1 + ref.activity[idx])))
    assert np.max(act) <= 1 / 32 + 1e-3


class ManglingProxy:
    """Forwards bytes between the firmware's pty and a new pty for the host, flipping one
    bit every ``down_every`` bytes firmware->host and every ``up_every`` bytes host->firmware."""

    def __init__(self, fw_path, down_every=4001, up_every=1999, seed=5):
        self.fw = serial.serial_for_url(fw_path, timeout=0)
        self.host = transport.PtyPort()
        self.path = self.host.path
        self.rng = random.Random(seed)
        self.every = {"down": down_every, "up": up_every}
        self.count = {"down": 0, "up": 0}
        self.flipped = {"down": 0, "up": 0}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def mangle(self, data: bytes, way: str) -> bytes:
        b = bytearray(data)
        n, every = self.count[way], self.every[way]
        for i in range(len(b)):
            if (n + i) % every == every - 1:
                b[i] ^= 1 << self.rng.randrange(8)
                self.flipped[way] += 1
        self.count[way] = n + len(b)
        return bytes(b)

    def run(self):
        fw_fd, host_fd = self.fw.fileno(), self.host.fileno()
        while not self.stop.is_set():
            r, _, _ = select.select([fw_fd, host_fd], [], [], 0.05)
            if fw_fd in r:
                try:
                    data = os.read(fw_fd, 65536)
                except OSError:
                    return
                _write_all(host_fd, self.mangle(data, "down"))
            if host_fd in r:
                try:
                    data = os.read(host_fd, 65536)
                except (OSError, BlockingIOError):
                    continue
                _write_all(fw_fd, self.mangle(data, "up"))

    def close(self):
        self.stop.set()
        self.thread.join(2)
        self.fw.close()
        self.host.close()


def _write_all(fd, data):
    while data:
        try:
            n = os.write(fd, data)
        except BlockingIOError:
            select.select([], [fd], [], 0.05)
            continue
        data = data[n:]


@pytest.mark.hil
def test_hil_corrupted_link_drops_counts_and_resyncs(realtime_fw):
    proxy = ManglingProxy(realtime_fw.path)
    try:
        with Device(proxy.path, timeout=0.25, retries=10) as dev:
            g_model = dev.load_model("face26")           # 6 chunks, some of them mangled
            g = dev.set(energy_gain=0.07)                # survives corruption by retrying
            assert g == g_model + 1
            snaps = list(dev.telemetry(seconds=1.5))
            lc = dev.link_counters()
            fw = dev.stats()
    finally:
        proxy.close()
    assert proxy.flipped["down"] > 10 and proxy.flipped["up"] > 0, (proxy.count, proxy.flipped, len(snaps), lc)
    errors = lc["crc_errors"] + lc["cobs_errors"] + lc["malformed"]
    assert errors > 0 and lc["lost"] > 0                 # dropped and counted on the host
    assert len(snaps) > 500                              # ... and the stream resynchronised
    t = np.array([s.t_us for s in snaps])
    assert np.all(np.diff(t) > 0)
    assert all(s.trackers.shape == (26,) and np.all(s.trackers["x"] < 304) for s in snaps)
    fw_errors = fw["link.rx_crc_errors"] + fw["link.rx_cobs_errors"] + fw["link.rx_malformed"]
    assert fw_errors > 0 and lc["retries"] > 0           # counted on the firmware side too
    assert fw["link.handler_errors"] == 0


@pytest.mark.slow
@pytest.mark.hil
def test_hil_monitor_cli(realtime_fw):
    with Device(realtime_fw.path) as dev:           # the firmware is streaming (slow start
        collect_until(dev, lambda s: len(s) > 0, timeout=30)    # on a loaded machine)
    out = subprocess.run(hostctl_cmd("--port", realtime_fw.path, "monitor", "--seconds", "1.2",
                                     "--smooth"), capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    frames = out.stdout.split("\x1b[H\x1b[2J")[1:]
    assert len(frames) >= 2                          # redraw rate: benchmarks/link.py
    last = frames[-1]
    assert "model face26" in last and "mouth" in last and "outline18" in last
    head = last.splitlines()[1]
    assert "lost frames " in head and "link errors 0" in head and "events " in head, head
    assert last.splitlines()[2].startswith("state streaming   faults 0"), last


@pytest.mark.hil
def test_hil_tcp_listener_with_key(tmp_path):
    """firmware-sim --listen with a key: hostctl with the key works, without it is refused,
    and unsigned frames are dropped and counted by the firmware."""
    key = tmp_path / "link.key"
    key.write_text("0123456789abcdef0123456789abcdef\n")
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", SCENE_S,
                  "--listen", "127.0.0.1:0", "--key-file", str(key))
    try:
        url = fw.path
        with pytest.raises(HostctlError, match="requires a key"):
            Device(url)
        with Device(url, key=key.read_bytes().strip()) as dev:
            assert dev.info["auth_required"]
            g = dev.set(energy_gain=0.06)
            collect_until(dev, lambda s: g in dev.applied, timeout=30)
            dev.port.write(wire.encode_frame(wire.MsgType.PARAM_SET, 999,
                                             wire.encode_param_set("energy_gain", 0.5)))
            assert dev.get("energy_gain") == {"energy_gain": 0.06}
            assert dev.stats()["link.auth_unsigned"] == 1
    finally:
        fw.close()


@pytest.mark.hil
def test_hil_tcp_1khz_telemetry_with_commands():
    """``--listen`` at the default 1 kHz telemetry: over 3 s of wall time the host keeps up
    with the stream while it sends commands (socket:// ports are read in whole pieces, not
    one byte per call): no command retried, >= 800 snapshots/s, every snapshot of the
    window received (consecutive event times), no link error, nothing dropped on the
    firmware side."""
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", SCENE_S, "--listen", "127.0.0.1:0")
    try:
        with Device(fw.path) as dev:                     # default 0.5 s per try
            collect_until(dev, lambda s: len(s) > 0, timeout=30)    # streaming (slow start
            before = dev.stats()                                    # on a loaded machine)
            snaps, rtts, gens = [], [], []
            t0 = time.monotonic()
            while time.monotonic() - t0 < 3.0:
                snaps += dev.telemetry(seconds=0.1)
                rtts.append(dev.ping())
                gens.append(dev.set(energy_gain=0.05 + 0.001 * len(gens)))
                assert "energy_gain" in dev.get("energy_gain")   # applied later, in the loop
            snaps += dev.telemetry(seconds=0.0)          # what is already queued
            elapsed = time.monotonic() - t0
            after = dev.stats()
            lc = dev.link_counters()
            collect_until(dev, lambda s: gens[-1] in dev.applied, timeout=30)
            assert dev.get("energy_gain") == {"energy_gain": 0.05 + 0.001 * (len(gens) - 1)}
    finally:
        fw.close()
    rate = len(snaps) / elapsed
    info = (f"{len(snaps)} snapshots in {elapsed:.2f} s ({rate:.0f}/s), {len(rtts)} pings, "
            f"max rtt {max(rtts) * 1e3:.1f} ms, {lc}")
    assert elapsed >= 3.0 and len(rtts) >= 10, info
    assert lc["retries"] == 0, info                      # no command timed out
    assert rate >= 800, info
    assert lc["crc_errors"] + lc["cobs_errors"] + lc["malformed"] + lc["oversize"] == 0, info
    assert lc["lost"] == 0 and lc["telemetry_overflow"] == 0, info
    t = np.array([s.t_us for s in snaps])
    assert np.all(np.diff(t) == 1000), info              # not one snapshot missing
    assert gens == sorted(gens) and len(set(gens)) == len(gens)
    for k in ("loop.telemetry_dropped", "link.tx_dropped", "link.rx_crc_errors",
              "link.rx_cobs_errors", "link.rx_malformed", "link.rx_lost", "link.handler_errors"):
        assert after[k] == before[k], (k, before[k], after[k], info)


@pytest.mark.slow
@pytest.mark.hil
def test_hil_record_without_telemetry_says_why(tmp_path):
    """A recording that receives nothing names the device's state and the way out: not
    started yet (``--wait-start``), then, once started, its short source run out."""
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", "0.3", "--pty",
                  "--wait-start")
    try:
        def record():
            return subprocess.run(hostctl_cmd("--port", fw.path, "record",
                                              str(tmp_path / "r.csv"), "--seconds", "0.5"),
                                  capture_output=True, text=True, timeout=60)
        out = record()
        assert out.returncode != 0 and "Traceback" not in out.stderr
        assert "no telemetry received in 0.5 s: the device is not started (hostctl start)" \
            in out.stderr, out.stderr
        with Device(fw.path) as dev:
            dev.start()
            wait_for(lambda: dev.stats().get("state") == "ended", what="the 0.3 s source's end",
                     interval=0.1)
        out = record()
        assert out.returncode != 0 and "Traceback" not in out.stderr
        assert "the device's source has ended (`hostctl record --start` replays it" \
            in out.stderr, out.stderr
        assert not (tmp_path / "r.csv").exists()
        # the way out it names: the whole 0.3 s replay, from its first sample to its last
        out = subprocess.run(hostctl_cmd("--port", fw.path, "record", str(tmp_path / "r.csv"),
                                         "--start", "--seconds", "30"),
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        t = np.unique(read_csv(tmp_path / "r.csv").t_us)
        # (a replay goes on from the camera clock's last time)
        assert t[-1] - t[0] >= 299_000 and np.all(np.diff(t) == 1000), t
    finally:
        fw.close()


@pytest.mark.slow
@pytest.mark.hil
def test_hil_record_under_overload_reports_every_missing_snapshot(tmp_path):
    """The firmware at --max-speed makes a snapshot every 200 µs of event time far faster
    than the pty carries them: its telemetry queue drops the oldest.  ``hostctl record``
    warns with the device's drops over the recorded span, and the rows it wrote plus the
    snapshots it names as lost cover every sample time of that span."""
    period = 200
    fw = Firmware("--source", "sim:face_occlusion", "--max-speed", "--seconds", "2",
                  "--telemetry-us", str(period), "--pty", "--wait-start")
    try:
        out = subprocess.run(hostctl_cmd("--port", fw.path, "record", str(tmp_path / "r.csv"),
                                         "--start", "--seconds", "60"),
                             capture_output=True, text=True, timeout=120)
    finally:
        fw.close()
    assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr
    m = re.search(r"lost device queue (\d+), device send queue (\d+), link (\d+), "
                  r"CRC errors \d+, host (\d+)", out.stdout + out.stderr)
    assert m, out.stdout + out.stderr
    lost = sum(int(x) for x in m.groups())
    # a machine fast enough to carry every snapshot drops none: then no warning, and the
    # rows alone must cover the span (below)
    assert ("warning: the recording is incomplete" in out.stderr) == (lost > 0), out.stderr
    t = np.unique(read_csv(tmp_path / "r.csv").t_us)
    assert np.all(np.diff(t) % period == 0)
    # nothing missing unreported within the span (drops of the oldest may also fall before
    # its first row), and no more reported than the 2 s scene's sample times
    assert (t[-1] - t[0]) // period + 1 <= len(t) + lost <= 2_000_000 // period, \
        (len(t), lost, t[0], t[-1])
