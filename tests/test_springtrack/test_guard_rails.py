"""Guard rails between a shape model and the sensor it tracks on (springtrack.sensor_fit):
every one triggers on a crafted bad model, in the library, `springtrack track` and the
firmware (NACK sensor_mismatch over the host link)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from springtrack import io as stio
from springtrack.events import make
from springtrack.sensor_fit import (SensorMismatch, TrackersOutside, check_inside, fit_model,
                                  outside_trackers)
from springtrack.model import face26, grid3x3, load
from springtrack.track import Track, read_csv
from springtrack.tracker import Tracker
from springtrack.watch import TrackWatch
from springtrack.wire import Nack


def track_cli(*args):
    return subprocess.run([sys.executable, "-m", "springtrack.cli", "track", *map(str, args),
                           "--no-progress"], capture_output=True, text=True, timeout=120)


def off_sensor(tmp_path, width=640, height=480, x=700.0):
    """A grid model of a width x height sensor with its first tracker at x."""
    path = tmp_path / "off.toml"
    path.write_text(grid3x3(width=width, height=height).to_toml()
                    .replace("x = 102.0", f"x = {x}", 1))
    return path


@pytest.fixture
def rec640(tmp_path):
    """A 640 x 480 EVT 2.0 recording: a blob under the grid's centre tracker."""
    rng = np.random.default_rng(4)
    n = 4000
    ev = make(np.sort(rng.integers(0, 200_000, n)), 152 + rng.integers(-3, 4, n),
              120 + rng.integers(-3, 4, n), 1)
    path = tmp_path / "rec640.raw"
    stio.write(path, ev, 640, 480)
    return path, ev


def test_fit_model_names_both_sizes_and_the_ways_out():
    m = face26()
    assert fit_model(m, 304, 240) is m
    assert fit_model(m, None, None) is m               # npy / CSV: size unknown
    with pytest.raises(SensorMismatch) as e:
        fit_model(m, 640, 480, what="rec.raw")
    msg = str(e.value)
    assert "[sensor] is 304x240 but rec.raw is 640x480" in msg
    assert "--sensor-from file" in msg and "--sensor-from model" in msg
    assert e.value.code == Nack.SENSOR_MISMATCH
    big = fit_model(m, 640, 480, "file")
    assert (big.width, big.height) == (640, 480) and big.trackers == m.trackers
    assert fit_model(m, 640, 480, "model") is m
    with pytest.raises(ValueError, match="--sensor-from must be file or model"):
        fit_model(m, 640, 480, "camera")


def test_trackers_outside_the_sensor_are_an_error(tmp_path):
    m = load(off_sensor(tmp_path))
    assert outside_trackers(m) == [("r0c0", 700.0, 70.0)]
    with pytest.raises(TrackersOutside, match=r"1 tracker\(s\) outside the 640x480 sensor: "
                                              r"r0c0 \(700, 70\)"):
        check_inside(m)
    with pytest.raises(TrackersOutside):
        Tracker(m)
    # a smaller sensor taken from the file leaves trackers outside it too
    with pytest.raises(TrackersOutside, match="outside the 100x100 sensor"):
        fit_model(grid3x3(), 100, 100, "file")
    Tracker(m, acquire=True)         # acquisition does not trust the positions: allowed


def test_track_refuses_a_model_of_another_sensor_unless_told(tmp_path, rec640):
    path, ev = rec640
    out = tmp_path / "t.csv"
    r = track_cli(path, "--model", "grid3x3", "--out", out)
    assert r.returncode == 2
    assert "the model's [sensor] is 304x240 but" in r.stderr and "640x480" in r.stderr
    assert "Traceback" not in r.stderr
    r = track_cli(path, "--model", "grid3x3", "--out", out, "--sensor-from", "file")
    assert r.returncode == 0, r.stderr
    ref = Tracker(grid3x3(width=640, height=480)).run(ev, 1000)
    got = read_csv(out)
    assert np.allclose(got.x, ref.x, atol=1e-5) and np.array_equal(got.t_us, ref.t_us)
    r = track_cli(path, "--model", "grid3x3", "--out", out, "--sensor-from", "model")
    assert r.returncode == 0, r.stderr


def test_track_refuses_trackers_outside_the_sensor(tmp_path, rec640):
    path, _ = rec640
    r = track_cli(path, "--model", off_sensor(tmp_path), "--out", tmp_path / "t.csv")
    assert r.returncode == 2
    assert "r0c0 (700, 70)" in r.stderr and "outside the 640x480 sensor" in r.stderr


