"""Putting single trackers elsewhere (ReferenceTracker.relocate, the backends' ``relocate``,
used by the recall of trackers left behind): the trackers named take their new means and
covariances and activity 0, every other tracker keeps its state (its activity included:
a recall no longer blanks the instance); the float kernel equals the reference to 1e-9
px through it, the fixed kernel (fx_relocate) stays within its bound, the microcontroller
build equals the fixed kernel bit for bit."""
import numpy as np
import pytest

import springtrack
from springtrack.model import face26
from springtrack.sim.synthetic import blob_stream

FIELDS = ("x", "y", "sxx", "sxy", "syy", "activity")
W, H = 320, 240
IDX = np.array([3, 11, 20])
NEW = dict(x=np.array([40.5, 250.25, 160.0]), y=np.array([30.0, 200.75, 120.5]),
           sxx=np.array([9.0, 16.0, 30.0]), sxy=np.array([1.5, -2.0, 0.0]),
           syy=np.array([12.0, 16.0, 25.0]))


def run_relocated(backend: str, n: int = 20000, **params):
    """(state just before, state just after the relocation, track after, tracker)."""
    f = face26(width=W, height=H)
    ev, _ = blob_stream(f, n, seed=4)
    half = len(ev) // 2
    tr = springtrack.Tracker(f, {"spring_period": 5, **params}, backend=backend)
    tr.run(ev[:half], 1000)
    t = int(ev["t"][half - 1])
    before = tr.state(t)
    tr._ib.relocate(0, IDX, *(NEW[k] for k in ("x", "y", "sxx", "sxy", "syy")))
    after = tr.state(t)
    return before, after, tr.run(ev[half:], 1000), tr


def test_relocate_moves_only_the_trackers_named_and_keeps_the_others_activities():
    before, after, _, _ = run_relocated("reference")
    others = np.setdiff1d(np.arange(26), IDX)
    for k in ("x", "y", "sxx", "sxy", "syy"):
        np.testing.assert_array_equal(after[k][IDX], NEW[k])     # inside the clamps
        np.testing.assert_array_equal(after[k][others], before[k][others])
    assert np.all(after["activity"][IDX] == 0.0)
    np.testing.assert_array_equal(after["activity"][others], before["activity"][others])
    assert before["activity"][others].min() > 0                  # not blanked


def test_a_relocated_trackers_motion_starts_again_and_the_others_keep_theirs():
    before, after, _, _ = run_relocated("reference", motion_tau_us=20_000.0)
    others = np.setdiff1d(np.arange(26), IDX)
    assert np.all(after["vx"][IDX] == 0.0) and np.all(after["vy"][IDX] == 0.0)
    assert np.any(before["vx"][IDX] != 0.0)
    np.testing.assert_array_equal(after["vx"][others], before["vx"][others])


@pytest.mark.parametrize("params", [{}, {"motion_tau_us": 20_000.0}])
def test_relocate_in_the_float_kernel_equals_the_reference(params):
    """With the motion model too: a relocated tracker's motion starts again as placed."""
    (b0, b1, b2, tb), (r0, r1, r2, tr) = (run_relocated(b, **params)
                                          for b in ("cython", "reference"))
    for fld in FIELDS:
        np.testing.assert_allclose(b1[fld], r1[fld], rtol=0, atol=1e-9, err_msg=fld)
        np.testing.assert_allclose(getattr(b2, fld), getattr(r2, fld), rtol=0, atol=1e-9,
                                   err_msg=fld)
    assert tb.counters["events_assigned"] == tr.counters["events_assigned"]


def test_relocate_in_the_fixed_kernel_stays_within_its_bound():
    from support.fixed_bound import figures, violations
    (_, _, a2, _), (_, _, b2, _) = run_relocated("cython"), run_relocated("fixed")
    res = figures(a2, b2)
    assert not violations(res), violations(res)
    assert len(a2) > 25


def test_relocate_refuses_a_tracker_outside_the_instance():
    for backend in ("reference", "cython", "fixed"):
        tr = springtrack.Tracker(face26(width=W, height=H), backend=backend)
        with pytest.raises((IndexError, ValueError)):
            tr._ib.relocate(0, [26], [10.0], [10.0], [4.0], [0.0], [4.0])


@pytest.mark.slow
def test_relocate_in_the_firmware_equals_the_host():
    """fx_relocate in the firmware (MCU_RELOCATE): the same integers as the host's."""
    (a0, a1, a2, ta), (b0, b1, b2, tb) = run_relocated("fixed", 8000), run_relocated("mcu", 8000)
    assert a1.tobytes() == b1.tobytes()
    for fld in FIELDS:
        assert np.array_equal(getattr(a2, fld), getattr(b2, fld)), fld
    assert ta.counters == tb.counters
