"""Each limit of a model (springtrack/limits.py) just inside and just outside, one axis or
entry at a time: a check that tests one field twice and another never (sxx for syy, x for
y) lets the untested one through, and these catch it."""
import math

import pytest

import springtrack
from springtrack import limits
from springtrack.model import Connection, ModelError, ShapeModel, TrackerSpec

VAR_MAX = limits.MODEL_SIGMA_MAX_PX ** 2
ABOVE = math.nextafter(VAR_MAX, math.inf)


def one(sigma=(25.0, 0.0, 25.0), x=100.0, y=100.0, mass=1.0, w=304, h=240):
    return ShapeModel("one", w, h, [TrackerSpec("a", x, y, sigma, mass)], [])


@pytest.mark.parametrize("axis", ["sxx", "syy"])
def test_each_variance_at_the_limit_is_accepted_and_just_above_refused(axis):
    at = (VAR_MAX, 0.0, 1.0) if axis == "sxx" else (1.0, 0.0, VAR_MAX)
    over = (ABOVE, 0.0, 1.0) if axis == "sxx" else (1.0, 0.0, ABOVE)
    one(at)                                               # exactly the limit: accepted
    with pytest.raises(ModelError, match=r"exceeds 1\.04858e\+06 px\^2"):
        one(over)
    with pytest.raises(ModelError, match=r"exceeds 1\.04858e\+06 px\^2"):
        one((1e12, 0.0, 1.0) if axis == "sxx" else (1.0, 0.0, 1e12))


@pytest.mark.parametrize("backend", ["reference", "cython", "fixed"])
def test_a_huge_syy_alone_is_refused_for_every_backend(backend):
    """syy = 1e12 with a modest sxx: refused before any kernel sees it (accepted, the float
    backends would clamp it and the fixed one load a wrapped value)."""
    with pytest.raises(ModelError, match="exceeds"):
        springtrack.Tracker(one((4.0, 0.0, 1e12)), backend=backend)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_covariance_is_refused(bad):
    with pytest.raises(ModelError):
        one((4.0, bad, 4.0))
    with pytest.raises(ModelError):
        one((bad, 0.0, 4.0))
    with pytest.raises(ModelError):
        one((4.0, 0.0, bad))


@pytest.mark.parametrize("key", ["x", "y"])
def test_each_position_at_the_box_edges(key):
    x_lo, x_hi, y_lo, y_hi = limits.position_box(304, 240)
    lo, hi = (x_lo, x_hi) if key == "x" else (y_lo, y_hi)
    other = 100.0
    pos = (lambda v: dict(x=v, y=other)) if key == "x" else (lambda v: dict(x=other, y=v))
    one(**pos(float(lo)))                                 # the lower edge is inside
    one(**pos(math.nextafter(hi, -math.inf)))             # just below the upper edge
    for v in (math.nextafter(lo, -math.inf), float(hi)):
        with pytest.raises(ModelError, match=f"{key}="):
            one(**pos(v))
    with pytest.raises(ModelError, match=f"{key} must be a finite number"):
        one(**pos(math.nan))


def test_mass_at_and_beyond_its_bounds():
    one(mass=limits.MASS_MIN)
    one(mass=limits.MASS_MAX)
    for m in (math.nextafter(limits.MASS_MIN, 0.0), math.nextafter(limits.MASS_MAX, math.inf)):
        with pytest.raises(ModelError, match="mass"):
            one(mass=m)


def pair(stiffness, kinds=("euclidean",), mass=1.0):
    return ShapeModel("pair", 304, 240, [TrackerSpec("a", 100.0, 100.0, (25.0, 0.0, 25.0), mass),
                                         TrackerSpec("b", 140.0, 100.0, (25.0, 0.0, 25.0), mass)],
                      [Connection("a", "b", kinds, stiffness)])


def test_stiffness_and_spring_load_at_and_beyond_their_bounds():
    """Load = stiffness (twice with a Cartesian spring beside a Euclidean or torsional one)
    / mass, at most 0.5; stiffness at most 1.  Exactly at each bound: accepted; one ulp
    beyond: refused, naming it."""
    pair(0.5)                                             # load exactly 0.5
    pair(0.5, ("cartesian",))
    pair(0.25, ("euclidean", "cartesian"))                # counted twice: 0.5
    with pytest.raises(ModelError, match="spring load"):
        pair(math.nextafter(0.5, 1.0))
    with pytest.raises(ModelError, match="spring load"):
        pair(math.nextafter(0.5, 1.0), ("cartesian",))
    with pytest.raises(ModelError, match="spring load"):
        pair(math.nextafter(0.25, 1.0), ("euclidean", "cartesian"))
    pair(1.0, mass=2.0)                                   # stiffness 1 (load 0.5)
    with pytest.raises(ModelError, match="stiffness"):
        pair(math.nextafter(1.0, 2.0), mass=4.0)
    with pytest.raises(ModelError, match="stiffness"):
        pair(-1e-300)
