"""The firmware's side of the reliability reproductions: a replayed file's decoder drops in
the stats line and STATS (never ``anomalies=none``), ``--record`` streamed to disk (an
unwritable path refused at once; rows on disk while it runs, so a SIGKILL keeps them),
random host sequence numbers not inflating ``rx_lost``, a retried MODEL_COMMIT answered
once when its validation ends; DAT and AEDAT 4 replays faster than the loop: transfers
shed and counted, the queue bounded by the buffer pool.  Firmware and host as separate processes where the
reproduction involves them."""
from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from firmware_sim.record import StreamRecorder
from springtrack import io as stio
from springtrack import wire
from springtrack.model import grid3x3
from springtrack.sim.synthetic import blob_stream
from springtrack.track import CSV_HEADER

from support.fwproc import firmware_cmd
from support.wait import wait_for


def es_with_garbage(path) -> int:
    """An Event Stream file whose header declares a sensor smaller than its events:
    returns the number of events outside it."""
    ev, _ = blob_stream(grid3x3(), 20_000, rate_hz=200_000, seed=2)
    data = bytearray(stio.encode_file(ev, 304, 240, "es"))
    small = 200
    assert data[16:18] == (304).to_bytes(2, "little")
    data[16:18] = small.to_bytes(2, "little")
    Path(path).write_bytes(bytes(data))
    return int((ev["x"] >= small).sum())


@pytest.mark.hil
def test_a_replayed_files_decoder_drops_reach_the_stats_line(tmp_path):
    src = tmp_path / "small.es"
    lost = es_with_garbage(src)
    assert lost > 1000
    model = tmp_path / "m.toml"
    model.write_text(grid3x3(cx=100, cy=120, spacing=40, width=200, height=240).to_toml())
    r = subprocess.run(firmware_cmd("--source", f"replay:{src}", "--max-speed",
                                    "--model", str(model)),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    stats = next(x for x in r.stdout.splitlines() if x.startswith("stats: "))
    assert "anomalies=none" not in stats and f"'replay_file': {lost}" in stats, stats
    assert "replay: warning: decoding" in r.stderr and "out_of_geometry" in r.stderr


OVERLOAD_BUFFERS = 4


@pytest.mark.hil
@pytest.mark.parametrize("fmt", ["dat", "aedat4"])
def test_a_replay_faster_than_the_loop_is_shed_and_counted_never_queued(tmp_path, fmt):
    """1 M events/s replayed in real time to the microcontroller build in its emulator
    (under 0.1 M events/s): the reader drops whole transfers when its pool of buffers is
    full, counts them in the stats line, and the queue never holds more than the pool."""
    ev, _ = blob_stream(grid3x3(), 300_000, rate_hz=1_000_000, seed=2)
    src = tmp_path / f"fast.{fmt}"
    src.write_bytes(stio.encode_file(ev, 304, 240, fmt))
    r = subprocess.run(firmware_cmd("--source", f"replay:{src}", "--realtime", "--backend",
                                    "mcu", "--preset", "grid3x3", "--buffers",
                                    str(OVERLOAD_BUFFERS)),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if x.startswith("stats: "))
    f = dict(kv.split("=", 1) for kv in line[len("stats: "):].split() if "=" in kv)
    assert int(f["dropped"]) > 0 and int(f["dropped_bytes"]) > 0, line
    assert int(f["queue_hwm"]) <= OVERLOAD_BUFFERS, line
    # the shed transfers' events are the ones missing: decoded < the file's, every decoded
    # event tracked, the dropped bytes a part of those read
    assert 0 < int(f["decoded"]) < len(ev) and int(f["tracked"]) == int(f["decoded"]), line
    assert int(f["dropped_bytes"]) < int(f["bytes"]), line


@pytest.mark.hil
def test_a_replay_of_random_bytes_behind_a_header_is_refused_at_once(tmp_path):
    """As ``springtrack track``: a file mostly of corrupt words is not replayed (its events
    would come at random times, each sampled for HOLD periods and at its end), one clear line, exit 2."""
    src = tmp_path / "g.raw"
    src.write_bytes(b"% evt 3.0\n% geometry 304x240\n% end\n"
                    + bytes(np.random.default_rng(7).integers(0, 256, 1 << 18, np.uint8)))
    r = subprocess.run(firmware_cmd("--source", f"replay:{src}", "--max-speed", "--preset",
                                    "grid3x3"), capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "does not decode as evt3" in lines[0], r.stderr


def test_stream_recorder_refuses_an_unwritable_path_at_once(tmp_path):
    with pytest.raises(OSError):
        StreamRecorder(tmp_path / "no" / "such" / "dir.csv")


@pytest.mark.hil
def test_firmware_record_is_on_disk_while_it_runs_and_survives_sigkill(tmp_path):
    out = tmp_path / "rec.csv"
    bad = subprocess.run(firmware_cmd("--source", "sim:face_occlusion", "--seconds", "1",
                                      "--record", str(tmp_path / "no" / "x.csv")),
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "No such file" in bad.stderr and "Traceback" not in bad.stderr
    p = subprocess.Popen(firmware_cmd("--source", "sim:face_occlusion", "--realtime",
                                      "--record", str(out)),
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: out.exists() and out.stat().st_size >= 20_000, timeout=60,
                 what="20 kB of the record on disk", interval=0.1)
        p.send_signal(signal.SIGKILL)
        p.wait(10)
    finally:
        if p.poll() is None:
            p.kill()
    lines = out.read_text().splitlines()
    assert tuple(lines[0].split(",")) == CSV_HEADER and len(lines) > 100
    # every row before the last flush is whole
    assert all(len(x.split(",")) == len(CSV_HEADER) for x in lines[1:-1])


def test_random_sequence_numbers_are_jumps_not_losses():
    s = wire.SeqTracker(max_gap=256)
    rng = np.random.default_rng(1)
    for seq in rng.integers(0, 1 << 16, 1000):
        s.update(int(seq))
    assert s.lost <= 1000 * 256 and s.jumps > 400
    ok = wire.SeqTracker()
    for seq in (1, 2, 5, 6):
        ok.update(seq)
    assert ok.lost == 2 and ok.jumps == 0
