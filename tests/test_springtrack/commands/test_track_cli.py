"""`springtrack track` on a .npy stream of a moving 3x3 grid: CSV with trackers following."""
import csv
import subprocess
import sys

import numpy as np
import pytest

from springtrack.model import grid3x3
from springtrack.sim.synthetic import blob_stream, part_positions
from springtrack.track import CSV_HEADER, read_csv


@pytest.mark.slow
def test_track_cli_follows_a_moving_grid(tmp_path):
    m = grid3x3()
    ev, _ = blob_stream(m, 200_000, rate_hz=200_000, speed_px_s=(15, 8), noise=0.2, seed=4)
    src = tmp_path / "grid.npy"
    np.save(src, ev)
    out = tmp_path / "track.csv"
    r = subprocess.run([sys.executable, "-m", "springtrack.cli", "track", str(src), "--model", "grid3x3",
                        "--sample-us", "2000", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "events=" in r.stdout and "realtime_factor=" in r.stdout
    with open(out) as f:
        assert tuple(next(csv.reader(f))) == CSV_HEADER
    tr = read_csv(out)
    assert tr.ids == m.ids
    t0, t1 = ev["t"][0], ev["t"][-1]
    assert tr.t_us[0] >= t0 and tr.t_us[-1] <= t1 and np.all(np.diff(tr.t_us) == 2000)
    truth = part_positions(m, tr.t_us, speed_px_s=(15, 8))
    err = np.hypot(tr.x - truth[..., 0], tr.y - truth[..., 1])
    assert err[len(err) // 2:].mean() < 1.5           # follows the moving blobs
    assert tr.active[-1].all()


def test_track_cli_bad_model_is_a_clear_error(tmp_path):
    src = tmp_path / "e.npy"
    np.save(src, blob_stream(grid3x3(), 100)[0])
    r = subprocess.run([sys.executable, "-m", "springtrack.cli", "track", str(src), "--model",
                        str(tmp_path / "missing.toml"), "--out", str(tmp_path / "o.csv")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "no such model file" in r.stderr


def test_track_profile_bins_count_every_event(tmp_path):
    ev, _ = blob_stream(grid3x3(), 30_000, rate_hz=100_000, seed=2)
    src = tmp_path / "g.npy"
    np.save(src, ev)
    prof = tmp_path / "prof.csv"
    r = subprocess.run([sys.executable, "-m", "springtrack.cli", "track", str(src), "--model", "grid3x3",
                        "--out", str(tmp_path / "t.csv"), "--profile", str(prof)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rows = np.loadtxt(prof, delimiter=",", skiprows=1)
    assert rows[:, 1].sum() == len(ev)
    assert np.all(np.diff(rows[:, 0]) == 10_000) and np.all(rows[:, 2] >= 0)


def _cli(argv, capsys):
    """``springtrack`` in-process: (exit status, stdout, stderr)."""
    from springtrack.cli import main
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize("extra, message", [
    (["--instances", "0", "--acquire"], "--instances must be at least 1, got 0"),
    (["--model", "face26", "--instances", "9", "--acquire"],
     "--instances 9 of 2 model(s) asks for 18 instances; the limit is 16 in all"),
    (["--acquire", "--acquire-ms", "-5"], "--acquire-ms must be a positive number of ms, got -5"),
    (["--acquire", "--acquire-scale", "0,2"], "--acquire-scale must be LO,HI with 0 < LO <= HI"),
    (["--acquire", "--acquire-angle", "400"], "--acquire-angle must be in [0, 180] degrees"),
])
def test_track_option_errors_name_the_option(tmp_path, capsys, extra, message):
    src = tmp_path / "e.npy"
    np.save(src, blob_stream(grid3x3(), 1000)[0])
    rc, _, err = _cli(["track", str(src), "--model", "grid3x3", *extra,
                       "--out", str(tmp_path / "o.csv"), "--no-progress"], capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("springtrack track: error: ")
    assert message in lines[0]


def test_track_reports_what_the_preparation_dropped(tmp_path, capsys):
    ev, _ = blob_stream(grid3x3(), 20_000, rate_hz=100_000, seed=3)
    src = tmp_path / "g.npy"
    np.save(src, ev)
    start = int(ev["t"][len(ev) // 2])
    rc, out, _ = _cli(["track", str(src), "--model", "grid3x3", "--start-us", str(start),
                       "--out", str(tmp_path / "t.csv"), "--no-progress"], capsys)
    assert rc == 0
    before = int((ev["t"] < start).sum())
    assert f"events={len(ev) - before} " in out
    assert f"outside window {before:,}" in out


def test_a_missing_input_is_one_line_naming_the_file(tmp_path, capsys):
    missing = tmp_path / "none.npy"
    for cmd in (["track", str(missing), "--model", "grid3x3", "--out", str(tmp_path / "o.csv")],
                ["learn", str(missing), "--out", str(tmp_path / "m.toml")]):
        rc, _, err = _cli(cmd, capsys)
        assert rc == 2
        assert err == f"springtrack {cmd[0]}: error: {missing}: No such file or directory\n"


def test_sensor_from_takes_the_same_words_in_track_and_firmware_sim():
    import argparse

    from firmware_sim.cli import build_parser
    from springtrack.commands import track
    p = argparse.ArgumentParser()
    track.add_arguments(p)
    fw = build_parser()
    for word in ("file", "source", "model"):
        assert p.parse_args(["e.npy", "--out", "o.csv", "--sensor-from", word]).sensor_from == word
        assert fw.parse_args(["run", "--source", "sim:grid_pull",
                              "--sensor-from", word]).sensor_from == word
