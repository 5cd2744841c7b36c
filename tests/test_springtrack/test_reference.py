"""Hand-computed cases for each equation of the reference tracker (springtrack.reference)."""
import math

import numpy as np
import pytest

from springtrack.model import Connection, ShapeModel, TrackerSpec
from springtrack.params import Params
from springtrack.gate import covariance_bias, truncation_factor
from springtrack.reference import (NO_TRACKER, SKIPPED_BACK_IN_TIME, SKIPPED_OUT_OF_SENSOR,
                                   ReferenceTracker, wrap_angle)

NEVER = 10 ** 6   # spring_period that keeps springs out of a test


def one(x=10.0, y=10.0, sigma=(4.0, 0.0, 4.0), **params):
    m = ShapeModel("one", 64, 48, [TrackerSpec("a", x, y, sigma)], [])
    return ReferenceTracker(m, Params(**{"spring_period": NEVER, **params}))


def test_truncation_factor_matches_closed_form():
    g = -2 * math.log(0.1)                          # gate for delta_p = 0.1: 4.60517
    assert g == pytest.approx(4.605170, abs=1e-6)
    assert truncation_factor(g) == pytest.approx((2 - (g + 2) * 0.1) / 1.8, rel=1e-12)
    assert truncation_factor(g) == pytest.approx(0.744157, abs=1e-6)
    assert truncation_factor(1e3) == pytest.approx(1.0, abs=1e-9)   # no gate -> no bias
    # small alpha: the bias is the truncation alone; it grows with the mean's jitter
    assert covariance_bias(1e-9, g) == pytest.approx(truncation_factor(g), rel=1e-6)
    assert covariance_bias(0.3, g) > covariance_bias(0.01, g)


def test_eq2_gate_assigns_inside_and_rejects_outside():
    tr = one()
    # d^2 = 2^2 / 4 = 1 < 4.605: inside the gate
    assert tr.step(0, 12, 10) == 0
    tr = one()
    # d^2 = 5^2 / 4 = 6.25 > 4.605: exp(-d2/2) = 0.044 < delta_p = 0.1
    assert tr.step(0, 15, 10) == NO_TRACKER
    assert tr.n_assigned == 0 and tr.n_valid == 1


def test_eq3_to_5_update_weights_the_new_event():
    tr = one(alpha_position=0.5, alpha_covariance=0.1)
    gain = 0.1 / covariance_bias(0.5, tr.gate)
    tr.step(0, 12, 10)
    assert (tr.mx[0], tr.my[0]) == (11.0, 10.0)                 # eq. (3): 0.5*10 + 0.5*12
    # eq. (4)/(5): dS about the pre-update mean: dx = 2, dy = 0
    assert tr.sxx[0] == pytest.approx(0.9 * 4 + gain * 4.0, rel=1e-15)
    assert tr.sxy[0] == pytest.approx(0.0)
    assert tr.syy[0] == pytest.approx(0.9 * 4, rel=1e-15)
    det = tr.sxx[0] * tr.syy[0]
    assert tr.ia[0] == pytest.approx(tr.syy[0] / det) and tr.ib[0] == 0.0


def test_eq6_activity_decays_between_events():
    tr = one(activity_tau_us=1000.0)
    tr.step(0, 10, 10)                                          # d2 = 0: p = 1
    assert tr.act[0] == pytest.approx(1.0)
    tr.step(1000, 10, 10)                                       # one tau later
    p2 = 1.0                                                    # event at the (moved) mean
    assert tr.act[0] == pytest.approx(math.exp(-1) + p2, rel=1e-12)
    assert tr.activity_at(0, 3000) == pytest.approx((math.exp(-1) + 1) * math.exp(-2), rel=1e-12)


