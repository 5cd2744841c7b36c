"""Exact values of eqs. (6) and (22) where a misreading copied into every backend would show:
the activity increment off the tracker's mean (at the mean the kernel is exactly 1), and
eq. (22)'s pull in the image frame on both sides, in x and in y.  The expected values are
computed here from the paper's formulas, not from the code under test."""
import math

import numpy as np
import pytest

import springtrack
from springtrack.events import make
from springtrack.model import Connection, ShapeModel, TrackerSpec
from support.springs import Springs

TOL = {"reference": 1e-12, "cython": 1e-12, "fixed": 1e-5}   # fixed: its Q formats
NEVER = 10 ** 6


@pytest.mark.parametrize("backend", list(TOL))
@pytest.mark.parametrize("dx,dy", [(1, 0), (2, 0), (3, 0), (0, -2), (0, 4), (-2, 2), (3, -1)])
def test_eq6_the_activity_grows_by_the_kernel_value_off_the_mean(backend, dx, dy):
    """One tracker at (100, 80), Sigma = diag(4, 9): an event at (100 + dx, 80 + dy) has
    d^2 = dx^2/4 + dy^2/9 and raises the activity by exp(-d^2 / 2) (eq. 6 with eq. 2's
    unnormalised kernel), after the decay exp(-dt / tau) of what was there."""
    m = ShapeModel("one", 304, 240, [TrackerSpec("a", 100.0, 80.0, (4.0, 0.0, 9.0))], [])
    tau = 2000.0
    tr = springtrack.Tracker(m, dict(spring_period=NEVER, activity_tau_us=tau, alpha_position=0.0,
                                     alpha_covariance=0.0), backend=backend)
    d2 = dx * dx / 4.0 + dy * dy / 9.0
    assert d2 < -2.0 * math.log(tr.params.p_threshold)          # inside the gate
    tr.process(make([1000], [100 + dx], [80 + dy], [1]))
    a1 = math.exp(-0.5 * d2)
    assert tr.state()["activity"][0] == pytest.approx(a1, rel=TOL[backend], abs=TOL[backend])
    tr.process(make([3000], [100 - dx], [80 - dy], [1]))             # the mirror event, tau later
    a2 = a1 * math.exp(-2000.0 / tau) + math.exp(-0.5 * d2)
    assert tr.state()["activity"][0] == pytest.approx(a2, rel=TOL[backend], abs=TOL[backend])


def kite():
    """A triangle a-b-c and a pendant d on c, unit masses, Cartesian springs so soft that the
    spring step moves nothing measurable (1e-9: displacements ~1e-8 px)."""
    pts = {"a": (100.0, 100.0), "b": (120.0, 100.0), "c": (110.0, 115.0), "d": (110.0, 130.0)}
    return ShapeModel("kite", 304, 240,
                      [TrackerSpec(k, x, y, (4.0, 0.0, 4.0)) for k, (x, y) in pts.items()],
                      [Connection(p, q, ("cartesian",), 1e-9)
                       for p, q in (("a", "b"), ("b", "c"), ("c", "a"), ("c", "d"))])


@pytest.mark.parametrize("backend", list(TOL))
@pytest.mark.parametrize("shift", [(10.0, 0.0), (-10.0, 0.0), (0.0, 10.0), (0.0, -10.0),
                                   (6.0, -8.0)])
def test_eq22_pulls_toward_the_rest_offset_from_the_centre_of_mass_in_the_image_frame(
        backend, shift):
    """d dragged by (sx, sy): only c-d is strained (E_cd = 4 x the mean of the four > 2 x
    the mean), so eq. (22) pulls both its ends toward G + dG0_i, G the centre of mass after
    the spring step = G0 + (sx, sy) / 4, by energy_gain 0.5:
        d -> d0 + s + 0.5 (s/4 - s) = d0 + 0.625 s,   c -> c0 + 0.5 (s/4) = c0 + 0.125 s,
    a and b stay.  Both sides, in x and in y: a pull the wrong way or along the wrong axis
    lands px away."""
    sx, sy = shift
    m = kite()
    run = Springs(backend, m, dict(spring_period=NEVER, energy_kind="cartesian",
                                   energy_scale=2.0, energy_gain=0.5, pull_frame="image",
                                   cartesian_frame="image"))
    x0 = np.array([t.x for t in m.trackers])
    y0 = np.array([t.y for t in m.trackers])
    x, y = x0.copy(), y0.copy()
    x[3] += sx
    y[3] += sy
    bx, by = run.update(x, y)
    tol = max(TOL[backend], 1e-6)                          # the springs' own ~1e-8 px
    np.testing.assert_allclose(bx, x0 + np.array([0, 0, 0.125, 0.625]) * sx, rtol=0, atol=tol)
    np.testing.assert_allclose(by, y0 + np.array([0, 0, 0.125, 0.625]) * sy, rtol=0, atol=tol)
    st = run.tr.state(0)
    assert list(st["sensitive"]) == [True, True, True, False]      # eq. (21): d's one link over
