"""The learner's parameters as options: ``--learn-param NAME=VALUE`` and a ``[learn]``
table in ``--params`` (learn, track --learn-first-ms, firmware-sim run), their errors,
and a params file's [learn] table left out of the tracking parameters."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from springtrack.cli import main as cli
from springtrack.events import EVENT_DTYPE
from springtrack import io as stio
from springtrack.learning.learner import learn_model
from springtrack.learning.settings import learn_overrides, parse_assignments
from springtrack.model import load
from springtrack.params import load as load_params

DOT_START_US = 1_317_888            # evt2_sample.raw's first event
DOT_WINDOW_US = 10_000


def dot_window(data_file):
    ev = stio.open(data_file("evt2_sample.raw")).read()
    return ev[ev["t"] < DOT_START_US + DOT_WINDOW_US]


def positions(model):
    return np.array([(t.x, t.y) for t in model.trackers])


def test_learn_param_and_learn_table_reach_the_learner(data_file, tmp_path, capsys):
    """The CLI's model equals the API's with the same overrides, and the overrides change
    what is learned (the dot's 10 ms: wider parts allowed, fewer events for a birth)."""
    ev = dot_window(data_file)
    default = learn_model(ev, width=640, height=480).model
    wanted = {"sigma_max_px": 24.0, "birth_events": 10}
    api = learn_model(ev, width=640, height=480, params=wanted).model
    assert len(api.trackers) != len(default.trackers)
    params = tmp_path / "p.toml"
    params.write_text("[learn]\nsigma_max_px = 24.0\n[params]\nalpha_position = 0.05\n")
    out = tmp_path / "m.toml"
    assert cli(["learn", str(data_file("evt2_sample.raw")), "--out", str(out), "--end-us",
                str(DOT_START_US + DOT_WINDOW_US), "--params", str(params),
                "--learn-param", "birth_events=10"]) == 0
    got = load(out)
    np.testing.assert_allclose(positions(got), positions(api), atol=1e-9)
    assert got.params["alpha_position"] == 0.05          # the [params] table still applies


@pytest.mark.parametrize("command", ["learn", "track"])
def test_help_lists_the_learner_parameters(command, capsys):
    with pytest.raises(SystemExit):
        cli([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--learn-param NAME=VALUE" in text and "life_tau_us" in text and "[learn]" in text


def test_learn_param_errors_name_the_way_out(tmp_path, capsys):
    np.save(tmp_path / "e.npy", np.zeros(0, EVENT_DTYPE))
    assert cli(["learn", str(tmp_path / "e.npy"), "--out", str(tmp_path / "m.toml"),
                "--learn-param", "sigma_max=24"]) == 2
    err = capsys.readouterr().err
    assert "--learn-param: unknown learner parameter(s) sigma_max" in err
    assert "sigma_max_px" in err                              # the valid names listed
    params = tmp_path / "p.toml"
    params.write_text("[learn]\nsigma_min_px = 30\n")        # above sigma_max_px
    assert cli(["learn", str(tmp_path / "e.npy"), "--out", str(tmp_path / "m.toml"),
                "--params", str(params)]) == 2
    assert f"{params} [learn]: learn: need 0 < sigma_min_px < sigma_max_px" in \
        capsys.readouterr().err


@pytest.mark.parametrize("item, message", [
    ("sigma_max_px", "takes NAME=VALUE"),
    ("=3", "takes NAME=VALUE"),
    ("sigma_max_px=wide", "'wide' is not a number"),
])
def test_assignments_refused(item, message):
    with pytest.raises(ValueError, match=message):
        parse_assignments([item])


def test_assignments_keep_integers_and_floats():
    assert parse_assignments(["batch_us=500", "sigma_max_px=24.0", "p_threshold=1e-1"]) == \
        {"batch_us": 500, "sigma_max_px": 24.0, "p_threshold": 0.1}


def test_overrides_refuse_bad_values_and_tables():
    with pytest.raises(ValueError, match="p_threshold must be in"):
        learn_overrides({"p_threshold": 2.0})
    with pytest.raises(ValueError, match="must be a table"):
        learn_overrides([1, 2], where="x.toml [learn]")


def test_learn_table_is_not_a_tracking_parameter(tmp_path):
    """A params file holding the tracking parameters at its top level and a [learn] table
    is read by the trackers without the [learn] table (not an unknown parameter)."""
    params = tmp_path / "p.toml"
    params.write_text("alpha_position = 0.07\n[learn]\nsigma_max_px = 24.0\n")
    assert load_params(params).alpha_position == 0.07


def test_firmware_learn_param_needs_learn_first_ms():
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        "sim:grid_pull", "--max-speed", "--seconds", "0.1", "--learn-param",
                        "sigma_max_px=24", "--stats-every", "0"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "--learn-param needs --learn-first-ms" in r.stderr
