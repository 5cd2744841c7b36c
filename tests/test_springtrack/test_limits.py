"""The limits every backend shares (springtrack/limits.py, docs/algorithm.md "Limits"): what
ShapeModel and Params accept runs on the float, fixed and reference kernels; what they refuse
is refused with a message naming it, before any kernel sees it."""
import math

import numpy as np
import pytest

import springtrack
from springtrack import limits, wire
from springtrack.events import make
from springtrack.model import Connection, ModelError, ShapeModel, TrackerSpec, face26, grid3x3
from springtrack.params import ParamError, Params
from springtrack.wire import Nack

ET = ("euclidean", "torsional")
ALL = ("euclidean", "torsional", "cartesian")


def pair(stiffness, springs=ET, mass_b=1.0):
    return ShapeModel("pair", 304, 240, [TrackerSpec("a", 100.0, 100.0, (25.0, 0.0, 25.0)),
                                         TrackerSpec("b", 140.0, 100.0, (25.0, 0.0, 25.0), mass_b)],
                      [Connection("a", "b", springs, stiffness)])


# ---- the reproductions: refused, with the reason ----------------------------------------
def test_unstable_springs_are_refused():
    with pytest.raises(ModelError, match=r"eye_l.*spring load 2\.5 exceeds 0\.5"):
        face26(stiffness=0.5)                  # the float kernel went NaN after ~58 k events
    with pytest.raises(ModelError, match="spring load 0.9 exceeds 0.5"):
        pair(0.9)
    with pytest.raises(ModelError, match=r"trackers\[1\] \('b'\): mass 1e-09 is outside"):
        pair(0.02, mass_b=1e-9)
    with pytest.raises(ModelError, match="mass 1e\\+30 is outside"):
        pair(0.02, mass_b=1e30)


def test_parameters_the_fixed_kernel_cannot_run_are_refused_by_params():
    with pytest.raises(ParamError, match=r"sigma_max_px=100.0 out of range \[0.5, 64.0\]"):
        Params(sigma_max_px=100.0)
    with pytest.raises(ParamError, match="alpha_covariance=1.0 is too large") as e:
        Params(alpha_covariance=1.0)
    assert e.value.code == Nack.OUT_OF_RANGE
    # the bound it names is the largest value accepted
    keep = float(str(e.value).rsplit("<= ", 1)[1])
    Params(alpha_covariance=keep * (1 - 1e-9))
    with pytest.raises(ParamError):
        Params(alpha_covariance=keep * (1 + 1e-6))


@pytest.mark.parametrize("backend", ["reference", "cython", "fixed"])
def test_a_huge_sigma_is_refused_for_every_backend(backend):
    with pytest.raises(ModelError, match="exceeds 1.04858e\\+06 px\\^2"):
        springtrack.Tracker(ShapeModel("big", 304, 240, [TrackerSpec("a", 100.0, 100.0,
                                                                     (1e12, 0.0, 1e12))], []),
                            backend=backend)
    # up to the model limit a sigma is accepted and clamped to sigma_max_px on load
    ok = ShapeModel("wide", 304, 240, [TrackerSpec("a", 100.0, 100.0, (1024.0 ** 2, 0.0, 1.0))], [])
    st = springtrack.Tracker(ok, backend=backend).state()
    assert st["sxx"][0] == pytest.approx(64.0 ** 2) and st["syy"][0] == pytest.approx(1.0)


def test_positions_and_sensor_are_bounded():
    x_lo, x_hi, y_lo, y_hi = limits.position_box(304, 240)
    assert (x_lo, x_hi, y_lo, y_hi) == (-304, 608, -240, 480)
    assert limits.position_box(8192, 100)[:2] == (-8191, 8191)
    for x, y in ((x_lo, y_lo), (x_hi - 1e-6, y_hi - 1e-6)):       # a model half out of view
        ShapeModel("m", 304, 240, [TrackerSpec("a", x, y, (4.0, 0.0, 4.0))], [])
    for x, y in ((x_lo - 1e-6, 0.0), (0.0, y_hi), (math.nan, 0.0)):
        with pytest.raises(ModelError, match="outside|finite"):
            ShapeModel("m", 304, 240, [TrackerSpec("a", x, y, (4.0, 0.0, 4.0))], [])
    with pytest.raises(ModelError, match=r"sensor.width must be an integer in \[1, 8192\]"):
        ShapeModel("m", 8193, 240, [TrackerSpec("a", 1.0, 1.0, (4.0, 0.0, 4.0))], [])


# ---- the spring bound, both ways --------------------------------------------------------
def at_load(model: ShapeModel, load: float) -> ShapeModel:
    """``model`` with every stiffness scaled so that its largest spring load is ``load``."""
    a = model.arrays()
    rho = limits.spring_loads(len(model.trackers), a["ca"], a["cb"], a["kinds"], a["stiffness"],
                              a["mass"]).max()
    conns = [Connection(c.a, c.b, c.springs, c.stiffness * load / rho) for c in model.connections]
    return ShapeModel(model.name, model.width, model.height, model.trackers, conns)


