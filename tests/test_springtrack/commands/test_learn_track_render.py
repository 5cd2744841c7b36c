"""A user's path with no model: `track --learn-first-ms --model-out` keeps the model it
learned, and `render --model --track` draws that track over the events, its frames in the
span --start-us / --end-us asks for."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from springtrack.model import load
from springtrack.sim import screen
from springtrack.sim.screen.pixels import ScreenConfig
from springtrack.track import read_csv


def cli(*args):
    return subprocess.run([sys.executable, "-m", "springtrack.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    ev, _ = screen.simulate_all("shapes_handheld", 0.15, seed=0,
                                config=ScreenConfig(refresh_hz=1000.0))
    path = tmp_path_factory.mktemp("hh") / "hh.npy"
    np.save(path, ev)
    return path


@pytest.mark.slow
def test_track_keeps_the_learned_model_and_render_draws_its_track(recording, tmp_path):
    model, track = tmp_path / "m.toml", tmp_path / "t.csv"
    r = cli("track", recording, "--learn-first-ms", 30, "--out", track, "--model-out", model,
            "--no-progress")
    assert r.returncode == 0, r.stderr
    assert f"wrote the learned model to {model}" in r.stderr
    m, t = load(model), read_csv(track)
    assert [s.id for s in m.trackers] == t.ids
    assert t.t_us[0] >= 30_000                       # tracked from the window's end
    out = tmp_path / "frames"
    r = cli("render", recording, "--model", model, "--track", track, "--out", out,
            "--start-us", 100_000, "--end-us", 130_000, "--window-us", 10_000)
    assert r.returncode == 0, r.stderr
    # two frames (110 and 120 ms), not the 11 of the whole track (30-150 ms)
    assert "wrote" in r.stderr and len(list(out.glob("frame_*.png"))) == 2
    r = cli("render", recording, "--model", model, "--track", track, "--out", tmp_path / "x.png",
            "--start-us", 200_000)
    assert r.returncode == 2 and "no samples between --start-us and --end-us" in r.stderr


def test_model_out_needs_learn_first_ms(recording, tmp_path):
    r = cli("track", recording, "--model", "grid3x3", "--sensor-from", "file",
            "--model-out", tmp_path / "m.toml", "--out", tmp_path / "t.csv")
    assert r.returncode == 2 and "--model-out writes the model --learn-first-ms learns" in r.stderr
    assert not (tmp_path / "m.toml").exists()
