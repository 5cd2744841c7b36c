"""Shape model TOML round trip, presets and every validation error."""
import math

import pytest

import springtrack
from springtrack import limits
from springtrack.model import ModelError, face26, grid3x3, load, load_model, loads
from springtrack.params import ParamError, Params, from_mapping

GOOD = """
name = "pair"
[sensor]
width = 304
height = 240
[[trackers]]
id = "a"
x = 100.0
y = 80.0
sigma = [25.0, 0.0, 25.0]
mass = 1.0
[[trackers]]
id = "b"
x = 150.0
y = 80.0
sigma = [25.0, 5.0, 16.0]
[[connections]]
a = "a"
b = "b"
springs = ["cartesian"]
stiffness = 0.001
[params]
alpha_position = 0.02
"""


def test_round_trip(tmp_path):
    m = loads(GOOD, "good.toml")
    assert m.ids == ["a", "b"] and m.trackers[1].mass == 1.0 and m.params == {"alpha_position": 0.02}
    p = tmp_path / "m.toml"
    m.save(p)
    m2 = load(p)
    assert m2.to_toml() == m.to_toml() and m2.digest() == m.digest()


@pytest.mark.parametrize("preset,n,nc", [("grid3x3", 9, 12), ("face26", 26, 40)])
def test_presets(preset, n, nc, tmp_path):
    m = springtrack.load_model(preset)
    assert (len(m.trackers), len(m.connections)) == (n, nc)
    p = tmp_path / f"{preset}.toml"
    m.save(p)
    assert springtrack.load_model(str(p)).to_toml() == m.to_toml()


def test_face26_structure():
    m = face26()
    assert all(c.springs == ("euclidean", "torsional") and c.stiffness == 0.02 for c in m.connections)
    internal = {"brow_l", "brow_r", "eye_l", "eye_r", "nostril_l", "nostril_r", "mouth"}
    assert internal <= set(m.ids)
    assert sum(i.startswith("outline") for i in m.ids) == 19
    big = face26(cx=300, cy=200, scale=240, width=640, height=480)
    assert big.trackers[0].x - 300 == pytest.approx(2 * (m.trackers[0].x - 152))


def test_equilibrium_comes_from_initial_positions():
    a = grid3x3(spacing=40).arrays()
    assert a["l0"][0] == pytest.approx(40.0) and a["th0"][0] == pytest.approx(0.0)
    assert a["gdx0"][4] == pytest.approx(0.0) and a["gdx0"][0] == pytest.approx(-40.0)


def bad(old, new):
    assert old in GOOD
    return GOOD.replace(old, new, 1)


@pytest.mark.parametrize("text,needle", [
    (bad('id = "b"', 'id = "a"'), "duplicate tracker id 'a'"),
    (bad('b = "b"', 'b = "zz"'), "unknown tracker id 'zz'"),
    (bad('b = "b"', 'b = "a"'), "to itself"),
    (bad("sigma = [25.0, 5.0, 16.0]", "sigma = [25.0, 30.0, 16.0]"), "not positive definite"),
    (bad("sigma = [25.0, 5.0, 16.0]", "sigma = [25.0, 5.0]"), "three finite numbers"),
    (bad("mass = 1.0", "mass = 0.0"), "mass must be positive"),
    (bad("stiffness = 0.001", "stiffness = -0.5"), "must not be negative"),
    (bad("x = 100.0", "x = nan"), "x must be a finite number"),
    (bad("stiffness = 0.001", "stiffness = inf"), "stiffness must be a finite number"),
    (bad('springs = ["cartesian"]', "springs = []"), "non-empty subset"),
    (bad('springs = ["cartesian"]', 'springs = ["elastic"]'), "unknown spring kind 'elastic'"),
    (bad("alpha_position = 0.02", "alpha_position = 2.0"), "alpha_position=2.0 out of range"),
    (bad("alpha_position = 0.02", "alpha_postion = 0.02"), "unknown parameter 'alpha_postion'"),
    (bad("width = 304", "width = -3"), "sensor.width"),
    (bad('x = 100.0', 'colour = "red"\nx = 100.0'), "unknown key(s) ['colour']"),
    ("name = 'x'\n[sensor]\nwidth = 10\n", "missing key 'height'"),
    ("name = 'x'\n[sensor\n", "not valid TOML"),
])
def test_validation_errors_name_file_and_entry(text, needle):
    with pytest.raises(ModelError) as e:
        loads(text, "bad.toml")
    assert needle in str(e.value)
    assert str(e.value).startswith("bad.toml")


