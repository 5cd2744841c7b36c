"""The similarity frame of eq. (22) and of the Cartesian springs (``pull_frame`` and
``cartesian_frame`` = "similarity", docs/algorithm.md): the mass-weighted Procrustes fit,
its fit set and degenerate cases, and the invariance it buys -- a rigidly turned and
scaled model at rest is neither pulled nor pushed -- in every backend."""
import math

import numpy as np
import pytest

import springtrack
from springtrack.model import Connection, ShapeModel, TrackerSpec, face26, grid3x3
from springtrack.params import Params
from springtrack.reference import FRAME_REFITS, FRAME_SCALE_MAX, FRAME_SCALE_MIN, ReferenceTracker
from support.springs import Springs, pose

SIMILARITY = dict(pull_frame="similarity", cartesian_frame="similarity")
IMAGE = dict(pull_frame="image", cartesian_frame="image")
FRAMES = {"similarity": SIMILARITY, "image": IMAGE}
# positions after one spring update: the float kernel equals the reference to rounding,
# the fixed-point kernel to its Q.16 fit (docs/fixed_point.md)
BACKENDS = {"reference": 1e-9, "cython": 1e-9, "fixed": 1e-4}


def weighted_model(stiffness=0.0):
    """face26 with unequal masses (the fit and G are mass-weighted); springs of this
    stiffness (0: the fit sees the placed configuration itself)."""
    m = face26(stiffness=stiffness)
    rng = np.random.default_rng(3)
    trackers = [TrackerSpec(t.id, t.x, t.y, t.sigma, float(rng.uniform(0.5, 3.0)))
                for t in m.trackers]
    return ShapeModel("face26w", m.width, m.height, trackers, m.connections)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_fit_recovers_a_rigid_turn_and_scale(backend):
    m = weighted_model()
    run = Springs(backend, m, dict(SIMILARITY, energy_scale=1e12))
    x, y = pose(m, 0.7, 1.25, (9.0, -4.0))
    run.update(x, y)
    f = run.tr.frame()
    tol = BACKENDS[backend]
    assert f["scale"] == pytest.approx(1.25, abs=tol)
    assert f["angle"] == pytest.approx(0.7, abs=tol)
    a = m.arrays()
    assert (f["gx"], f["gy"]) == pytest.approx((a["x"][0] - a["gdx0"][0] + 9.0,
                                                a["y"][0] - a["gdy0"][0] - 4.0), abs=tol)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("frame", FRAMES)
def test_a_turned_and_scaled_model_feels_no_cartesian_force_in_its_frame(backend, frame):
    """Cartesian springs (eqs. 18-20) hold the rest offsets s R d0 in the similarity
    frame: a grid turned by 40 deg and scaled by 0.75 is at rest there, and far from rest
    in the image frame (the paper's rule).  The springs use the frame fitted at the update
    before, so the grid is placed there anew for a few updates first (the frame then
    converges by a factor of about 20 per update)."""
    m = grid3x3(stiffness=0.05)
    run = Springs(backend, m, dict(FRAMES[frame], energy_scale=1e12))
    x, y = pose(m, math.radians(40), 0.75, (5.0, 3.0))
    nx, ny = run.update(x, y, times=12)
    moved = np.hypot(nx - x, ny - y).max()
    cart = run.tr.energies()["cartesian"]
    if frame == "similarity":
        assert moved < BACKENDS[backend] * 10
        assert cart.max() < BACKENDS[backend]
    else:
        assert moved > 1.0
        assert cart.min() > 1.0


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("frame", FRAMES)
def test_a_turned_and_scaled_model_is_not_pulled_in_its_frame(backend, frame):
    """eq. (22) pulls toward G + s R dG0 in the similarity frame: with every connection
    over the threshold (s = 0, the Euclidean energies of a scaled model are all > 0) and
    the full pull (gain 1), a turned and scaled face stays where it is; in the image frame
    it is pulled back toward the upright, unscaled shape.  Torsional springs only: they
    feel no rigid turn (eq. 15), and the Euclidean energies are computed all the same."""
    m = ShapeModel("f", 304, 240, face26().trackers,
                   [Connection(c.a, c.b, ("torsional",), 0.01) for c in face26().connections])
    run = Springs(backend, m, dict(FRAMES[frame], energy_scale=0.0, energy_gain=1.0,
                                   energy_kind="euclidean"))
    x, y = pose(m, math.radians(-35), 1.2, (-6.0, 2.0))
    nx, ny = run.update(x, y)
    assert (run.tr.energies()["euclidean"] > 0).all()         # every connection is over
    moved = np.hypot(nx - x, ny - y)
    if frame == "similarity":
        assert moved.max() < BACKENDS[backend] * 10
    else:
        assert moved.min() > 1.0


