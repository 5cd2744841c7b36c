"""Behaviour of the tracker as a whole: convergence, springs, occlusion, invariance."""
import math

import numpy as np
import pytest

import springtrack
from springtrack.events import make
from springtrack.model import Connection, ShapeModel, TrackerSpec, face26, grid3x3
from springtrack.reference import ReferenceTracker
from springtrack.params import Params
from springtrack.sim.synthetic import blob_stream


@pytest.mark.parametrize("a1", [0.001, 0.01, 0.1, 0.3])
def test_blob_size_converges_to_the_true_covariance(a1):
    """Deliver 5(c): a tracker fed events from a fixed Gaussian converges to its mean and
    covariance within 10 % for alpha_position from 0.001 to 0.3."""
    C = np.array([[36.0, 12.0], [12.0, 16.0]])
    mu = np.array([150.0, 120.0])
    m = ShapeModel("one", 304, 240, [TrackerSpec("a", 146.0, 123.0, (20.0, 0.0, 20.0))], [])
    tr = springtrack.Tracker(m, dict(alpha_position=a1, alpha_covariance=1e-3,
                                     sigma_min_px=0.5, activity_threshold=0.0))
    rng = np.random.default_rng(11)
    n = 400_000
    u = rng.multivariate_normal(mu, C, size=n)
    ev = make(np.arange(n) * 5, np.round(u[:, 0]), np.round(u[:, 1]), 1)
    track = tr.run(ev, sample_us=1000)
    late = slice(len(track) // 2, None)
    # pixel quantisation adds 1/12 px^2 to the variances of the event cloud
    got = np.array([track.sxx[late].mean(), track.sxy[late].mean(), track.syy[late].mean()])
    want = np.array([36 + 1 / 12, 12, 16 + 1 / 12])
    assert np.all(np.abs(got - want) <= 0.10 * np.array([want[0], want[0], want[2]])), got
    assert np.hypot(track.x[late].mean() - mu[0], track.y[late].mean() - mu[1]) < 0.5


def test_uncorrected_gate_would_collapse_the_blob():
    """The bias the correction removes is real: with the literal reading (dS about the
    moved mean, no truncation factor), a1 = 0.2 shrinks the ellipse far below the blob."""
    C = 25.0
    ref = ReferenceTracker(ShapeModel("one", 304, 240, [TrackerSpec("a", 150.0, 120.0, (C, 0.0, C))], []),
                           Params(alpha_position=0.2, alpha_covariance=1e-2, spring_period=10 ** 6))
    rng = np.random.default_rng(2)
    sxx = C
    mx = my = None
    mx, my, syy, sxy = 150.0, 120.0, C, 0.0
    for x, y in rng.normal(0, 5, size=(20000, 2)) + [150, 120]:
        det = sxx * syy - sxy * sxy
        dx, dy = x - mx, y - my
        if (syy * dx * dx + sxx * dy * dy - 2 * sxy * dx * dy) / det < ref.gate:
            mx, my = mx + 0.2 * dx, my + 0.2 * dy
            dx, dy = x - mx, y - my                       # literal eq. (5): moved mean
            sxx = 0.99 * sxx + 0.01 * dx * dx
            syy = 0.99 * syy + 0.01 * dy * dy
            sxy = 0.99 * sxy + 0.01 * dx * dy
    assert sxx < 0.2 * C


def test_springs_relax_a_displaced_tracker_exponentially():
    m = grid3x3(stiffness=0.05)
    tr = ReferenceTracker(m, Params(spring_period=1, energy_scale=1e12, energy_kind="cartesian"))
    eq = (tr.mx[4], tr.my[4])
    tr.mx[4] += 10.0                                   # centre tracker pushed 10 px right
    dist, energy = [], []
    for k in range(200):
        tr.springs()
        dist.append(math.hypot(tr.mx[4] - tr.mx[3] - 50.0, tr.my[4] - tr.my[3]))
        energy.append(sum(tr.energy[2]))
    assert dist[-1] < 0.01 * dist[0]
    assert all(b <= a + 1e-12 for a, b in zip(energy, energy[1:]))   # energy never grows


def test_torsional_energy_is_zero_for_a_rigid_rotation():
    m = face26()
    tr = ReferenceTracker(m, Params(spring_period=10 ** 6, energy_scale=1e12))
    a = m.arrays()
    cx, cy = a["x"].mean(), a["y"].mean()
    ang = math.radians(30)
    for i in range(tr.n):
        dx, dy = a["x"][i] - cx, a["y"][i] - cy
        tr.mx[i] = cx + math.cos(ang) * dx - math.sin(ang) * dy
        tr.my[i] = cy + math.sin(ang) * dx + math.cos(ang) * dy
    before = list(tr.mx), list(tr.my)
    tr.springs()
    assert max(tr.energy[1]) < 1e-20                   # eq. (15) removes the common rotation
    assert max(tr.energy[0]) < 1e-20                   # lengths unchanged too
    assert max(tr.energy[2]) > 1.0                     # Cartesian springs do feel it
    assert np.allclose(tr.mx, before[0], atol=1e-9) and np.allclose(tr.my, before[1], atol=1e-9)


def pulled_grid_stream(seed=5, dragged=(0,)):
    """grid3x3 blobs at rest; the ``dragged`` blobs (r0c0) are dragged 40 px up-left between
    0.3 s and 1.3 s and stay there (an occluder or a wrong cloud), then events continue to
    2 s."""
    m = grid3x3()
    a = m.arrays()
    rng = np.random.default_rng(seed)
    n = 400_000
    t = np.sort(rng.integers(0, 2_000_000, n))
    k = rng.integers(0, 9, n)
    frac = np.clip((t - 300_000) / 1_000_000, 0, 1)
    off = 40 / math.sqrt(2) * frac * np.isin(k, dragged)
    px = a["x"][k] - off
    py = a["y"][k] - off
    x = np.round(px + rng.normal(0, 5, n))
    y = np.round(py + rng.normal(0, 5, n))
    ok = (x >= 0) & (y >= 0) & (x < 304) & (y < 240)
    return m, make(t[ok], x[ok], y[ok], 1)


FRAMES = {"image": dict(pull_frame="image", cartesian_frame="image"),
          "similarity": dict(pull_frame="similarity", cartesian_frame="similarity")}


@pytest.mark.parametrize("frame", FRAMES)
def test_energy_criteria_release_a_tracker_from_a_wrong_cloud(frame):
    """Figs. 7, 13: the dragged tracker's connections exceed s * mean energy, it turns
    insensitive and returns near its equilibrium; with s so large the criteria never act,
    it follows the wrong cloud.  The same in both frames of eq. (22)."""
    m, ev = pulled_grid_stream()
    eq = np.array([m.trackers[0].x, m.trackers[0].y])
    on = springtrack.Tracker(m, dict(FRAMES[frame], energy_scale=4.5, energy_gain=0.05))
    tr_on = on.run(ev, 1000)
    off = springtrack.Tracker(m, dict(FRAMES[frame], energy_scale=1e9))
    tr_off = off.run(ev, 1000)
    end_on = np.array([tr_on.x[-1, 0], tr_on.y[-1, 0]])
    end_off = np.array([tr_off.x[-1, 0], tr_off.y[-1, 0]])
    assert (~tr_on.sensitive[:, 0]).any()              # eq. (21) fired for r0c0
    assert np.linalg.norm(end_on - eq) < 6.0            # back near equilibrium
    assert np.linalg.norm(end_off - eq) > 25.0          # followed the wrong cloud
    assert tr_off.sensitive.all()


@pytest.mark.parametrize("frame", FRAMES)
def test_energy_criteria_pull_back_a_pair_dragged_together(frame):
    """Fig. 8: two neighbours dragged together keep their own connection calm, so neither
    turns insensitive (eq. 21), but their other connections exceed the threshold and eq.
    (22) pulls both back toward their places about G -- in the similarity frame, about
    the frame fitted to the calm trackers.  Without the criteria both follow the cloud.
    s = 3.5, not the grid's 4.5: three equal over-threshold connections of twelve are at
    most 12/3 = 4 times the mean energy, so at 4.5 only transients of the drag exceed it
    (in either frame; measured ratio about 4.1 image, 3.9 similarity)."""
    m, ev = pulled_grid_stream(dragged=(0, 1))
    eq = np.array([[t.x, t.y] for t in m.trackers[:2]])
    ends = {}
    for name, s in (("on", 3.5), ("off", 1e9)):
        tr = springtrack.Tracker(m, dict(FRAMES[frame], energy_scale=s))
        track = tr.run(ev, 1000)
        ends[name] = np.hypot(track.x[-1, :2] - eq[:, 0], track.y[-1, :2] - eq[:, 1])
    assert (ends["on"] < 6.0).all(), ends
    assert (ends["off"] > 25.0).all(), ends
