"""The near-sensor chain tells the truth on real recordings: firmware-sim and hostctl as
separate processes over a real pty, each replaying a recording from the data folder.

* a model that is not in the recording is ``searching`` then ``not found`` in STATS, in
  the telemetry (``hostctl record``'s rows), in ``hostctl monitor`` / ``record`` (exit 8,
  saying so) and in the firmware's own statistics line; the offline track says the same;
* ``hostctl record --start`` captures a short replay whole;
* ``hostctl get-model`` returns the device's model, with the tracker ids of the record;
* ``firmware-sim run --source replay:`` takes springtrack track's recording options and
  its record then equals ``springtrack track``'s byte for byte (the biplane);
* a model uploaded for another sensor is refused with the host's way out named first.
"""
import subprocess

import numpy as np
import pytest

from springtrack.commands.track import DOUBTFUL_EXIT

from support.fwproc import Firmware, firmware_cmd, hostctl_cmd
from hostctl import Device, HostctlError
from springtrack import cli as st_cli
from springtrack.track import read_csv

NOT_FOUND_EXIT = 8


def hostctl(port, *args, timeout=120):
    return subprocess.run(hostctl_cmd("--port", port, *args), capture_output=True, text=True,
                          timeout=timeout)


pytestmark = pytest.mark.hil


def test_model_not_in_the_recording_is_not_found_everywhere(tmp_path, data_file):
    """N-CARS (a car's edges, 0.1 s: two 50 ms windows and a shorter last one) with the
    face model: searched in vain, said so by every output."""
    dat = str(data_file("ncars_sample.dat"))
    fw = Firmware("--source", f"replay:{dat}", "--preset", "face26", "--sensor-from", "source",
                  "--acquire", "--pty", "--wait-start")
    try:
        rec = hostctl(fw.path, "record", str(tmp_path / "r.csv"), "--start", "--seconds", "60")
        assert rec.returncode == NOT_FOUND_EXIT, rec.stderr
        assert "model instance face26#1 not found" in rec.stderr, rec.stderr
        track = read_csv(tmp_path / "r.csv")
        names = set(np.array(["searching", "tracking", "lost", "not found"])[
            np.unique(track.state)])
        assert names == {"searching", "not found"}, names     # never tracking
        assert not track.sensitive.any() and not track.active.any()
        # the last rows, after the search ended, say not found; the first, searching
        assert (track.state[-1] == 3).all() and (track.state[0] == 0).all()
        st = hostctl(fw.path, "stats")
        assert st.returncode == 0
        assert "instances.face26#1: not found" in st.stdout
        assert "acquisition: model instance face26#1 not found" in st.stdout
        mon = hostctl(fw.path, "monitor", "--seconds", "0.5")
        assert mon.returncode == NOT_FOUND_EXIT and "not found" in mon.stderr, mon.stderr
    finally:
        fw.close()
    # the offline track says the same, row for row
    out = tmp_path / "t.csv"
    assert st_cli.main(["track", dat, "--model", "face26", "--sensor-from", "file", "--acquire",
                        "--out", str(out), "--no-progress"]) == 1
    offline = read_csv(out)
    assert np.array_equal(offline.t_us, track.t_us)
    assert np.array_equal(offline.state, track.state)