def test_the_fit_leaves_out_the_trackers_an_occluder_dragged():
    """The fit set is the trackers no over-threshold connection touches: a tracker dragged
    40 px off a turned and scaled grid stretches its connection to r0c1 over the threshold,
    so the fit sees the other seven trackers and finds the turn and scale exactly (a fit
    over all nine is tilted by the dragged one)."""
    m = grid3x3(stiffness=1e-12, springs=("euclidean",))   # energies, forces of ~1e-11 px
    tr = ReferenceTracker(m, Params(**SIMILARITY, energy_scale=2.0, energy_gain=0.0,
                                    energy_kind="euclidean"))
    x, y = pose(m, 0.3, 1.1, (4.0, 4.0))
    x[0] -= 40.0
    tr.mx, tr.my = [float(v) for v in x], [float(v) for v in y]
    tr.springs()
    c, s, _, _ = tr.frame()
    assert math.atan2(s, c) == pytest.approx(0.3, abs=1e-9)
    assert math.hypot(c, s) == pytest.approx(1.1, abs=1e-9)
    tr._fit_similarity(list(range(9)), dict.fromkeys(range(9), 1.0), 0)
    c, s, _, _ = tr.frame()
    assert abs(math.atan2(s, c) - 0.3) > 1e-3


def pulled_grid(dx):
    """grid3x3 turned by 0.3 rad and scaled by 1.1, r1c2 pulled ``dx`` px along the grid's
    own X axis; returns the model (Cartesian springs too weak to move anything), the
    positions and where r1c2 belongs."""
    m = grid3x3(stiffness=1e-12)
    x, y = pose(m, 0.3, 1.1, (4.0, 4.0))
    k = m.ids.index("r1c2")
    home = (x[k], y[k])
    x[k] += dx * math.cos(0.3)
    y[k] += dx * math.sin(0.3)
    return m, x, y, k, home


def test_the_fit_refits_without_a_pulled_part_that_no_connection_flags():
    """r1c2 has 3 of the grid's 12 connections: pulled away alone, each of them holds a
    quarter of the energy, under s = 4.5 times the mean, so the criteria leave it in the
    fit set; its residual in the fitted frame is over s times the set's mean, so the
    frame is refitted without it and finds the turn and scale of the other eight."""
    m, x, y, k, _ = pulled_grid(30.0)
    tr = ReferenceTracker(m, Params(**SIMILARITY, energy_scale=4.5, energy_gain=0.0,
                                    energy_kind="cartesian"))
    tr.mx, tr.my = [float(v) for v in x], [float(v) for v in y]
    assert tr.fit_frame([True] * 9) == {i: float(i == k) for i in range(9)}
    c, s, _, _ = tr.frame()
    assert (math.atan2(s, c), math.hypot(c, s)) == pytest.approx((0.3, 1.1), abs=1e-9)
    tr._fit_similarity(list(range(9)), dict.fromkeys(range(9), 1.0), 0)                        # all nine: dragged
    c, s, _, _ = tr.frame()
    assert abs(math.hypot(c, s) - 1.1) > 1e-2
    # s at or above the connection count: no connection is ever over, no tracker tested
    tr.set_params(Params(**SIMILARITY, energy_scale=12.0))
    assert tr.fit_frame([True] * 9) == {}


def test_the_refit_weights_are_continuous_in_the_residual():
    """Pulled by a little more at each step, r1c2 goes from agreeing (weight 1) to
    disagreeing (0) through the ramp between T and (1 + FRAME_RAMP) T, monotonically, and
    the frame's scale follows without a jump: kernels whose means differ by rounding fit
    the same frame."""
    dis, scale = [], []
    for dx in list(np.linspace(0.0, 0.6, 1201)) + [4.0]:
        m, x, y, k, _ = pulled_grid(dx)
        tr = ReferenceTracker(m, Params(**SIMILARITY, energy_scale=4.5, energy_gain=0.0,
                                        energy_kind="cartesian"))
        tr.mx, tr.my = [float(v) for v in x], [float(v) for v in y]
        dis.append(tr.fit_frame([True] * 9)[k])
        c, s, _, _ = tr.frame()
        scale.append(math.hypot(c, s))
    dis, scale = np.array(dis), np.array(scale)
    assert dis[0] == 0.0 and dis[-2] == 1.0 and dis[-1] == 1.0
    assert np.all(np.diff(dis) >= -1e-12)
    ramp = (dis > 0.0) & (dis < 1.0)
    assert ramp.sum() >= 5                                       # a ramp, not a step
    assert np.abs(np.diff(scale[:-1])).max() < 1e-4              # 5e-4 px steps of dx
    assert scale[-1] == pytest.approx(1.1, abs=1e-9)             # the others' scale


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_pulled_part_moves_neither_the_frame_nor_its_place_and_is_pulled_back(backend):
    """In every backend: the frame fitted with r1c2 pulled 30 px away is the other eight's
    turn and scale, and eq. (22) pulls r1c2 toward its place in it (gain 0.5: halfway),
    the others untouched."""
    m, x, y, k, home = pulled_grid(30.0)
    run = Springs(backend, m, dict(SIMILARITY, energy_scale=4.5, energy_gain=0.5,
                                   energy_kind="cartesian"))
    nx, ny = run.update(x, y)
    f = run.tr.frame()
    tol = BACKENDS[backend]
    assert (f["angle"], f["scale"]) == pytest.approx((0.3, 1.1), abs=tol)
    assert (nx[k], ny[k]) == pytest.approx((0.5 * (x[k] + home[0]), 0.5 * (y[k] + home[1])),
                                           abs=10 * tol)
    others = np.arange(9) != k
    assert np.abs(nx[others] - x[others]).max() < 10 * tol
    assert np.abs(ny[others] - y[others]).max() < 10 * tol


