"""DV network streams and cameras (springtrack.live.dv) with the real dv-processing: a
NetworkWriter in another process replays the AEDAT 4 sample over loopback TCP."""
from __future__ import annotations

import re
import subprocess
import sys
import time

import dv_processing as dv
import pytest

from support.live_senders import free_port
from support import REPO

SENDER = str(REPO / "tests" / "support" / "live_senders.py")
TRACK = [sys.executable, "-m", "springtrack.cli", "track"]
MODEL = ["--model", "grid3x3", "--sensor-from", "file", "--no-progress"]
COUNTS = re.compile(r"stream dv://\S+: events=(\d+) batches=(\d+) gaps=(\d+) .* ended: (.+)")


def start_sender(path, *extra) -> tuple[subprocess.Popen, str]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, SENDER, "dv", str(port), str(path), *extra],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "listening"
    return proc, f"dv://127.0.0.1:{port}"


def batch_sizes(path) -> list[int]:
    rec = dv.io.MonoCameraRecording(str(path))
    out = []
    while rec.isRunning():
        b = rec.getNextEventBatch()
        if b is not None:
            out.append(len(b))
    return out


def test_track_of_a_dv_stream_equals_the_files(data_file, tmp_path):
    path = data_file("sample.aedat4")
    ref = subprocess.run(TRACK + [str(path), "--out", str(tmp_path / "file.csv")] + MODEL,
                         capture_output=True, text=True, check=True)
    sender, url = start_sender(path)
    live = subprocess.run(TRACK + [url, "--out", str(tmp_path / "live.csv")] + MODEL,
                          capture_output=True, text=True, timeout=120)
    sender.wait(timeout=30)
    assert live.returncode == 0, live.stderr
    assert (tmp_path / "live.csv").read_bytes() == (tmp_path / "file.csv").read_bytes()
    assert ref.stdout.split()[:3] == live.stdout.split()[:3]       # events, assigned, skipped
    events, batches, gaps, ended = COUNTS.search(live.stderr).groups()
    sizes = batch_sizes(path)
    assert (int(events), int(batches), int(gaps)) == (111_954, len(sizes), 0)
    assert "closed the stream" in ended


def test_a_stream_cut_mid_way_ends_cleanly_with_its_counts(data_file, tmp_path):
    """The sender stops after 50,000 events and goes: the track ends with what came (the
    file's track up to there, row for row) and says how much that was."""
    path = data_file("sample.aedat4")
    subprocess.run(TRACK + [str(path), "--out", str(tmp_path / "file.csv")] + MODEL,
                   capture_output=True, check=True)
    sender, url = start_sender(path, "--cut", "50000")
    live = subprocess.run(TRACK + [url, "--out", str(tmp_path / "cut.csv")] + MODEL,
                          capture_output=True, text=True, timeout=120)
    sender.wait(timeout=30)
    assert live.returncode == 0, live.stderr
    sizes = batch_sizes(path)
    k = next(i for i in range(len(sizes)) if sum(sizes[:i + 1]) >= 50_000) + 1
    events, batches, _, _ = COUNTS.search(live.stderr).groups()
    assert (int(events), int(batches)) == (sum(sizes[:k]), k)
    assert f"events={sum(sizes[:k])} " in live.stdout
    cut = (tmp_path / "cut.csv").read_text().splitlines()
    full = (tmp_path / "file.csv").read_text().splitlines()
    assert 1 < len(cut) < len(full) and cut == full[:len(cut)]


def test_a_dropped_connection_ends_the_stream_cleanly(data_file, tmp_path):
    """The sender process is killed mid-stream (no orderly close): the reader ends with
    its counts, and the program exits 0 with the track of what arrived."""
    path = data_file("sample.aedat4")
    sender, url = start_sender(path, "--cut", "30000", "--linger", "60")
    live = subprocess.Popen(TRACK + [url, "--out", str(tmp_path / "drop.csv")] + MODEL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert sender.stdout.readline().startswith("sent")
    time.sleep(0.5)
    sender.kill()
    sender.wait()
    out, err = live.communicate(timeout=60)
    assert live.returncode == 0, err
    events, batches, _, ended = COUNTS.search(err).groups()
    assert int(events) >= 30_000 and int(batches) >= 1
    assert f"events={events} " in out


def test_firmware_sim_tracks_a_dv_stream_as_springtrack_tracks_the_file(data_file, tmp_path):
    """Through the near-sensor loop (re-encoded as EVT 2.0 words, the fused decode and
    track): the record equals springtrack track's CSV, its times re-based by whole seconds."""
    path = data_file("sample.aedat4")
    subprocess.run(TRACK + [str(path), "--out", str(tmp_path / "file.csv")] + MODEL,
                   capture_output=True, check=True)
    sender, url = start_sender(path)
    fw = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source", url,
                         "--model", "grid3x3", "--sensor-from", "source", "--max-speed",
                         "--record", str(tmp_path / "fw.csv"), "--stats-every", "0"],
                        capture_output=True, text=True, timeout=120)
    sender.wait(timeout=30)
    assert fw.returncode == 0, fw.stderr
    both = fw.stdout + fw.stderr
    offset = int(re.search(r"re-based by -(\d+) us", both).group(1))
    assert offset % 1_000_000 == 0 and offset > 0
    assert "events=111954 " in both
    head, *rows = (tmp_path / "fw.csv").read_text().splitlines()
    shifted = [head] + [f"{int(r.split(',', 1)[0]) + offset},{r.split(',', 1)[1]}" for r in rows]
    assert shifted == (tmp_path / "file.csv").read_text().splitlines()