def lever():
    """Connections of 2 px and ~150 px on one tracker: eq. (15)'s mean angle couples them."""
    return ShapeModel("lever", 304, 240, [TrackerSpec("a", 100.0, 100.0, (4.0, 0.0, 4.0)),
                                          TrackerSpec("b", 102.0, 100.0, (4.0, 0.0, 4.0)),
                                          TrackerSpec("c", 250.0, 110.0, (4.0, 0.0, 4.0))],
                      [Connection("a", "b", ET, 0.1), Connection("b", "c", ET, 0.1),
                       Connection("a", "c", ET, 0.1)])


def chain():
    """Masses alternating 1/64 and 16 384 (the mass limits) along a chain of every kind."""
    return ShapeModel("chain", 304, 240,
                      [TrackerSpec(f"c{k}", 40.0 + 35 * k, 120.0, (9.0, 0.0, 9.0),
                                   limits.MASS_MIN if k % 2 else limits.MASS_MAX)
                       for k in range(7)],
                      [Connection(f"c{k}", f"c{k + 1}", ALL, 1e-4) for k in range(6)])


SHAPES = {"pair": lambda: pair(0.1, ALL), "face26": face26, "grid3x3": grid3x3,
          "lever": lever, "chain": chain}


def adversarial(model, n, seed=0):
    """Events 1-4 us apart, half anywhere on the sensor, half scattered about random
    trackers' rest positions by three times their sigma: with alpha_position = 1 each one
    throws the tracker it falls to onto itself, stretching and twisting its springs."""
    rng = np.random.default_rng(seed)
    a = model.arrays()
    k = rng.integers(0, len(a["x"]), n)
    x = a["x"][k] + 3 * np.sqrt(a["sxx"][k]) * rng.standard_normal(n)
    y = a["y"][k] + 3 * np.sqrt(a["syy"][k]) * rng.standard_normal(n)
    wild = rng.random(n) < 0.5
    x[wild] = rng.uniform(0, model.width, wild.sum())
    y[wild] = rng.uniform(0, model.height, wild.sum())
    x = np.clip(np.round(x), 0, model.width - 1)
    y = np.clip(np.round(y), 0, model.height - 1)
    return make(np.cumsum(rng.integers(1, 5, n)), x, y, np.ones(n))


# every spring update after every event, trackers thrown onto events, with and without the
# pull of eq. (22)
HARSH = [dict(alpha_position=1.0, spring_period=1, energy_scale=1e9),
         dict(alpha_position=1.0, spring_period=1, energy_gain=1.0, energy_kind="torsional"),
         dict(alpha_position=0.2, spring_period=7, energy_gain=0.5)]


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_just_outside_the_spring_bound_is_refused(shape):
    at_load(SHAPES[shape](), limits.SPRING_LOAD_MAX * (1 - 1e-12))
    with pytest.raises(ModelError, match="spring load"):
        at_load(SHAPES[shape](), limits.SPRING_LOAD_MAX * (1 + 1e-9))


@pytest.mark.parametrize("backend", ["cython", "fixed"])
@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_just_inside_the_spring_bound_stays_finite_on_an_adversarial_stream(shape, backend):
    m = at_load(SHAPES[shape](), limits.SPRING_LOAD_MAX * (1 - 1e-12))
    ev = adversarial(m, 200_000, seed=len(shape))
    x_lo, x_hi, y_lo, y_hi = limits.position_box(m.width, m.height)
    for prm in HARSH:
        tr = springtrack.Tracker(m, params=prm, backend=backend)
        for part in np.array_split(ev, 15):
            tr.process(part)
            st = tr.state()
            for f in ("x", "y", "sxx", "sxy", "syy", "activity"):
                assert np.all(np.isfinite(st[f])), (prm, f)
            assert np.all((st["x"] >= x_lo) & (st["x"] < x_hi)), prm
            assert np.all((st["y"] >= y_lo) & (st["y"] < y_hi)), prm
        assert np.all(np.isfinite(tr.energies()["mean"]))
        assert tr.counters["spring_updates"] > 0 and tr.counters["state_resets"] == 0


# ---- the state guard: what would escape the limits anyway is reset, never sent out --------
def fresh_state(model, backend):
    return springtrack.Tracker(model, backend=backend).state()


@pytest.mark.parametrize("backend", ["reference", "cython", "fixed"])
def test_the_guard_resets_a_state_that_left_the_box(backend):
    """A tracker thrown out of the position box (NaN for the float kernels, 5000 px for all)
    is caught by the next spring update: counted, and the whole state reset to the model,
    the same in the three kernels; tracking goes on from there."""
    from support import probes
    from springtrack.sim.synthetic import blob_stream
    m = grid3x3()
    ev, _ = blob_stream(m, 6000, seed=3)
    for bad in ([math.nan, 5000.0] if backend != "fixed" else [5000.0]):
        tr = springtrack.Tracker(m, backend=backend)
        tr.process(ev[:3000])
        k = tr._b
        if backend == "reference":
            k.ref.mx[4] = bad
        elif backend == "cython":
            probes.load("kernel_probe").place(k, 4, bad, 120.0)
        else:
            probes.load("fixed_probe").set_raw(k, 4, x=int(bad) << 32)
        (k.ref if backend == "reference" else k).springs()
        assert tr.counters["state_resets"] == 1
        st, want = tr.state(), fresh_state(m, backend)
        for f in ("x", "y", "sxx", "sxy", "syy", "activity", "active", "sensitive"):
            assert np.array_equal(st[f], want[f]), f
        assert tr.energies()["mean"] == 0.0
        tr.process(ev[3000:])
        assert np.all(np.isfinite(tr.state()["x"])) and tr.counters["events_assigned"] > 0