@pytest.mark.parametrize("backend", ["cython", "fixed"])
@pytest.mark.parametrize("dx,fits", [(0.0, 1), (30.0, 2), (0.34, 1 + FRAME_REFITS)])
def test_the_refits_stop_early_only_where_they_would_repeat_the_fit(backend, dx, fits):
    """The frame's refit loop (fit_frame) stops as soon as the weights a refit would use
    are those of the fit just made (or fewer than 2 trackers agree): that refit would
    reproduce the same frame.  The turned and scaled grid with r1c2 pulled dx px, its
    fits counted in the reference: all nine agreeing (dx = 0: the first weighting changes
    nothing, one fit), r1c2 pulled far (its weight 0 from the first refit on, the second
    weighting repeats the first: two fits), r1c2 on the ramp (its weight changes at every
    refit: all 1 + FRAME_REFITS fits).  In each, the kernel's frame and the positions
    eq. (22) pulls by how much each tracker disagrees equal the reference's (1e-9 px
    float, the fixed kernel's 1e-4): an exit that skipped a refit which changes the frame,
    or refitted differently, would show here."""
    m, x, y, k, _ = pulled_grid(dx)
    params = dict(SIMILARITY, energy_scale=4.5, energy_gain=0.5, energy_kind="cartesian")
    ref, run = Springs("reference", m, params), Springs(backend, m, params)
    calls, fit = [], ref.tr._b.ref._fit_similarity
    ref.tr._b.ref._fit_similarity = lambda *a: calls.append(a) or fit(*a)
    rx, ry = ref.update(x, y)
    assert len(calls) == fits
    bx, by = run.update(x, y)
    tol = BACKENDS[backend]
    np.testing.assert_allclose(run.tr._b.frame(), ref.tr._b.frame(), rtol=0, atol=tol)
    np.testing.assert_allclose(bx, rx, rtol=0, atol=10 * tol)
    np.testing.assert_allclose(by, ry, rtol=0, atol=10 * tol)
    moved = np.hypot(rx - x, ry - y)
    assert moved[k] > 0.05 if dx else moved.max() < 1e-9      # r1c2 pulled where it disagrees
    assert np.delete(moved, k).max() < 1e-9                    # the others agree: not pulled