def test_firmware_stats_line_says_not_found_and_budget(tmp_path, data_file):
    """Without a host link: the final statistics line names the instance's state; a
    search budget ends the search before the source does."""
    dat = str(data_file("ncars_sample.dat"))
    r = subprocess.run(firmware_cmd("--source", f"replay:{dat}", "--preset", "face26",
                                    "--sensor-from", "source", "--acquire", "--max-speed",
                                    "--acquire-budget-ms", "60", "--record",
                                    str(tmp_path / "r.csv")),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "instances=face26#1:not found" in r.stdout, r.stdout
    tr = read_csv(tmp_path / "r.csv")
    first_nf = tr.t_us[(tr.state == 3).all(axis=1)][0]
    assert first_nf <= 60_000 + 1000      # the budget, not the source's end (100 ms)


def test_record_start_get_model_ids_and_replay_options(tmp_path, data_file):
    """The biplane with the recording options, learned and tracked on the device: `record
    --start` gets all of it, `get-model` the learned model whose ids the rows use, and the
    rows equal those of springtrack track on the same options."""
    es = str(data_file("dvs.es"))
    opts = ["--dequantize", "--start-us", "1000", "--learn-first-ms", "200", "--acquire"]
    fw = Firmware("--source", f"replay:{es}", *opts, "--pty", "--wait-start")
    try:
        rec = hostctl(fw.path, "record", str(tmp_path / "r.csv"), "--start", "--seconds", "120")
        assert rec.returncode == 0, rec.stderr
        got = hostctl(fw.path, "get-model", str(tmp_path / "m.toml"))
        assert got.returncode == 0, got.stderr
    finally:
        fw.close()
    track = read_csv(tmp_path / "r.csv")
    model = (tmp_path / "m.toml").read_text()
    assert track.ids[0] == "p00" and all(f'id = "{i}"' in model for i in track.ids)
    out = tmp_path / "t.csv"
    # (4: tracked, the biplane found at a bound of the search: a doubtful find)
    assert st_cli.main(["track", es, *opts, "--out", str(out), "--no-progress"]) in (0, DOUBTFUL_EXIT)
    offline = read_csv(out)
    # the whole replay: every sample time of the offline track (telemetry is quantised)
    assert np.array_equal(offline.t_us, track.t_us)
    assert offline.ids == track.ids
    assert np.abs(offline.x - track.x).max() <= 1 / 16
    assert np.array_equal(offline.state, track.state)
    assert (track.state[-1] == 1).all()                 # tracking at the end
    # and drawn with the downloaded model
    assert st_cli.main(["render", es, "--model", str(tmp_path / "m.toml"), "--track",
                        str(tmp_path / "r.csv"), "--dequantize", "--start-us", "1000", "--out",
                        str(tmp_path / "p.png")]) == 0


def test_replay_record_equals_track_byte_for_byte(tmp_path, data_file):
    """firmware-sim's --record with --dequantize --start-us --end-us --burst-fraction
    equals springtrack track's output on the same options (the biplane, acquired)."""
    es = str(data_file("dvs.es"))
    model = tmp_path / "plane.toml"
    assert st_cli.main(["learn", es, "--out", str(model), "--start-us", "1000", "--end-us",
                        "200000", "--dequantize"]) == 0
    opts = ["--dequantize", "--start-us", "1000", "--end-us", "600000", "--burst-fraction",
            "0.4", "--acquire"]
    r = subprocess.run(firmware_cmd("--source", f"replay:{es}", "--model", str(model), *opts,
                                    "--max-speed", "--record", str(tmp_path / "fw.csv")),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "prepared: tick=1000 us (dequantized)" in r.stderr
    assert st_cli.main(["track", es, "--model", str(model), *opts, "--out",
                        str(tmp_path / "t.csv"), "--no-progress"]) in (0, DOUBTFUL_EXIT)
    assert (tmp_path / "fw.csv").read_bytes() == (tmp_path / "t.csv").read_bytes()
    # the options belong to a recording
    r = subprocess.run(firmware_cmd("--source", "sim:face_occlusion", "--dequantize"),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--source replay:FILE" in r.stderr


def test_upload_for_another_sensor_names_the_hosts_way_out(data_file):
    """hostctl load-model of a model for another sensor: refused, and the message names
    what the host can do before the firmware's own option (a restart)."""
    es = str(data_file("dvs.es"))
    fw = Firmware("--source", f"replay:{es}", "--pty", "--wait-start")   # face26, centred
    try:
        with Device(fw.path) as dev:
            with pytest.raises(HostctlError) as e:
                dev.load_model("grid3x3")              # 304x240, the camera is 320x240
        msg = str(e.value)
        assert "upload a model made for 320x240" in msg, msg
        assert "restart the firmware with `firmware-sim run --sensor-from" in msg, msg
        assert msg.index("upload a model") < msg.index("firmware-sim run")
    finally:
        fw.close()


def test_short_replay_reports_its_processing_time(data_file):
    """A replay shorter than the 10 ms load window (evt3_sample.raw: 219,596 events in
    8.8 ms) still reports the time it took to process, not 0."""
    raw = str(data_file("evt3_sample.raw"))
    r = subprocess.run(firmware_cmd("--source", f"replay:{raw}", "--max-speed"),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    line = [x for x in r.stdout.splitlines() if x.startswith("stats: ")][-1]
    assert "tracked=219596" in line
    mean = float(line.split("proc_us_per_10ms(mean=")[1].split()[0])
    assert mean > 0, line
