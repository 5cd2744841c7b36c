"""Moving an instance rigidly (ReferenceTracker.move, the backends' ``move``): means mapped by
the similarity, covariances turned and scaled, activities, sensitivities and deformation
kept; the float kernel equals the reference to 1e-9 px through the move and after it."""
import math

import numpy as np
import pytest

import probes
import springtrack
from springtrack.acquire import Pose, model_pose, place
from springtrack.instances import ModelSet
from springtrack.model import face26
from springtrack.reference import ReferenceTracker
from springtrack.synthetic import blob_stream

FIELDS = ("x", "y", "sxx", "sxy", "syy", "activity")
W, H = 320, 240


def similarity(model, dx, dy, deg, k):
    """(a, b, tx, ty) turning by ``deg`` and scaling by ``k`` about the model's centre of
    mass, then shifting by (dx, dy); and the model moved by it."""
    g = model_pose(model)
    c, s = k * math.cos(math.radians(deg)), k * math.sin(math.radians(deg))
    tx, ty = g.tx + dx - (c * g.tx - s * g.ty), g.ty + dy - (s * g.tx + c * g.ty)
    return (c, s, tx, ty), place(model, Pose(g.tx + dx, g.ty + dy, deg, k))


@pytest.mark.parametrize("dx, dy, deg, k", [(3.0, -2.0, 2.5, 1.0), (-40.0, 25.0, -30.0, 1.2),
                                            (0.0, 0.0, 90.0, 0.8)])
def test_move_maps_means_and_covariances_and_keeps_activity_and_deformation(dx, dy, deg, k):
    f = face26(width=W, height=H)
    ref = ReferenceTracker(ModelSet([f, f], {"spring_period": 5}))
    ev, _ = blob_stream(f, 3000, seed=2)
    for t, x, y in zip(ev["t"].tolist(), ev["x"].tolist(), ev["y"].tolist()):
        ref.step(t, x, y)
    before = [list(v) for v in (ref.mx, ref.my, ref.sxx, ref.sxy, ref.syy, ref.act,
                                ref.tlast, ref.sensitive)]
    frame0 = ref.frame(1)
    sim, moved = similarity(f, dx, dy, deg, k)
    ref.move(1, sim, moved)
    a, b, tx, ty = sim
    A = np.array([[a, -b], [b, a]])
    for i in range(26, 52):
        want = A @ [before[0][i], before[1][i]] + [tx, ty]
        assert ref.mx[i] == pytest.approx(want[0], abs=1e-9)
        assert ref.my[i] == pytest.approx(want[1], abs=1e-9)
        S = A @ np.array([[before[2][i], before[3][i]], [before[3][i], before[4][i]]]) @ A.T
        sxx = min(max(S[0, 0], ref.smin2), ref.smax2)   # within the kernels' clamps
        assert ref.sxx[i] == pytest.approx(sxx, rel=1e-12)
    # the other instance, activities, sensitivities untouched; the frame's centre mapped
    assert ref.mx[:26] == before[0][:26] and ref.act == before[5] and ref.tlast == before[6]
    assert ref.sensitive == before[7]
    c, s, gx, gy = ref.frame(1)
    assert (c, s) == frame0[:2]
    assert (gx, gy) == pytest.approx(tuple(A @ frame0[2:] + [tx, ty]), abs=1e-9)
    # deformation kept: the trackers' offsets from the moved rest shape are the old ones,
    # turned and scaled
    rest = f.arrays()
    old = np.array([before[0][26:], before[1][26:]]) - np.array([rest["x"], rest["y"]])
    mv = moved.arrays()
    new = np.array([ref.mx[26:], ref.my[26:]]) - np.array([mv["x"], mv["y"]])
    np.testing.assert_allclose(new, A @ old, atol=1e-9)
    np.testing.assert_allclose(ref.l0[40:], np.asarray(f.arrays()["l0"]) * k, rtol=1e-12)


@pytest.mark.parametrize("dx, dy, deg, k", [(2.5, -3.0, 3.0, 1.0), (-30.0, 20.0, -25.0, 1.15)])
def test_move_in_the_float_kernel_equals_the_reference(dx, dy, deg, k):
    """Kernel and reference moved alike between two runs of a face stream: every field
    within 1e-9 px at every sample, the spatial index rebuilt."""
    f = face26(width=W, height=H)
    ev, _ = blob_stream(f, 30000, seed=3)
    half = len(ev) // 2
    sim, moved = similarity(f, dx, dy, deg, k)
    # the stream's second half follows the face to its new place
    ev2 = ev[half:].copy()
    a, b, tx, ty = sim
    x, y = ev2["x"].astype(float), ev2["y"].astype(float)
    nx, ny = np.rint(a * x - b * y + tx), np.rint(b * x + a * y + ty)
    keep = (nx >= 0) & (nx < W) & (ny >= 0) & (ny < H)
    ev2 = ev2[keep]
    ev2["x"], ev2["y"] = nx[keep], ny[keep]
    tracks = {}
    for backend in ("cython", "reference"):
        tr = springtrack.Tracker(f, {"spring_period": 5}, backend=backend)
        t1 = tr.run(ev[:half], 1000)
        tr._ib.move(0, sim, moved)
        mid = tr.state()
        t2 = tr.run(ev2, 1000)
        tracks[backend] = (t1, mid, t2, tr)
    (a1, am, a2, ta), (b1, bm, b2, tb) = tracks["cython"], tracks["reference"]
    for fld in FIELDS:
        np.testing.assert_allclose(am[fld], bm[fld], rtol=0, atol=1e-9, err_msg=fld)
        for p, q in ((a1, b1), (a2, b2)):
            np.testing.assert_allclose(getattr(p, fld), getattr(q, fld), rtol=0, atol=1e-9,
                                       err_msg=fld)
    assert (a2.sensitive == b2.sensitive).all() and (a2.active == b2.active).all()
    fa, fb = ta.frame(), tb.frame()
    for key in fb:
        np.testing.assert_allclose(fa[key], fb[key], rtol=0, atol=1e-9, err_msg=key)
    assert ta.counters["events_assigned"] == tb.counters["events_assigned"]
    probes.load("kernel_probe").check_index(ta._b)


@pytest.mark.parametrize("backend", ["fixed", "mcu"])
def test_backends_that_cannot_move_say_so(backend):
    f = face26(width=W, height=H)
    try:
        tr = springtrack.Tracker(f, backend=backend)
    except ValueError as e:                  # no toolchain for the mcu build
        pytest.skip(str(e))
    assert not tr._ib.movable
    sim, moved = similarity(f, 1.0, 0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="cannot move an instance"):
        tr._ib.move(0, sim, moved)
