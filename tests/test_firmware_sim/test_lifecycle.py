"""Clean lifecycles, with the firmware as a real process: a source that cannot be read ends
the program at once with one clear line; with a host link the program outlives its source
(idle, STATS, START replays) until SHUTDOWN or a signal; SIGTERM and Ctrl-C stop every
thread and still print the statistics."""
from __future__ import annotations

import signal
import struct
import subprocess
import zlib

import numpy as np
import pytest

from hostctl import Device
from springtrack.sim.sensor import simulate_all
from springtrack.wire import Notice

from support.fwproc import Firmware, firmware_cmd, hostctl_cmd
from support.wait import wait_for


def png(path):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 0, 0, 0, 0))
                     + chunk(b"IEND", b""))
    return path


@pytest.fixture(scope="module")
def bad_sources(tmp_path_factory):
    d = tmp_path_factory.mktemp("sources")
    (d / "empty.raw").write_bytes(b"")
    (d / "garbage.dat").write_bytes(bytes(range(256)) * 4)
    (d / "short.npy").write_bytes(b"\x93NUMPY\x01\x00")
    return {"missing file": f"replay:{d / 'missing.raw'}",
            "a directory": f"replay:{d}",
            "a PNG": f"replay:{png(d / 'picture.png')}",
            "an empty file": f"replay:{d / 'empty.raw'}",
            "garbage": f"replay:{d / 'garbage.dat'}",
            "a truncated .npy": f"replay:{d / 'short.npy'}",
            "no file named": "replay:",
            "an unknown scene": "sim:nope",
            "an unknown scheme": "camera:0"}


@pytest.mark.hil
@pytest.mark.parametrize("kind", ["missing file", "a directory", "a PNG", "an empty file",
                                  "garbage", "a truncated .npy", "no file named",
                                  "an unknown scene", "an unknown scheme"])
@pytest.mark.parametrize("link", [[], ["--listen", "127.0.0.1:0"]])
def test_a_source_that_cannot_be_read_ends_the_program_with_one_clear_line(bad_sources, kind, link):
    r = subprocess.run(firmware_cmd("--source", bad_sources[kind], *link), capture_output=True,
                       text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith("firmware-sim run: error: ") and "Traceback" not in r.stderr
    assert r.stdout == ""                          # no link announced, no statistics


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    ev, _ = simulate_all("face_occlusion", 0.3, seed=2)
    path = tmp_path_factory.mktemp("rec") / "rec.npy"
    np.save(path, ev)
    return path, len(ev)


@pytest.mark.hil
def test_after_the_replay_the_firmware_serves_the_link_and_start_replays(recording):
    path, n = recording
    fw = Firmware("--source", f"replay:{path}", "--max-speed", "--listen", "127.0.0.1:0")
    try:
        with Device(fw.path) as dev:
            # the replay ran before we came
            wait_for(lambda: fw.proc.poll() is not None or dev.stats()["state"] == "ended",
                     timeout=60, what="the source ended", interval=0.05)
            assert fw.proc.poll() is None
            st = dev.stats()
            assert st["events_tracked"] == n and st["state"] == "ended"
            dev.start()                                  # replays it from the start
            snaps = []

            def replayed():
                snaps.extend(dev.telemetry(seconds=0.1))
                got = dev.stats()
                return got if got["state"] == "ended" and got["events_tracked"] == 2 * n else None
            st = wait_for(replayed, timeout=60, what="the replay's end", interval=0)
            snaps += dev.telemetry(seconds=0.5)
            assert st["anomalies.tracker_back_in_time"] == 0
            assert dev.notices and {x.code for x in dev.notices} == {Notice.STREAM_ENDED}
            t = np.array([s.t_us for s in snaps])
            assert len(t) > 250 and np.all(np.diff(t) == 1000)  # time goes on, never back
            dev.shutdown()
        assert fw.wait(60) == 0
    finally:
        fw.close()
    assert fw.out.startswith("stats: ") and "tracked=%d" % (2 * n) in fw.out
    assert "shutdown: threads stopped in" in fw.err and "Traceback" not in fw.err


@pytest.mark.hil
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_every_thread_and_prints_the_statistics(sig):
    """With a streaming camera and a host connected: the host is told (NOTICE shutting_down),
    the program exits 0 having joined its threads, and says how long that took."""
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", "60", "--listen", "127.0.0.1:0")
    try:
        with Device(fw.path) as dev:
            wait_for(lambda: dev.stats()["events_tracked"] > 0, timeout=60,
                     what="events tracked", interval=0.05)
            fw.proc.send_signal(sig)
            assert fw.wait(60) == 0
            try:
                dev.poll(0.5)
            except Exception:                            # noqa: BLE001 - the link is gone
                pass
            assert Notice.SHUTTING_DOWN in [x.code for x in dev.notices]
    finally:
        fw.close()
    assert "interrupted" in fw.err and "shutdown: threads stopped in" in fw.err, fw.err
    assert "did not stop" not in fw.err, fw.err       # every thread joined (1 s allowed each)
    assert "Traceback" not in fw.err and fw.out.startswith("stats: ")


@pytest.mark.hil
def test_hostctl_shutdown_ends_a_pty_firmware():
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", "60", "--pty")
    try:
        r = subprocess.run(hostctl_cmd("--port", fw.path, "shutdown"), capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 0 and "shutdown: ok" in r.stdout, r.stderr
        assert fw.wait(60) == 0
    finally:
        fw.close()
    assert fw.out.startswith("stats: ")
