"""The fixed-point kernel's telemetry records come straight from its integer state
(fixed/csrc/fixed_telemetry.c), in springtrack.wire's TELE_TRACKER layout, and agree with
wire.quantise_trackers of the float view of the same state."""
import numpy as np
import pytest

from support import probes
from springtrack import wire
from springtrack.tracker import Tracker, make_backend
from springtrack.sim.sensor import simulate_all

FIELDS = ("x", "y", "sx", "sy", "rho", "act")


@pytest.fixture(scope="module")
def states():
    """(float-view snapshot, integer records) at 300 times of a face run."""
    ev, _ = simulate_all("face_occlusion", 1.0, seed=3)
    tr = Tracker("face26")
    k = make_backend("fixed", tr.model, tr.params)
    out = []
    for chunk in np.array_split(ev, 300):
        k.run(chunk, 0, 0, 0)
        t = int(chunk["t"][-1]) + 1
        snap = k.snapshot(t)
        rec = np.zeros(len(snap["x"]), wire.TRACK_DTYPE)
        for f in ("x", "y", "sxx", "sxy", "syy", "activity", "active", "sensitive"):
            rec[f] = snap[f]
        out.append((rec, k.telemetry_records(t)))
    return out


def codes(payload: bytes) -> np.ndarray:
    return np.frombuffer(payload, wire.TELE_TRACKER)


def test_integer_records_equal_the_float_encoder_within_one_code(states):
    exact = total = 0
    for rec, native in states:
        want = wire.quantise_trackers(rec)
        got = codes(native)
        for f in FIELDS:
            d = np.abs(got[f].astype(int) - want[f].astype(int))
            assert d.max() <= 1, f
            exact += int(np.sum(d == 0))
            total += d.size
        assert np.array_equal(got["x"] >> 15, want["x"] >> 15)        # active flag
        assert np.array_equal(got["y"] >> 15, want["y"] >> 15)        # sensitive flag
    assert exact / total > 0.999           # a code differs only on rounding near a tie


def test_records_decode_to_the_state_within_the_wire_resolution(states):
    rec, native = states[-1]
    payload = wire.encode_telemetry(123, 4, 0.5, native)
    t, gen, me, dec = wire.decode_telemetry(payload)
    assert (t, gen, me) == (123, 4, 0.5)
    assert np.all(np.abs(dec["x"] - rec["x"]) <= 1 / 32 + 1e-12)
    assert np.all(np.abs(np.sqrt(dec["sxx"]) - np.sqrt(rec["sxx"])) <= 1 / 8 + 1e-12)


def test_hand_computed_record():
    """One tracker at (10.5 px, 20.25 px), sxx = 4, syy = 9, sxy = -3 px^2 (sigma 2, 3 px,
    rho = -0.5), activity exactly 3 at t = its last update: x = 168, y = 324 (1/16 px),
    sx = 8, sy = 12 (1/4 px), rho = round(-63.5) = -64 (half away from zero), act =
    round(16 log2 4) = 32."""
    from springtrack.model import loads
    m = loads("""name = "one"
[sensor]
width = 64
height = 64
[[trackers]]
id = "a"
x = 10.5
y = 20.25
sigma = [4.0, -3.0, 9.0]
mass = 1.0
""")
    tr = Tracker(m)
    k = make_backend("fixed", tr.model, tr.params)
    fx = probes.load("fixed_probe")
    fx.set_raw(k, 0, act=3 << 32)                       # Q.32; no event yet: no decay at t=0
    r = codes(k.telemetry_records(0))[0]
    assert (r["x"] & 0x7FFF, r["y"] & 0x7FFF, r["sx"], r["sy"], r["rho"], r["act"]) == (
        168, 324, 8, 12, -64, 32)


def test_telemetry_records_reject_a_payload_that_is_not_whole_records():
    with pytest.raises(wire.WireError, match="whole 8-byte records"):
        wire.encode_telemetry(0, 0, 0.0, b"\x00" * 12)
