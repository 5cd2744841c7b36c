"""The live view (springtrack.view) recorded to .rrd and read back with Rerun's own
reader (rerun.chunk.RrdReader): entities, frame times, counts, and the trackers drawn
where the track CSV puts them."""
from __future__ import annotations

import collections
import csv
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pytest
import rerun.chunk as rrc

from support.fwproc import Firmware, hostctl_cmd
from support.live_senders import free_port
from springtrack import io as stio
from springtrack.render import LEGEND
from springtrack.view.recorder import CLASS
from support import REPO

SENDER = str(REPO / "tests" / "support" / "live_senders.py")
TRACK = [sys.executable, "-m", "springtrack.cli", "track"]
MODEL = ["--model", "grid3x3", "--sensor-from", "file", "--no-progress"]
EVERY_US = 10_000


def read_rrd(path) -> dict:
    """entity path -> list of rows (dicts of the logged columns), in event time order."""
    rows = collections.defaultdict(list)
    for ch in rrc.RrdReader(str(path)).stream().to_chunks():
        b = ch.to_record_batch()
        d = {name: (col.cast(pa.int64()) if pa.types.is_temporal(col.type) else col).to_pylist()
             for name, col in zip(b.schema.names, b.columns)}
        n = ch.num_rows
        rows[ch.entity_path] += [{k: v[i] for k, v in d.items()} for i in range(n)]
    for ent in rows.values():
        ent.sort(key=lambda r: r.get("event_time") or 0)      # static rows (None) first
    return rows


def us(row) -> int:
    """A row's event time, µs (the timeline holds ns)."""
    return row["event_time"] // 1000


def frame_times(t_us) -> list[int]:
    """The view's rule: the first sample row, then each row at or past the next multiple
    of the frame period."""
    out, nxt = [], None
    for t in t_us:
        if nxt is None or t >= nxt:
            out.append(t)
            nxt = t - t % EVERY_US + EVERY_US
    return out


def test_a_live_dv_stream_viewed_to_an_rrd_holds_the_track(data_file, tmp_path):
    path = data_file("sample.aedat4")
    port = free_port()
    sender = subprocess.Popen([sys.executable, SENDER, "dv", str(port), str(path)],
                              stdout=subprocess.PIPE, text=True)
    assert sender.stdout.readline().strip() == "listening"
    r = subprocess.run(TRACK + [f"dv://127.0.0.1:{port}", "--out", str(tmp_path / "t.csv"),
                                "--view", str(tmp_path / "v.rrd")] + MODEL,
                       capture_output=True, text=True, timeout=180)
    sender.wait(timeout=30)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(tmp_path / "t.csv")))
    times = sorted({int(x["t_us"]) for x in rows})
    frames = frame_times(times)
    assert f"view: {len(frames)} frames" in r.stdout
    rec = read_rrd(tmp_path / "v.rrd")
    for ent in ("/sensor/events", "/sensor/trackers", "/sensor/springs", "/trackers/active",
                "/energy", "/instances"):
        assert [us(x) for x in rec[ent] if x.get("event_time") is not None] == frames, ent
    assert all(len(x["Scalars:scalars"]) == 3 for x in rec["/energy"] if x.get("event_time") is not None)
    assert rec["/energy"][0]["SeriesLines:names"] == ["euclidean", "torsional", "cartesian"]
    assert rec["/instances"][0]["SeriesLines:names"] == ["grid3x3#1"]
    # the legend: render's labels and colours as the annotation context
    ctx = rec["/"][0]
    assert all(label in str(ctx) for label, _ in LEGEND)
    # each frame's events: those of the frame period before it, ON / OFF by class
    ev = stio.open(path).read()
    for row in rec["/sensor/events"][::7]:
        t = us(row)
        win = ev[(ev["t"] >= t - EVERY_US) & (ev["t"] < t)]
        assert len(row["Points2D:positions"]) == len(win)
        assert row["Points2D:class_ids"] == [CLASS["ON"] if p else CLASS["OFF"] for p in win["p"]]
        assert np.array_equal(np.array(row["Points2D:positions"]),
                              np.stack([win["x"], win["y"]], -1).astype(np.float32))
    # the trackers: one 2σ ellipse each around the CSV's position, the class of its flags
    by_t = collections.defaultdict(list)
    for x in rows:
        by_t[int(x["t_us"])].append(x)
    for row in rec["/sensor/trackers"]:
        state = by_t[us(row)]
        assert row["LineStrips2D:labels"] == [x["tracker"] for x in state]
        for strip, cls, x in zip(row["LineStrips2D:strips"], row["LineStrips2D:class_ids"], state):
            pts = np.array(strip)
            centre = (pts.max(0) + pts.min(0)) / 2
            assert np.allclose(centre, [float(x["x"]), float(x["y"])], atol=0.2)
            want = ("insensitive" if x["sensitive"] == "0" else
                    "active (2σ)" if x["active"] == "1" else "inactive")
            assert cls == CLASS[want]
    assert [len(x["LineStrips2D:strips"]) for x in rec["/sensor/springs"]] == \
        [12] * len(frames)                          # grid3x3: 12 springs


@pytest.mark.hil
def test_hostctl_monitor_views_a_devices_telemetry(tmp_path):
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", "30", "--pty")
    try:
        r = subprocess.run(hostctl_cmd("--port", fw.path, "monitor", "--seconds", "2",
                                       "--view", str(tmp_path / "m.rrd"), "--model", "face26"),
                           capture_output=True, text=True, timeout=120)
    finally:
        fw.close()
    assert r.returncode == 0, r.stderr
    frames = int(r.stderr.split("view: ")[1].split()[0])
    assert frames > 5
    rec = read_rrd(tmp_path / "m.rrd")
    assert len(rec["/sensor/trackers"]) == frames
    assert all(len(x["LineStrips2D:strips"]) == 26 for x in rec["/sensor/trackers"])
    assert "mouth" in rec["/sensor/trackers"][-1]["LineStrips2D:labels"]
    assert len(rec["/sensor/springs"]) == frames
    assert [len(x["Scalars:scalars"]) for x in rec["/energy"] if x.get("event_time") is not None] == [1] * frames
    assert rec["/energy"][0]["SeriesLines:names"] == ["mean"]
    assert len([x for x in rec["/instances"] if x.get("event_time") is not None]) == frames
    t = [us(x) for x in rec["/sensor/trackers"]]
    assert all(b - a >= EVERY_US - a % EVERY_US for a, b in zip(t, t[1:]))


def test_view_targets_and_the_missing_extra(tmp_path, monkeypatch):
    r = subprocess.run(TRACK + ["x.npy", "--out", str(tmp_path / "t.csv"), "--view", "screen"]
                       + MODEL, capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2 and "--view must be rerun" in r.stderr
    from springtrack import view
    from springtrack.live.extras import MissingExtra
    monkeypatch.setitem(sys.modules, "rerun", None)
    with pytest.raises(MissingExtra, match=r"pip install 'springtrack\[view\]'"):
        view.open(str(tmp_path / "v.rrd"), None)
