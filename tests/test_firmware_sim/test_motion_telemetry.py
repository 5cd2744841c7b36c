"""The motion model's velocities (eq. M7) cross the host link: firmware-sim replays the real
dot of evt2_sample.raw with a one-tracker model and the motion model on, as a separate
process on a pty; ``hostctl record --start`` receives the TELEMETRY velocity block, and its
vx, vy equal those of ``springtrack track`` on the same recording within the code's half
unit (wire.VEL_UNIT / 2 px/s), the dot's speed about 12,950 px/s; on the float kernel and on
the integer one (fixed/csrc/fixed_motion.c)."""
import subprocess

import numpy as np
import pytest

import springtrack.io
from springtrack import cli as st_cli
from springtrack import wire
from springtrack.track import read_csv

from support.dot_truth import dot_model_toml, dot_truth
from support.fwproc import Firmware, hostctl_cmd

pytestmark = [pytest.mark.hil, pytest.mark.slow]

MOTION_TOML = "[params]\nmotion_tau_us = 1000.0\npolarity_gain = 1.0\n"


@pytest.mark.parametrize("backend", ["cython", "fixed"])
def test_the_dots_velocity_reaches_the_host(tmp_path, data_file, backend):
    raw = str(data_file("evt2_sample.raw"))
    truth = dot_truth(springtrack.io.open(raw).read())
    (tmp_path / "dot.toml").write_text(dot_model_toml(truth))
    (tmp_path / "motion.toml").write_text(MOTION_TOML)
    opts = ["--model", str(tmp_path / "dot.toml"), "--params", str(tmp_path / "motion.toml"),
            "--backend", backend]
    fw = Firmware("--source", f"replay:{raw}", *opts, "--pty", "--wait-start")
    try:
        rec = subprocess.run(hostctl_cmd("--port", fw.path, "record", str(tmp_path / "r.csv"),
                                         "--start", "--seconds", "120"),
                             capture_output=True, text=True, timeout=180)
        assert rec.returncode == 0, rec.stderr
    finally:
        fw.close()
    track = read_csv(tmp_path / "r.csv")
    out = tmp_path / "t.csv"
    assert st_cli.main(["track", raw, *opts, "--out", str(out), "--no-progress"]) == 0
    offline = read_csv(out)
    assert np.array_equal(offline.t_us, track.t_us) and len(track) >= 45
    for k in ("vx", "vy"):
        assert np.abs(getattr(offline, k) - getattr(track, k)).max() <= wire.VEL_UNIT / 2
    speed = np.hypot(track.vx[10:, 0], track.vy[10:, 0])
    assert abs(np.median(speed) - truth.speed_px_s) < 0.1 * truth.speed_px_s
