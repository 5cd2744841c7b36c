"""Hostile and unusual inputs to the command line, each a reproduction: drops the decoder
made reported (never silent), memory bounded by the events (header size fields, declared
geometry, time-span pauses), inputs that are not files (a named pipe), ``--out -``, a
reader of standard output that goes away, SIGTERM during ``track``.  Separate processes
as a user runs them; peak memory through tests/peak_rss.py."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from springtrack import io as stio
from springtrack.events import EVENT_DTYPE
from springtrack.io.outputs import INCOMPLETE_MARK
from springtrack.model import grid3x3
from springtrack.sim.synthetic import blob_stream
from support import REPO
from support.wait import wait_for

HERE = REPO / "tests" / "support"
CLI = [sys.executable, "-m", "springtrack.cli"]


def cli(*args, timeout=120, **kw):
    return subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True,
                          timeout=timeout, **kw)


def peak(limit_mib, *args, timeout=120):
    """(result, peak MiB) of ``springtrack ARGS`` under a data limit of ``limit_mib``."""
    r = subprocess.run([sys.executable, str(HERE / "peak_rss.py"), str(limit_mib), "springtrack",
                        *[str(a) for a in args]], capture_output=True, text=True, timeout=timeout)
    mib = float(r.stderr.rsplit("peak_rss_mib", 1)[1].split()[0])
    return r, mib


@pytest.fixture(scope="module")
def grid_events():
    ev, _ = blob_stream(grid3x3(), 40_000, rate_hz=200_000, seed=3)
    return ev


def smaller_header_raw(path, ev, declared=(100, 80)) -> None:
    """An EVT 2.0 file of 304x240 events whose header declares a smaller sensor."""
    data = stio.encode_file(ev, 304, 240, "evt2")
    w, h = declared
    data = data.replace(b"height=240;width=304", f"height={h};width={w}".encode()) \
               .replace(b"% geometry 304x240", f"% geometry {w}x{h}".encode())
    Path(path).write_bytes(data)


# ---- every drop reported ---------------------------------------------------------------
def test_track_warns_of_events_the_decoder_dropped_outside_a_smaller_declared_sensor(
        tmp_path, grid_events):
    src = tmp_path / "small.raw"
    smaller_header_raw(src, grid_events)
    model = tmp_path / "m.toml"
    model.write_text(grid3x3(cx=50, cy=40, spacing=15, width=100, height=80).to_toml())
    r = cli("track", src, "--model", model, "--out", tmp_path / "t.csv", "--no-progress")
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if x.startswith("events="))
    assert "decoder_anomalies=" in line and "decoder_anomalies=none" not in line
    assert "out_of_geometry" in line
    assert "warning:" in r.stderr and "out_of_geometry" in r.stderr


@pytest.mark.parametrize("command", ["learn", "render"])
def test_learn_and_render_warn_of_decoder_drops(tmp_path, grid_events, command):
    src = tmp_path / "small.raw"
    smaller_header_raw(src, grid_events)
    out = tmp_path / ("m.toml" if command == "learn" else "e.png")
    r = cli(command, src, "--out", out, timeout=300)
    assert "warning:" in r.stderr and "out_of_geometry" in r.stderr, r.stderr


def test_garbage_aedat4_payload_is_refused_not_a_silent_empty_result(tmp_path, grid_events):
    good = stio.encode_file(grid_events[:2000], 304, 240, "aedat4")
    info = stio.open(_write(tmp_path / "g.aedat4", good))
    data = good[:info.offset] + bytes(np.random.default_rng(1).integers(0, 256, 20_000, np.uint8))
    src = _write(tmp_path / "bad.aedat4", data)
    r = cli("track", src, "--model", "grid3x3", "--out", tmp_path / "t.csv", "--no-progress")
    assert r.returncode == 2 and "does not decode as aedat4" in r.stderr, (r.stdout, r.stderr)
    assert "unframed_bytes 20,000" in r.stderr, r.stderr


# headers of the formats whose words random bytes decode into events (and time jumps)
GARBAGE_HEADERS = {
    "evt2": b"% evt 2.0\n% geometry 304x240\n% end\n",
    "evt21": b"% evt 2.1\n% format EVT21;height=240;width=304\n% end\n",
    "evt3": b"% evt 3.0\n% geometry 304x240\n% end\n",
    "dat": b"% Data file containing CD events.\n% Version 2\n% Width 304\n% Height 240\n\x0c\x08",
}


@pytest.mark.parametrize("fmt", sorted(GARBAGE_HEADERS))
def test_random_bytes_behind_a_valid_header_are_refused_not_multiplied(tmp_path, fmt):
    """A megabyte of random bytes read as EVT 3.0 became 155 MB of track CSV (each event
    after a random time jump opening an empty stretch sampled for several periods): refused with the
    counts before any row is written, by track, learn and render; info still describes it."""
    src = _write(tmp_path / f"g.{'dat' if fmt == 'dat' else 'raw'}", GARBAGE_HEADERS[fmt]
                 + bytes(np.random.default_rng(7).integers(0, 256, 1 << 18, np.uint8)))
    csv = tmp_path / "t.csv"
    for command in (["track", src, "--model", "grid3x3", "--out", csv, "--no-progress"],
                    ["learn", src, "--out", tmp_path / "m.toml"],
                    ["render", src, "--out", tmp_path / "e.png"]):
        r = cli(*command)
        assert r.returncode == 2, (command, r.stdout, r.stderr)
        assert f"does not decode as {fmt}" in r.stderr and "unknown_type" in r.stderr, r.stderr
    assert csv.read_text().count("\n") == 1            # the header line only
    assert not (tmp_path / "m.toml").exists() and not (tmp_path / "e.png").exists()
    r = cli("info", src)
    assert r.returncode == 0 and "unknown_type" in r.stdout, r.stderr


def test_a_recording_with_a_damaged_stretch_is_still_tracked(tmp_path, grid_events):
    """Corrupt words under CORRUPT_SHARE of a stream: tracked, the anomalies a warning."""
    data = stio.encode_file(grid_events, 304, 240, "evt2")
    offset = stio.open(_write(tmp_path / "g.raw", data)).offset
    cut = offset + ((len(data) - offset) // 2 & ~3)           # a word boundary
    bad = b"\xff\xff\xff\x5f"                                  # word type 5: unknown
    src = _write(tmp_path / "d.raw", data[:cut] + bad * 2000 + data[cut:])
    csv = tmp_path / "t.csv"
    r = cli("track", src, "--model", "grid3x3", "--out", csv, "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "unknown_type 2,000" in r.stderr and csv.read_text().count("\n") > 100


def _write(path, data: bytes):
    Path(path).write_bytes(data)
    return path


# ---- memory by the events, not by size fields, geometry or time span --------------------
def test_npy_header_claiming_1e12_events_is_refused_without_allocating(tmp_path):
    path = tmp_path / "huge.npy"
    fmt = np.lib.format
    with open(path, "wb") as f:
        fmt.write_array_header_1_0(f, {"descr": fmt.dtype_to_descr(EVENT_DTYPE),
                                       "fortran_order": False, "shape": (10**12,)})
        f.write(bytes(160))
    raw = path.read_bytes()
    assert len(raw) < 400
    for command in (["info", path], ["track", path, "--model", "grid3x3", "--out",
                                     tmp_path / "t.csv"], ["learn", path, "--out", tmp_path / "m.toml"],
                    ["render", path, "--out", tmp_path / "e.png"]):
        r, mib = peak(300, *command)
        assert r.returncode == 2, (command, r.stderr)
        assert "header declares shape (1000000000000,)" in r.stderr and "Traceback" not in r.stderr
        assert mib < 300


def test_a_65535_px_declared_geometry_is_refused_by_learn_and_render(tmp_path, grid_events):
    src = tmp_path / "huge.raw"
    smaller_header_raw(src, grid_events[:1000], declared=(65535, 65535))
    for command in ("learn", "render"):
        out = tmp_path / ("m.toml" if command == "learn" else "e.png")
        r, mib = peak(400, command, src, "--out", out)
        assert r.returncode == 2 and "65535x65535 sensor" in r.stderr, r.stderr
        assert mib < 400


def test_learn_memory_follows_the_events_not_a_28_hour_pause(tmp_path):
    ev, _ = blob_stream(grid3x3(), 30_000, rate_hz=200_000, seed=5)
    half = len(ev) // 2
    ev["t"][half:] += 28 * 3600 * 1_000_000                # a 28-hour pause in the middle
    src = tmp_path / "pause.npy"
    np.save(src, ev)
    r, mib = peak(600, "learn", src, "--out", tmp_path / "m.toml", "--trackers", "9",
                  timeout=300)
    assert r.returncode in (0, 3), r.stderr[-2000:]
    assert "MemoryError" not in r.stderr and mib < 600


def test_render_memory_follows_the_events_not_a_28_hour_pause(tmp_path):
    ev, _ = blob_stream(grid3x3(), 30_000, rate_hz=200_000, seed=5)
    ev["t"][len(ev) // 2:] += 28 * 3600 * 1_000_000
    src = tmp_path / "pause.npy"
    np.save(src, ev)
    r, mib = peak(600, "render", src, "--model", "grid3x3", "--out", tmp_path / "o.png",
                  timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "MemoryError" not in r.stderr and mib < 600


def test_learn_batches_skip_a_long_pause():
    from springtrack.learning.discovery import MAX_IDLE_BATCHES, _batches
    ev = np.zeros(4, EVENT_DTYPE)
    ev["t"] = [0, 10, 10**12, 10**12 + 5]
    got = list(_batches(ev, 0, int(ev["t"][-1]), 1000))
    assert len(got) <= MAX_IDLE_BATCHES + 4
    assert sum(sl.stop - sl.start for _, sl in got) == 4        # every event in one batch
    assert all(a[0] < b[0] for a, b in zip(got, got[1:]))


def test_info_memory_is_constant_in_the_number_of_bins():
    from collections import Counter
    from springtrack.commands.info import BINS_OPEN, _close_bins
    bins = Counter({b: 1 for b in range(3 * BINS_OPEN)})
    bins[5] = 7
    pb, p = _close_bins(bins, max(bins) - BINS_OPEN, None, 0)
    assert len(bins) == BINS_OPEN + 1 and (pb, p) == (5, 7)


# ---- inputs that are not files, outputs that are not files -------------------------------
def test_a_named_pipe_is_read_as_a_stream_and_its_writer_is_not_killed(tmp_path, grid_events):
    fifo = tmp_path / "ev.fifo"
    os.mkfifo(fifo)
    data = stio.encode_file(grid_events, 304, 240, "evt2")
    status = {}

    def writer():
        with open(fifo, "wb") as f:
            try:
                f.write(data)
                status["ok"] = True
            except BrokenPipeError:
                status["ok"] = False
    th = threading.Thread(target=writer, daemon=True)
    th.start()
    r = cli("info", fifo, timeout=60)
    th.join(10)
    assert r.returncode == 0, r.stderr
    assert f"events     {len(grid_events):,}" in r.stdout or f"{len(grid_events):,}" in r.stdout
    assert status.get("ok") is True


def test_out_dash_writes_the_track_csv_to_stdout_and_the_summary_to_stderr(tmp_path, grid_events):
    src = tmp_path / "g.npy"
    np.save(src, grid_events)
    r = cli("track", src, "--model", "grid3x3", "--out", "-", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("t_us,tracker,") and "events=" not in r.stdout
    assert "events=" in r.stderr and not (tmp_path / "-").exists() and not Path("-").exists()


def test_output_into_a_closed_pipe_ends_quietly_with_141(tmp_path, grid_events):
    src = tmp_path / "g.npy"
    np.save(src, grid_events)
    p = subprocess.Popen(CLI + ["track", str(src), "--model", "grid3x3", "--out", "-",
                                "--no-progress", "--sample-us", "100"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.readline()
    p.stdout.close()                                   # like `| head -1`
    err = p.stderr.read().decode()
    assert p.wait(60) == 141, err
    assert "Broken pipe" not in err and "Traceback" not in err


def test_sigterm_during_track_leaves_a_clearly_marked_csv(tmp_path):
    ev, _ = blob_stream(grid3x3(), 3_000_000, rate_hz=200_000, seed=6)
    src = tmp_path / "long.npy"
    np.save(src, ev)
    out = tmp_path / "t.csv"
    p = subprocess.Popen(CLI + ["track", str(src), "--model", "grid3x3", "--out", str(out),
                                "--no-progress", "--sample-us", "100"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for(lambda: out.exists() and out.stat().st_size >= 50_000, timeout=60,
             what="50 kB of the track written", interval=0.05)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 143, err
    assert "incomplete (SIGTERM)" in err and "Traceback" not in err
    last = out.read_text().rstrip("\n").splitlines()[-1]
    assert last.startswith(INCOMPLETE_MARK)


# ---- the smaller items ------------------------------------------------------------------
def test_render_model_png_and_gif_need_no_imageio(tmp_path, grid_events):
    src = tmp_path / "g.npy"
    np.save(src, grid_events)
    out = tmp_path / "o.png"
    code = ("import sys; sys.modules['imageio'] = None; sys.modules['imageio.v2'] = None; "
            "from springtrack.cli import main; sys.exit(main(sys.argv[1:]))")
    r = subprocess.run([sys.executable, "-c", code, "render", str(src), "--model", "grid3x3",
                        "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = subprocess.run([sys.executable, "-c", code, "render", str(src), "--model", "grid3x3",
                        "--out", str(tmp_path / "o.gif")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and (tmp_path / "o.gif").read_bytes()[:6] == b"GIF89a", r.stderr
    r = subprocess.run([sys.executable, "-c", code, "render", str(src), "--model", "grid3x3",
                        "--out", str(tmp_path / "o.mp4")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 2 and "needs imageio" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.hil
def test_listen_port_out_of_range_is_a_clear_error():
    from support.fwproc import firmware_cmd
    r = subprocess.run(firmware_cmd("--source", "sim:face_occlusion", "--listen", "127.0.0.1:99999"),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "port in 0..65535" in r.stderr and "Traceback" not in r.stderr


def test_score_with_a_time_beyond_int64_is_a_clear_error(tmp_path):
    truth = tmp_path / "truth.csv"
    truth.write_text("t_us,part,x,y\n" + "9" * 30 + ",a,1,2\n")
    track = tmp_path / "track.csv"
    track.write_text("t_us,tracker,x,y,sxx,sxy,syy,activity,active,sensitive\n"
                     + "9" * 30 + ",a,1,2,1,0,1,0,1,1\n")
    r = cli("score", truth, track)
    assert r.returncode == 2 and "malformed truth row" in r.stderr and "Traceback" not in r.stderr
    truth.write_text("t_us,part,x,y\n1000,a,1,2\n")
    r = cli("score", truth, track)
    assert r.returncode == 2 and "malformed track row" in r.stderr and "Traceback" not in r.stderr


def test_aedat4_decompression_amplification_is_bounded(tmp_path):
    """A valid file of identical events compresses ~200x with LZ4: its packets beyond
    aedat4.MAX_RATIO are corrupt packets (counted, warned about), never an allocation."""
    from springtrack.io import aedat4
    ev = np.zeros(400_000, EVENT_DTYPE)
    ev["x"], ev["y"] = 5, 7
    data = stio.encode_file(ev, 304, 240, "aedat4")
    assert len(ev) * 16 / len(data) > aedat4.MAX_RATIO      # a real amplification
    src = _write(tmp_path / "amp.aedat4", data)
    r = stio.open(src)
    got = r.read()
    assert len(got) * 16 <= len(data) * aedat4.MAX_RATIO
    assert r.stats.anomalies["corrupt_packets"] > 0
    res = cli("track", src, "--model", "grid3x3", "--out", tmp_path / "t.csv", "--no-progress")
    assert "warning:" in res.stderr and "corrupt_packets" in res.stderr