def test_capacity_limits():
    trackers = "\n".join(f'[[trackers]]\nid = "t{i}"\nx = 1.0\ny = 1.0\nsigma = [1.0, 0.0, 1.0]'
                         for i in range(limits.MAX_TRACKERS + 1))
    with pytest.raises(ModelError, match="exceed the kernel capacity of 64"):
        loads(f'name = "big"\n[sensor]\nwidth = 10\nheight = 10\n{trackers}', "big.toml")


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(ModelError, match="no such model file"):
        springtrack.load_model(str(tmp_path / "nope.toml"))


def test_kernel_capacity_matches_limits():
    from springtrack.kernel import kernel as _kernel  # noqa: F401  (asserts at import)


@pytest.mark.parametrize("changes,needle", [
    ({"spring_period": 0}, "spring_period=0 out of range"),
    ({"spring_period": 5.5}, "whole number"),
    ({"energy_kind": "total"}, "energy_kind must be one of"),
    ({"pull_frame": "rotated"}, "pull_frame must be one of image, similarity"),
    ({"cartesian_frame": 1}, "cartesian_frame must be one of"),
    ({"alpha_covariance": "big"}, "must be a number"),
    ({"activity_tau_us": math.inf}, "must be finite"),
    ({"sigma_min_px": 10.0, "sigma_max_px": 5.0}, "must be below"),
])
def test_param_validation(changes, needle):
    with pytest.raises(ParamError, match=needle):
        from_mapping(changes)


def test_param_defaults_are_the_face_experiment():
    """The paper's face values; the criteria read the Cartesian energy (docs/parameters.md)."""
    p = Params()
    assert (p.alpha_position, p.alpha_covariance, p.p_threshold, p.energy_scale,
            p.spring_period, p.energy_kind) == (0.2, 2e-4, 0.1, 2.5, 55, "cartesian")


@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan, 10 ** 400])
def test_non_finite_integer_param_is_a_param_error(value):
    with pytest.raises(ParamError):
        from_mapping({"spring_period": value})


def test_toml_nested_too_deeply_is_a_model_error(tmp_path):
    """tomllib recurses once per nesting level: 20 000 levels are a ModelError with the
    firmware's invalid_model code (and a ParamError for a params file), refused before
    parsing (springtrack.toml_bounds)."""
    from springtrack import params as _params
    from springtrack.wire import Nack
    deep = 'name = "deep"\nx = ' + "[" * 20_000 + "]" * 20_000 + "\n"
    with pytest.raises(ModelError, match="nested too deeply") as e:
        loads(deep, "upload")
    assert e.value.code == Nack.INVALID_MODEL
    (tmp_path / "m.toml").write_text(deep)
    with pytest.raises(ModelError, match="m.toml: line 2: arrays or inline tables nested too deeply"):
        load_model(tmp_path / "m.toml")
    (tmp_path / "p.toml").write_text("a = " + "{b = " * 20_000 + "1" + "}" * 20_000 + "\n")
    with pytest.raises(_params.ParamError, match="p.toml: line 1: .* nested too deeply"):
        _params.load(tmp_path / "p.toml")
    (tmp_path / "bin.toml").write_bytes(b"name = \"\xff\"\n")
    with pytest.raises(ModelError, match="not valid TOML"):
        load_model(tmp_path / "bin.toml")