@pytest.mark.parametrize("url, says", [
    ("dv:camera", "no iniVation camera is attached"),
    ("dv:camera:DXA00000", "no iniVation camera is attached"),
    ("dv:webcam", "a DV source is dv://HOST:PORT | dv:camera[:SERIAL]"),
    ("dv://127.0.0.1", "give the stream's address as dv://HOST:PORT"),
    ("dv://127.0.0.1:7777?retry=1", "unknown option 'retry'"),
])
def test_dv_urls_that_cannot_open_say_why(url, says, tmp_path):
    r = subprocess.run(TRACK + [url, "--out", str(tmp_path / "x.csv")] + MODEL,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_no_server_there_is_a_connection_error_naming_the_address(tmp_path):
    port = free_port()
    r = subprocess.run(TRACK + [f"dv://127.0.0.1:{port}", "--out", str(tmp_path / "x.csv")]
                       + MODEL, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert f"cannot connect to a DV stream at 127.0.0.1:{port}: connect: Connection refused" in r.stderr


def test_the_camera_is_opened_through_dv_processing_when_discovered(monkeypatch):
    """The path up to opening, with dv-processing's discovery answering a camera (none is
    attached here): the serial asked for is the one opened, an unknown one is refused
    with the list."""
    from springtrack.live import dv as dvsrc

    class Desc:
        serialNumber = "DXA00093"
    opened = []
    monkeypatch.setattr(dv.io.camera, "discover", lambda: [Desc()])
    monkeypatch.setattr(dv.io.camera, "open", lambda *a: opened.append(a) or "camera")
    assert dvsrc.open_camera(dv, "DXA00093", "dv:camera:DXA00093") == "camera"
    assert dvsrc.open_camera(dv, "", "dv:camera") == "camera"
    assert opened == [("DXA00093",), ()]
    with pytest.raises(ConnectionError, match="no attached camera has serial 'X1'; attached: DXA00093"):
        dvsrc.open_camera(dv, "X1", "dv:camera:X1")


def test_without_dv_processing_the_message_names_the_extra(monkeypatch):
    from springtrack import live
    from springtrack.live.extras import MissingExtra
    monkeypatch.setitem(sys.modules, "dv_processing", None)
    with pytest.raises(MissingExtra, match=r"pip install 'springtrack\[dv\]'"):
        live.open("dv://127.0.0.1:7777")


def test_io_open_and_the_source_registries_route_live_urls():
    from firmware_sim import sources
    from springtrack import io as stio, live
    assert live.scheme_of("dv://h:1") == "dv" and live.scheme_of("udp://h:1") == "udp"
    assert live.scheme_of("rec.aedat4") is None and live.scheme_of("C:rec") is None
    assert all(sources.SCHEMES[s] == "firmware_sim.sources.live" for s in live.SCHEMES)
    assert sources.usage().count("dv://HOST:PORT") == 1
    with pytest.raises(ConnectionError):
        stio.open(f"dv://127.0.0.1:{free_port()}")


def test_a_dropped_stream_reconnects_within_its_window(data_file, tmp_path):
    """``?reconnect=S``: the first sender goes after 30,000 events, a second comes up on
    the same port and serves the whole file; the reader connects again, counts it, and
    reads both (the second's events are back in time: the tracker skips and counts
    them)."""
    path = data_file("sample.aedat4")
    first, url = start_sender(path, "--cut", "30000")
    port = url.rsplit(":", 1)[1]
    live = subprocess.Popen(TRACK + [url + "?reconnect=20", "--out", str(tmp_path / "r.csv")]
                            + MODEL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first.wait(timeout=60)
    second = subprocess.Popen([sys.executable, SENDER, "dv", port, str(path)],
                              stdout=subprocess.PIPE, text=True)
    assert second.stdout.readline().strip() == "listening"
    second.wait(timeout=60)
    out, err = live.communicate(timeout=120)
    assert live.returncode == 0, err
    sizes = batch_sizes(path)
    k = next(i for i in range(len(sizes)) if sum(sizes[:i + 1]) >= 30_000) + 1
    m = re.search(r"events=(\d+) batches=(\d+) gaps=(\d+) reconnects=(\d+)", err)
    assert [int(v) for v in m.groups()][:2] == [sum(sizes[:k]) + 111_954, k + len(sizes)]
    assert int(m.group(4)) == 1
    assert "back_in_time=" in out and "back_in_time=0 " not in out


def test_info_describes_a_dv_stream_as_the_file(data_file):
    path = data_file("sample.aedat4")
    sender, url = start_sender(path)
    r = subprocess.run([sys.executable, "-m", "springtrack.cli", "info", url],
                       capture_output=True, text=True, timeout=120)
    sender.wait(timeout=30)
    assert r.returncode == 0, r.stderr
    assert "geometry  320x240 (from the stream's event resolution)" in r.stdout
    assert "events    111,954 (55,023 ON)" in r.stdout
    assert f"decoded   {len(batch_sizes(path))} packets" in r.stdout
    assert "= 2020-11-16 14:38:13.718345 UTC" in r.stdout