@pytest.mark.parametrize("backend", ["cython", "fixed"])
def test_past_the_bound_the_guard_keeps_every_sample_finite(monkeypatch, backend):
    """The lever at three times the spring bound (validation bypassed): its springs
    overshoot and grow, the guard resets the state (counted) and every sample stays finite
    and in the box; at the bound itself nothing is reset (above)."""
    from springtrack import model as _model
    m = at_load(lever(), limits.SPRING_LOAD_MAX)
    ev = adversarial(m, 100_000, seed=6)
    monkeypatch.setattr(_model, "validate", lambda m: None)
    monkeypatch.setattr(limits, "check_model", lambda *a, **k: None)
    unstable = at_load(lever(), 3 * limits.SPRING_LOAD_MAX)
    tr = springtrack.Tracker(unstable, params=HARSH[0], backend=backend)
    track = tr.run(ev, 100)
    assert tr.counters["state_resets"] > 0
    for f in ("x", "y", "sxx", "sxy", "syy", "activity", "energy"):
        assert np.all(np.isfinite(getattr(track, f))), f
    x_lo, x_hi, y_lo, y_hi = limits.position_box(m.width, m.height)
    assert np.all((track.x >= x_lo) & (track.x < x_hi) & (track.y >= y_lo) & (track.y < y_hi))


# ---- the firmware's path: NACKs, never a dead thread ------------------------------------
@pytest.fixture
def slot():
    from firmware_sim.slot import ModelSlot
    return ModelSlot("fixed", "face26")


@pytest.mark.parametrize("name,value", [("sigma_max_px", 100), ("alpha_covariance", 1)])
def test_param_set_the_fixed_kernel_cannot_run_is_nacked(slot, name, value):
    from firmware_sim.engine import UpdateRejected
    with pytest.raises(UpdateRejected) as e:
        slot.queue_param(name, value)
    assert e.value.code == Nack.OUT_OF_RANGE and name in str(e.value)
    assert not slot.pending


def test_model_uploads_that_cannot_run_are_invalid_models(slot):
    from firmware_sim.engine import UpdateRejected
    text = face26().to_toml()
    bad = [(text.replace("stiffness = 0.02", "stiffness = 0.5"), Nack.INVALID_MODEL),  # NaN
           (text.replace('name = "face26"', 'name = "' + "x" * 1200 + '"'),         # INFO over
            Nack.TOO_LONG),                                                          # a frame
           ('name = "deep"\nx = ' + "[" * 20_000 + "]" * 20_000 + "\n",            # parser
            Nack.INVALID_MODEL),                                                     # recursion
           (text.replace("mass = 1.0", "mass = 1e-9", 1), Nack.INVALID_MODEL)]
    for t, code in bad:
        with pytest.raises(UpdateRejected) as e:
            slot.queue_model(t)
        assert e.value.code == code, t[:40]
    assert not slot.pending


def test_the_longest_name_keeps_info_within_a_frame(slot):
    """A name of INFO_NAME_BUDGET bytes in INFO's JSON (the worst characters: outside the
    BMP, 12 bytes each) is accepted, and INFO with it and the largest values of everything
    else the firmware reports fits one frame; a byte more is refused."""
    from firmware_sim.loop import FIRMWARE
    emoji = "\U0001F600"
    name = emoji * (wire.INFO_NAME_BUDGET // 12) + "x" * (wire.INFO_NAME_BUDGET % 12)
    assert wire.info_name_bytes(name) == wire.INFO_NAME_BUDGET
    text = face26().to_toml().replace('name = "face26"', f'name = "{name}"')
    slot.queue_model(text)
    info = dict(firmware=FIRMWARE, backend="mcu:cortex-m4", width=8192, height=8192,
                max_trackers=limits.MAX_TRACKERS, max_connections=limits.MAX_CONNECTIONS,
                model=name, model_hash="f" * 16, running=True, generation=2 ** 32 - 1,
                telemetry_period_us=2 ** 32 - 1, trackers_omitted=limits.MAX_TRACKERS)
    payload = wire.encode_info(info, b"\xff" * wire.NONCE_LEN, True)
    assert len(payload) <= wire.MAX_PAYLOAD
    assert wire.decode_info(payload)["model"] == name
    from firmware_sim.engine import UpdateRejected
    with pytest.raises(UpdateRejected, match="bytes in INFO") as e:
        slot.queue_model(text.replace(name, name + "x"))
    assert e.value.code == Nack.TOO_LONG
