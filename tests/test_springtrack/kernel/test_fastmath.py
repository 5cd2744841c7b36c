"""springtrack/csrc/fastmath.h, the kernel's replacements for libm: atan2 (eq. 14),
sin / cos - 1 (eq. 16) and exp (eqs. 2, 6) against Python's math (libm) on many
arguments and on the edge cases the kernel can meet."""
import math

import numpy as np
import pytest

from support import probes

kp = probes.load("kernel_probe")
fastmath_atan2, fastmath_exp, fastmath_exp_batch = (kp.fastmath_atan2, kp.fastmath_exp,
                                                    kp.fastmath_exp_batch)
fastmath_sincos, torsion_angles_framed = kp.fastmath_sincos, kp.torsion_angles_framed

ULP1 = 2.0 ** -52


def test_atan2_matches_libm_to_half_a_femtoradian():
    rng = np.random.default_rng(1)
    n = 200_000
    # lengths from 1e-6 to 1e3 px, every direction, plus near-axis and near-diagonal cases
    r = 10.0 ** rng.uniform(-6, 3, n)
    th = rng.uniform(-math.pi, math.pi, n)
    th[: n // 10] = rng.choice([0.0, 0.5, 1.0, -0.5, -1.0], n // 10) * math.pi + rng.normal(0, 1e-9, n // 10)
    th[n // 10: n // 5] = rng.choice([0.25, 0.75, -0.25, -0.75], n // 10) * math.pi + rng.normal(0, 1e-9, n // 10)
    x, y = r * np.cos(th), r * np.sin(th)
    got = fastmath_atan2(y, x)
    want = np.array([math.atan2(a, b) for a, b in zip(y.tolist(), x.tolist())])
    err = np.abs(got - want)
    assert err.max() <= 4.5e-16, err.max()
    # relative near 0 (|y| << |x|, x > 0): as good as libm's own rounding, 2 ulp
    small = (np.abs(want) < 1e-3) & (want != 0)
    assert (err[small] / np.abs(want[small])).max() <= 2 * ULP1


@pytest.mark.parametrize("y,x", [(0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -0.0), (0.0, -1.0),
                                 (-0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (1.0, 1.0), (-1.0, -1.0),
                                 (3.0, -3.0), (1e-300, 1.0), (1.0, 1e-300), (-1e-300, -1.0),
                                 (5e-324, 1.0), (1e300, 1e-300)])
def test_atan2_edge_cases_as_libm(y, x):
    got = fastmath_atan2([y], [x])[0]
    want = math.atan2(y, x)
    assert abs(got - want) <= 4.5e-16
    assert math.copysign(1.0, got) == math.copysign(1.0, want)     # signed zeros, +-pi


def test_sincos_small_matches_libm():
    rng = np.random.default_rng(2)
    e = np.concatenate([rng.uniform(-math.pi / 4, math.pi / 4, 200_000),
                        10.0 ** rng.uniform(-12, -1, 20_000) * rng.choice([-1, 1], 20_000),
                        [0.0, -0.0, math.pi / 4, -math.pi / 4]])
    sn, cm1 = fastmath_sincos(e)
    want_s = np.array([math.sin(v) for v in e.tolist()])
    want_c = np.array([math.cos(v) for v in e.tolist()]) - 1.0
    nz = want_s != 0
    assert (np.abs(sn - want_s)[nz] / np.abs(want_s[nz])).max() <= 2 * ULP1
    # cos(e) - 1.0 computed by libm loses up to 1 ulp of 1.0 to cancellation; ours does not
    assert np.abs(cm1 - want_c).max() <= 1.2 * ULP1
    assert np.all(np.abs(cm1 - (-2.0 * np.sin(e / 2) ** 2)) <= 1e-16 + 4 * ULP1 * np.abs(cm1))
    assert sn[-4] == 0.0 and cm1[-4] == 0.0 and cm1[-3] == 0.0


def test_sincos_falls_back_to_libm_beyond_pi_over_4():
    e = np.array([0.79, -0.8, 1.0, 2.5, -3.0, 10.0, 1e6, math.pi])
    mixed = np.concatenate([e, np.linspace(-0.5, 0.5, 37)])       # wide and narrow in one batch
    sn, cm1 = fastmath_sincos(mixed)
    for k, v in enumerate(e.tolist()):
        assert sn[k] == math.sin(v) and cm1[k] == math.cos(v) - 1.0
    assert np.abs(sn[len(e):] - np.sin(mixed[len(e):])).max() <= 1e-16


def test_exp_matches_libm():
    rng = np.random.default_rng(3)
    x = np.concatenate([-rng.uniform(0, 2.5, 100_000),            # exp(-d2/2) inside the gate
                        -rng.exponential(3.0, 100_000),            # decay exp(-dt/tau)
                        rng.uniform(-745, 709, 50_000), [0.0, -0.0, -1e-300, -700.0, -699.99]])
    got = fastmath_exp(x)
    want = np.array([math.exp(v) for v in x.tolist()])
    rel = np.abs(got - want) / want
    normal = want > 2.3e-308
    assert rel[normal].max() <= 2 * ULP1, rel[normal].max()
    assert np.all(np.abs(got - want)[~normal] <= 5e-324)
    assert fastmath_exp([0.0])[0] == 1.0
    inf_nan = fastmath_exp([-np.inf, np.inf, np.nan, -1000.0])
    assert inf_nan[0] == 0.0 and inf_nan[1] == np.inf and np.isnan(inf_nan[2]) and inf_nan[3] == 0.0


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def test_framed_angles_match_libm_within_three_eighths_of_pi():
    """csrc/springs.h st_torsion_angles_framed: th = wrap(phi + angle from q to r) for r
    within 3 pi/8 of q, the reduced branch (|t| > tan(pi/8)) and the wrap at +-pi included."""
    rng = np.random.default_rng(3)
    n = 100_000
    q_ang = rng.uniform(-math.pi, math.pi, n)
    dev = rng.uniform(-0.374, 0.374, n) * math.pi          # just inside +-3 pi/8
    dev[:1000] = rng.choice([1 / 8, -1 / 8, 0.0], 1000) * math.pi + rng.normal(0, 1e-12, 1000)
    ql, rl = 10.0 ** rng.uniform(-1, 3, n), 10.0 ** rng.uniform(-3, 3, n)
    qx, qy = ql * np.cos(q_ang), ql * np.sin(q_ang)
    rx, ry = rl * np.cos(q_ang + dev), rl * np.sin(q_ang + dev)
    for phi in (0.0, 1.0, -2.9, math.pi - 1e-9, -math.pi):
        th, far = torsion_angles_framed(rx, ry, qx, qy, phi)
        assert not far
        want = np.array([math.atan2(qxk * ryk - qyk * rxk, qxk * rxk + qyk * ryk)
                         for qxk, qyk, rxk, ryk in zip(qx.tolist(), qy.tolist(), rx.tolist(),
                                                       ry.tolist())]) + phi
        err = np.abs(th - np.where(want >= math.pi, want - 2 * math.pi,
                                   np.where(want < -math.pi, want + 2 * math.pi, want)))
        assert err.max() <= 1e-15, (phi, err.max())
        assert np.all((th >= -math.pi) & (th < math.pi))


@pytest.mark.parametrize("ang", [0.376 * math.pi, -0.376 * math.pi, 0.5 * math.pi, math.pi, None])
def test_framed_angles_report_a_connection_outside_their_range(ang):
    """One connection beyond 3 pi/8 from its q (or r = 0) sets the fallback flag."""
    rx, ry = np.ones(9), np.zeros(9)
    if ang is None:
        rx[4] = 0.0
    else:
        rx[4], ry[4] = math.cos(ang), math.sin(ang)
    th, far = torsion_angles_framed(rx, ry, np.ones(9), np.zeros(9), 0.0)
    assert far


def test_exp_batch_equals_exp_bit_for_bit():
    """st_exp_batch (the kernel's activity log) gives st_exp's values exactly, the libm
    fallback beyond |x| >= 700 included, for every length (vector body and tail)."""
    rng = np.random.default_rng(4)
    x = np.concatenate([rng.uniform(-40, 0, 5000), rng.uniform(-745, 710, 500),
                        [0.0, -0.0, 699.9, 700.0, -700.0, -1000.0, np.inf, -np.inf, np.nan]])
    rng.shuffle(x)
    for n in (len(x), 1, 3, 7, 257):
        got, want = fastmath_exp_batch(x[:n]), fastmath_exp(x[:n])
        assert np.array_equal(got, want, equal_nan=True), n