def test_eq6_a_new_tau_decays_from_the_change_on():
    tr = one(activity_tau_us=1000.0)
    tr.step(0, 10, 10)                                          # p = 1 at t = 0
    tr.step(1000, 40, 40)                                       # no tracker: time moves on
    tr.set_params(Params(spring_period=NEVER, activity_tau_us=2000.0))
    # 1000 us at tau = 1000 (before the change), then 2000 us at tau = 2000
    assert tr.activity_at(0, 3000) == pytest.approx(math.exp(-1) * math.exp(-1), rel=1e-12)


def test_sigma_bounds_keep_the_covariance_positive_definite():
    tr = one(sigma=(100.0, 99.9, 100.0), sigma_min_px=1.0, sigma_max_px=8.0)
    assert tr.sxx[0] == 64.0 and tr.syy[0] == 64.0
    assert abs(tr.sxy[0]) <= 0.99 * 64.0 + 1e-12
    tr = one(sigma=(0.01, 0.0, 0.01), sigma_min_px=1.0)
    assert tr.sxx[0] == 1.0


def test_events_back_in_time_and_outside_are_counted_and_skipped():
    tr = one()
    assert tr.step(100, 10, 10) == 0
    assert tr.step(99, 10, 10) == SKIPPED_BACK_IN_TIME
    assert tr.step(101, 64, 10) == SKIPPED_OUT_OF_SENSOR
    assert tr.step(101, 10, 48) == SKIPPED_OUT_OF_SENSOR
    assert (tr.n_back, tr.n_outside, tr.n_valid) == (1, 2, 1)


def test_argmin_picks_the_closest_in_mahalanobis_distance():
    m = ShapeModel("two", 64, 48, [TrackerSpec("a", 10.0, 10.0, (1.0, 0.0, 1.0)),
                                   TrackerSpec("b", 14.0, 10.0, (16.0, 0.0, 16.0))], [])
    tr = ReferenceTracker(m, Params(spring_period=NEVER))
    # event at x=12: d2_a = 4/1 = 4, d2_b = 4/16 = 0.25 -> b, though equidistant in px
    assert tr.step(0, 12, 10) == 1


def pair(springs, b=(20.0, 10.0), stiffness=0.1):
    m = ShapeModel("pair", 64, 48, [TrackerSpec("a", 10.0, 10.0, (4.0, 0.0, 4.0)),
                                    TrackerSpec("b", b[0], b[1], (4.0, 0.0, 4.0))],
                   [Connection("a", "b", tuple(springs), stiffness)])
    return ReferenceTracker(m, Params(spring_period=NEVER, energy_scale=1e12))


def test_eq18_19_20_cartesian_spring():
    tr = pair(["cartesian"])
    tr.mx[1] = 22.0                       # elongation dx = 2
    tr.springs()
    assert tr.mx[0] == pytest.approx(10.2) and tr.mx[1] == pytest.approx(21.8)
    assert tr.energy[2][0] == pytest.approx(0.5 * 0.1 * 4)


def test_eq10_11_12_euclidean_spring():
    tr = pair(["euclidean"])
    tr.mx[1] = 22.0                       # l = 12, l0 = 10: dl = 2 along +x
    tr.springs()
    assert tr.mx[0] == pytest.approx(10.2) and tr.mx[1] == pytest.approx(21.8)
    assert tr.my[0] == pytest.approx(10.0) and tr.my[1] == pytest.approx(10.0)
    assert tr.energy[0][0] == pytest.approx(0.2)