def test_degenerate_fits():
    """Fewer than 2 calm trackers: the fit takes them all; rest points that coincide (no
    rotation to tell): s R = I, G the current centroid; a scale outside [1/4, 4] is held
    there, the rotation kept."""
    m = grid3x3(stiffness=0.0)
    tr = ReferenceTracker(m, Params(**SIMILARITY))
    x, y = pose(m, -0.4, 0.9)
    tr.mx, tr.my = [float(v) for v in x], [float(v) for v in y]
    tr.fit_frame([False] * 8 + [True])
    c, s, _, _ = tr.frame()
    assert (math.atan2(s, c), math.hypot(c, s)) == pytest.approx((-0.4, 0.9), abs=1e-12)
    for scale, held in ((0.1, FRAME_SCALE_MIN), (6.0, FRAME_SCALE_MAX)):
        x, y = pose(m, 1.0, scale)
        tr.mx, tr.my = [float(v) for v in x], [float(v) for v in y]
        tr.fit_frame([True] * 9)
        c, s, _, _ = tr.frame()
        assert (math.atan2(s, c), math.hypot(c, s)) == pytest.approx((1.0, held), abs=1e-12)
    tr.mx, tr.my = [150.0] * 9, [100.0] * 9                    # collapsed onto one point
    tr.fit_frame([True] * 9)
    assert tr.frame() == pytest.approx((FRAME_SCALE_MIN, 0.0, 150.0, 100.0), abs=1e-12)
    same = ShapeModel("two", 304, 240, [TrackerSpec("a", 50.0, 60.0, (4.0, 0.0, 4.0)),
                                        TrackerSpec("b", 50.0, 60.0, (4.0, 0.0, 4.0), 3.0)], [])
    tr = ReferenceTracker(same, Params(**SIMILARITY))
    tr.mx, tr.my = [70.0, 74.0], [61.0, 65.0]
    tr.fit_frame([True, True])
    assert tr.frame() == pytest.approx((1.0, 0.0, 73.0, 64.0), abs=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_coincident_rest_points_give_the_identity_frame(backend):
    """Rest points that coincide leave no rotation to fit: s R = I and G the trackers'
    weighted centroid, in every backend."""
    same = ShapeModel("two", 304, 240, [TrackerSpec("a", 50.0, 60.0, (4.0, 0.0, 4.0)),
                                        TrackerSpec("b", 50.0, 60.0, (4.0, 0.0, 4.0), 3.0)],
                      [Connection("a", "b", ("euclidean",), 0.0)])
    run = Springs(backend, same, dict(SIMILARITY, energy_scale=1e12))
    run.update([70.0, 74.0], [61.0, 65.0])
    f = run.tr.frame()
    tol = BACKENDS[backend]
    assert (f["scale"], f["angle"], f["gx"], f["gy"]) == pytest.approx((1.0, 0.0, 73.0, 64.0),
                                                                       abs=tol)


@pytest.mark.parametrize("backend", BACKENDS)
def test_backends_agree_on_degenerate_and_held_frames(backend):
    """The kernels take the reference's degenerate branches: a collapsed structure (scale
    held at 1/4) and an exploded one (held at 4).  (Collapsed onto one point exactly, the
    direction kept is that of rounding residue: each backend holds its own.)"""
    m = weighted_model()
    for scale in (0.05, 9.0):
        run = Springs(backend, m, dict(SIMILARITY, energy_scale=1e12))
        ref = Springs("reference", m, dict(SIMILARITY, energy_scale=1e12))
        x, y = pose(m, 2.5, scale, (3.0, 1.0))
        bx, by = run.update(x, y)
        rx, ry = ref.update(x, y)
        np.testing.assert_allclose(run.tr._b.frame(), ref.tr._b.frame(), rtol=0,
                                   atol=BACKENDS[backend])
        np.testing.assert_allclose(bx, rx, rtol=0, atol=BACKENDS[backend] * 100)
        np.testing.assert_allclose(by, ry, rtol=0, atol=BACKENDS[backend] * 100)


@pytest.fixture(scope="module")
def spinning_grid():
    """grid_spin at 30 deg/s for 10 s: 0 -> +90 -> -90 -> -60 deg in the image plane while
    translating (about 0.9 M events)."""
    from springtrack.metrics import truth_from_array
    from springtrack.sim.scenes import make_scene
    from springtrack.sim.sensor import simulate_all
    scene = make_scene("grid_spin", speed_deg_s=30.0)
    ev, truth = simulate_all(scene, 10.0, seed=0)
    return scene, ev, truth_from_array(truth)


@pytest.mark.slow
@pytest.mark.parametrize("springs,alpha,s", [(("euclidean", "torsional"), 0.001, 4.0),
                                             (("cartesian",), 0.001, 4.5),
                                             (("cartesian",), 0.016, 4.5)])
@pytest.mark.parametrize("frame", FRAMES)
def test_a_grid_turning_90_degrees_each_way_stays_tracked(spinning_grid, frame, springs, alpha,
                                                          s):
    """The paper's grid values (alpha1 = 0.02, alpha2 = 5e-5, its spring kinds, alpha and s)
    on a grid turning through +-90 deg in the image plane: in the similarity frame every
    tracker stays within 5 px of its part at every sample (parts are 50 px apart; 1.6-1.7 px
    measured).  In the image frame eq. (22) (Euclidean + torsional springs) and stiff
    Cartesian springs (alpha 0.016) drag the grid back upright (104 and 160 px); soft
    Cartesian springs (alpha 0.001) hold their image-frame rest offsets too weakly to, and
    every tracker stays within 5 px (4.2 px measured)."""
    from springtrack.metrics import score_track
    scene, ev, truth = spinning_grid
    model = scene.initial_model(stiffness=alpha, springs=springs)
    track = springtrack.Tracker(model, dict(FRAMES[frame], energy_scale=s)).run(ev, 1000)
    err = score_track(truth, track).err_px
    assert err.shape == (9999, 9)                        # every sample of every part scored
    if frame == "similarity" or (springs == ("cartesian",) and alpha < 0.01):
        assert err.max() < 5.0, err.max()
    else:
        assert err.max() > 25.0, err.max()               # some tracker lost its part