def test_track_warns_about_trackers_that_never_received_an_event(tmp_path, rec640):
    path, _ = rec640
    r = track_cli(path, "--model", "grid3x3", "--out", tmp_path / "t.csv", "--sensor-from",
                  "file")
    assert r.returncode == 0
    # the blob sits under r1c1 only: the eight others never get an event
    assert "warning: 8 of 9 tracker(s) never received an event: r0c0, r0c1" in r.stderr
    assert "r1c1" not in r.stderr.split("never received an event:")[1].split("(")[0]


def test_the_watch_reports_trackers_and_the_instance_leaving_the_sensor():
    m = grid3x3()
    w = TrackWatch(m)
    k = len(m.ids)
    t = np.array([1000, 2000, 3000, 4000])
    x = np.tile([t.x for t in m.trackers], (4, 1)).astype(float)
    y = np.tile([t.y for t in m.trackers], (4, 1)).astype(float)
    x[2:, 0] = -5.0                                  # r0c0 goes out at t = 3000 for good
    x[3, :] -= 400.0                                 # everything goes out at t = 4000
    z = np.zeros((4, k))
    act = z.copy()
    act[1, :4] = 0.5                                 # four trackers received events
    tr = Track(t, list(m.ids), x, y, z + 25, z, z + 25, act, z, z, z > 0, z == 0)
    w.add(tr)
    w.finish({"activity": np.zeros(k)})
    msgs = w.warnings()
    assert msgs[0].startswith("5 of 9 tracker(s) never received an event: r1c1, r1c2")
    assert "the model instance 'grid3x3' left the 304x240 sensor at t=4000 us" in msgs[1]
    assert msgs[2].startswith("9 tracker(s) left the 304x240 sensor: r0c0 (t=3000 us), "
                              "r0c1 (t=4000 us)")
    # back on the sensor at the end: no warning about leaving
    w2 = TrackWatch(m)
    w2.add(tr)
    back = Track(np.array([5000]), list(m.ids), x[:1], y[:1], z[:1] + 25, z[:1], z[:1] + 25,
                 act[:1] + 1, z[:1], z[:1], z[:1] > 0, z[:1] == 0)
    w2.add(back)
    w2.finish({"activity": np.ones(k)})
    assert w2.warnings() == []


def test_the_firmware_nacks_an_uploaded_model_that_does_not_fit_its_camera():
    """Over a real pty with hostctl: a 304 x 240 model, and one with a tracker at x = 700,
    sent to a firmware whose camera is 640 x 480: NACK sensor_mismatch naming the problem,
    the running model untouched."""
    from firmware_sim import camera as camusb
    from firmware_sim.loop import FirmwareLoop
    from hostctl import Device, Nacked
    from support.link import Served
    eng = FirmwareLoop(lambda: None, face26(cx=320, cy=240, width=640, height=480),
                       profile=camusb.PROFILES["evt2"])
    s = Served(eng)
    try:
        with Device(s.path) as dev:
            assert (dev.info["width"], dev.info["height"]) == (640, 480)
            with pytest.raises(Nacked, match="sensor_mismatch") as e:
                dev.load_model(grid3x3())
            assert "304x240 but the camera's sensor is 640x480" in e.value.reason
            bad = grid3x3(width=640, height=480).to_toml().replace("x = 102.0", "x = 700.0", 1)
            with pytest.raises(Nacked, match="sensor_mismatch") as e:
                dev.load_model(bad)
            assert "r0c0 (700, 70)" in e.value.reason
            assert dev.hello()["model"] == "face26"
            dev.load_model(grid3x3(width=640, height=480))
    finally:
        s.close()
    assert eng.model.name == "grid3x3"


def test_firmware_sim_refuses_a_model_that_does_not_fit_the_recording(data_file, tmp_path):
    path = data_file("evt2_sample.raw")
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        f"replay:{path}", "--max-speed", "--preset", "face26"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert ("the model's [sensor] is 304x240 but the camera's sensor is 640x480" in r.stderr
            and "--sensor-from source" in r.stderr)
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        f"replay:{path}", "--max-speed", "--model", off_sensor(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "r0c0 (700, 70)" in r.stderr


def test_the_watch_names_an_instance_never_found_instead_of_its_idle_trackers():
    from springtrack.instances import ModelSet
    a = grid3x3(cx=100, cy=120, spacing=30)
    b = grid3x3(cx=200, cy=120, spacing=30)
    w = TrackWatch(ModelSet([a, b]))
    act = np.zeros(18)
    act[:8] = 1.0                                    # #1's r2c2 and all of #2 got nothing
    w.finish({"activity": act}, never_found=["grid3x3#2"])
    msgs = w.warnings()
    assert msgs == ["the model instance 'grid3x3#2' was never found (searching to the end): "
                    "its 9 trackers' rows hold unplaced positions",
                    "1 of 18 tracker(s) never received an event: grid3x3#1/r2c2 (nothing moved "
                    "under them, or the model does not match the recording: check its "
                    "positions against `springtrack render INPUT --out grid.png`)"]