def test_eq14_to_17_torsional_spring_with_mean_correction():
    # a-b along +x, a-c along +y; rotate b by 0.1 rad about a (a of mass 2: its two
    # springs of stiffness 0.5 keep its spring load at the 0.5 of springtrack.limits)
    m = ShapeModel("tri", 64, 48, [TrackerSpec("a", 10.0, 10.0, (4.0, 0.0, 4.0), 2.0),
                                   TrackerSpec("b", 20.0, 10.0, (4.0, 0.0, 4.0)),
                                   TrackerSpec("c", 10.0, 20.0, (4.0, 0.0, 4.0))],
                   [Connection("a", "b", ("torsional",), 0.5),
                    Connection("a", "c", ("torsional",), 0.5)])
    tr = ReferenceTracker(m, Params(spring_period=NEVER, energy_scale=1e12))
    tr.mx[1], tr.my[1] = 10 + 10 * math.cos(0.1), 10 + 10 * math.sin(0.1)
    tr.springs()
    # eq. (15): dtheta = 0.1 - mean(0.1, 0) = 0.05 for a-b, -0.05 for a-c
    assert tr.energy[1][0] == pytest.approx(0.5 * 0.5 * 0.05 ** 2, rel=1e-9)
    assert tr.energy[1][1] == pytest.approx(0.5 * 0.5 * 0.05 ** 2, rel=1e-9)
    # eq. (16) for a-b: u = l (dir(0.1 + 0.5*0.05) - dir(0.1)); b moves by -u
    ux = 10 * (math.cos(0.125) - math.cos(0.1))
    uy = 10 * (math.sin(0.125) - math.sin(0.1))
    assert tr.mx[1] == pytest.approx(10 + 10 * math.cos(0.1) - ux, rel=1e-12)
    assert tr.my[1] == pytest.approx(10 + 10 * math.sin(0.1) - uy, rel=1e-12)
    # the angle of a-b moves back toward 0
    assert math.atan2(tr.my[1] - tr.my[0], tr.mx[1] - tr.mx[0]) < 0.1


def test_eq21_22_energy_criteria_make_an_outlier_insensitive_and_pull_it():
    # triangle a-b-c plus pendant d on c; d is dragged 10 px away
    pts = {"a": (10.0, 10.0), "b": (30.0, 10.0), "c": (20.0, 25.0), "d": (20.0, 40.0)}
    m = ShapeModel("kite", 64, 64, [TrackerSpec(k, x, y, (4.0, 0.0, 4.0)) for k, (x, y) in pts.items()],
                   [Connection(a, b, ("cartesian",), 0.01) for a, b in
                    (("a", "b"), ("b", "c"), ("c", "a"), ("c", "d"))])
    tr = ReferenceTracker(m, Params(spring_period=NEVER, energy_kind="cartesian",
                                    energy_scale=2.0, energy_gain=0.5))
    tr.my[3] = 50.0
    tr.springs()
    # only c-d is strained: E_cd = 0.5*0.01*100 = 0.5, mean = 0.125, 0.5 > 2*0.125
    assert tr.energy[2][3] == pytest.approx(0.5)
    assert tr.mean_energy == pytest.approx(0.125)
    assert tr.sensitive == [True, True, True, False]       # eq. (21): all of d's links over
    # eq. (22): d pulled halfway to G + dG0 (G after the spring step)
    assert tr.my[3] < 50.0 - 0.1 - 1.0


def test_model_at_rest_is_not_insensitive():
    tr = pair(["cartesian"])
    tr.springs()                                            # all energies 0, mean 0
    assert tr.sensitive == [True, True]


def test_wrap_angle():
    assert wrap_angle(math.pi + 0.1) == pytest.approx(-math.pi + 0.1)
    assert wrap_angle(-math.pi - 0.1) == pytest.approx(math.pi - 0.1)
    assert wrap_angle(0.3) == pytest.approx(0.3)


def test_run_samples_state_before_events_at_the_sample_time():
    tr = one(alpha_position=0.5, polarity_gain=0.0)     # eq. (3): OFF events, one mean
    ev = np.zeros(3, dtype=[("t", "i8"), ("x", "u2"), ("y", "u2"), ("p", "u1")])
    ev["t"] = [500, 1000, 2500]
    ev["x"] = [12, 12, 12]
    ev["y"] = 10
    s = tr.run(ev, sample_us=1000)
    assert [t for t, _ in s] == [1000, 2000]
    assert s[0][1][0][0] == 11.0        # after the t=500 event only
    assert s[1][1][0][0] == 11.5        # after t=500 and t=1000
