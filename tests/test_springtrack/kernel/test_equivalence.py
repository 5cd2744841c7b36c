"""The Cython kernel equals the reference (<= 1e-9 px in every field) on random models and
streams (hypothesis) and on structured grid/face scenes of >= 100k events; and so it does
holding several model instances (springtrack.instances): random sets of random models,
copies of one model beyond 64 trackers (several mask words), and sets whose instances
are lost, moved and re-placed mid-stream."""
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings, strategies as st

from support import probes
import springtrack
from springtrack.events import make
from springtrack.model import SPRING_KINDS, Connection, ShapeModel, TrackerSpec, face26, grid3x3
from springtrack.params import ENERGY_KINDS, FRAMES
from springtrack.sim.synthetic import blob_stream

FIELDS = ("x", "y", "sxx", "sxy", "syy", "activity", "vx", "vy")
# Positions (px) and activities within 1e-9 absolute; covariances (px^2, up to ~1e3 on
# wide random trackers) also within 1e-10 relative: a relative gap r in S = sigma^2 is a
# relative gap r / 2 in the spread sigma, the same digits whatever the tracker's size.
RTOL = dict(sxx=1e-10, sxy=1e-10, syy=1e-10, vx=1e-10, vy=1e-10)
# velocities are reported in px/s: 1e-6 px/s is 1e-12 px/us, 1e-9 px over 1 ms
ATOL = dict(vx=1e-6, vy=1e-6)
kp = probes.load("kernel_probe")      # place a kernel's trackers, check its spatial index


def assert_same(model, params, events, sample_us=1000, instances=1, atol_px=1e-9):
    """``model``: one ShapeModel or a list of them (``instances`` copies of each)."""
    a = springtrack.Tracker(model, params, backend="cython", instances=instances)
    b = springtrack.Tracker(model, params, backend="reference", instances=instances)
    assert_same_run(a, b, a.run(events, sample_us), b.run(events, sample_us), atol_px)
    return a


def assert_same_run(a, b, ta, tb, atol_px=1e-9):
    """Trackers ``a`` (cython) and ``b`` (reference) and the Tracks they returned: every
    field within ``atol_px`` (1e-9 px), the same flags, states, counters; energies, every
    instance's mean energy and similarity frame."""
    assert len(ta) == len(tb)
    for f in FIELDS:
        np.testing.assert_allclose(getattr(ta, f), getattr(tb, f), rtol=RTOL.get(f, 0),
                                   atol=ATOL.get(f, atol_px), err_msg=f)
    assert (ta.active == tb.active).all() and (ta.sensitive == tb.sensitive).all()
    sa, sb = a.state(), b.state()
    for f in FIELDS:
        np.testing.assert_allclose(sa[f], sb[f], rtol=RTOL.get(f, 0),
                                   atol=ATOL.get(f, atol_px), err_msg=f)
    ea, eb = a.energies(), b.energies()
    for k in ENERGY_KINDS:
        # 1e-9 like positions: energies scale with a * dl, so a 1e-11 px position gap
        # (rounding grown on a random model) already moves them by ~1e-11
        np.testing.assert_allclose(ea[k], eb[k], rtol=1e-9, atol=1e-9, err_msg=k)
    np.testing.assert_allclose(ea["means"], eb["means"], rtol=1e-9, atol=1e-12)
    assert (ta.state == tb.state).all() and (sa["state"] == sb["state"]).all()
    ca, cb = a.counters, b.counters
    for k in cb:
        assert ca[k] == cb[k], k
    for g in range(len(b.models)):      # the similarity frame of the last spring update
        fa, fb = a.frame(g), b.frame(g)
        for k in fb:
            np.testing.assert_allclose(fa[k], fb[k], rtol=0, atol=1e-9, err_msg=f"{g} {k}")


# The kernel's exp/atan2/sin/cos are ~1-ulp polynomials (springtrack/csrc/fastmath.h), not
# libm's, so kernel and reference differ by rounding.  That stays far below 1e-9 px on
# well-posed models, but two kinds of random model amplify rounding without bound, and no
# tolerance can compare them: (1) unstable springs, where one spring update overshoots
# (stiffness x (1/m_a + 1/m_b) summed over a tracker's springs above ~1) and positions grow
# geometrically to inf/NaN; (2) connections whose ends coincide (rest length 0), whose
# direction (eq. 11) and angle (eq. 14) are then defined by rounding noise alone.  The
# strategy below draws only models outside both: connected ends at least 1 px apart, and
# stiffness scaled so that every tracker's spring load sum(kinds x a / m) is at most 0.5
# and the torsional loop gain through eq. (15)'s mean angle (see models()) too.
MAX_SPRING_LOAD = 0.5


@st.composite
def models(draw, size=None):
    w, h = size or (draw(st.integers(40, 400)), draw(st.integers(40, 300)))
    n = draw(st.integers(1, 12))
    trackers = []
    for i in range(n):
        sx = draw(st.floats(1.0, 8.0))
        sy = draw(st.floats(1.0, 8.0))
        rho = draw(st.floats(-0.8, 0.8))
        trackers.append(TrackerSpec(f"t{i}", draw(st.floats(0, w - 1)), draw(st.floats(0, h - 1)),
                                    (sx * sx, rho * sx * sy, sy * sy), draw(st.floats(0.2, 5.0))))
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)
             if np.hypot(trackers[i].x - trackers[j].x, trackers[i].y - trackers[j].y) >= 1.0]
    chosen = draw(st.lists(st.sampled_from(pairs), unique=True, max_size=20)) if pairs else []
    drawn = [(i, j, tuple(draw(st.lists(st.sampled_from(SPRING_KINDS), min_size=1, max_size=3,
                                        unique=True))),
              draw(st.floats(0.0, 0.3))) for i, j in chosen]
    load = np.zeros(n)
    for i, j, kinds, a in drawn:
        load[i] += len(kinds) * a / trackers[i].mass
        load[j] += len(kinds) * a / trackers[j].mass
    # a relative 1e-12 below the bound, so that the scaled loads, rounded, stay within it
    # (only loads above the bound are scaled: a tiny load would overflow the quotient)
    scale = (MAX_SPRING_LOAD / load.max() * (1 - 1e-12)
             if drawn and load.max() > MAX_SPRING_LOAD * (1 - 1e-12) else 1.0)
    # torsion couples every connection through the mean angle of eq. (15): a torsional
    # spring of length L moves its ends by ~ L a dth / m, which turns a connection of length
    # l by that over l; keep that loop gain a (1/m_a + 1/m_b) L_max / l_min below 0.5
    lengths = [np.hypot(trackers[i].x - trackers[j].x, trackers[i].y - trackers[j].y)
               for i, j, _, _ in drawn]
    lever = max(lengths) / min(lengths) if drawn else 1.0
    conns = []
    for i, j, kinds, a in drawn:
        a = a * scale
        gain = a * (1.0 / trackers[i].mass + 1.0 / trackers[j].mass) * lever
        if "torsional" in kinds and gain > MAX_SPRING_LOAD:
            a = a * MAX_SPRING_LOAD / gain
        conns.append(Connection(f"t{i}", f"t{j}", kinds, a))
    return ShapeModel("rand", w, h, trackers, conns)


@st.composite
def params(draw):
    return dict(alpha_position=draw(st.floats(0.001, 0.5)),
                alpha_covariance=draw(st.floats(1e-5, 0.05)),
                p_threshold=draw(st.floats(0.01, 0.5)),
                activity_tau_us=draw(st.floats(100.0, 1e5)),
                energy_scale=draw(st.floats(0.5, 10.0)),
                energy_gain=draw(st.floats(0.0, 0.5)),
                spring_period=draw(st.integers(1, 60)),
                energy_kind=draw(st.sampled_from(ENERGY_KINDS)),
                pull_frame=draw(st.sampled_from(FRAMES)),
                cartesian_frame=draw(st.sampled_from(FRAMES)),
                **draw(motion_params()))


@st.composite
def motion_params(draw):
    """The motion model's parameters (eqs. M1-M9), each part off (0) or on."""
    return dict(motion_tau_us=draw(st.sampled_from([0.0]) | st.floats(20.0, 1e5)),
                prediction_horizon_us=draw(st.floats(0.0, 5000.0)),
                polarity_gain=draw(st.sampled_from([0.0]) | st.floats(0.0, 1.0)))


# Criterion energies (eqs. 12, 17, 20) this small are rounding residue of a model at rest:
# 1e-20 px^2 is a length error of 1e-9 px.  eqs. (21)-(22) compare them with s times their
# mean, so there the reference's own decision is set by its rounding, which only a
# bit-identical implementation reproduces.
ENERGY_NOISE = 1e-20


# How often the random tests excused a divergence as rounding noise, per test: [examples
# run, excused], counted over the session and bounded by test_excusals_are_counted_and_rare
# (the last tests of this module).  Measured: none in 263 random models and 90 random
# instance sets drawn at random, 2 of 32 instance sets in one hypothesis run (which favours
# edge cases); the excused cases of a session are listed in EXCUSED_CASES and printed by
# the bound test, to be pinned as an @example of their test.
EXCUSALS = {"models": [0, 0], "instance_sets": [0, 0]}
EXCUSED_CASES: list = []
MAX_EXCUSED_SHARE = 0.2
MIN_RUNS = 20          # below this many examples the share says nothing


def excused(kind: str, is_noise: bool, case) -> bool:
    """Count one excusal of ``kind`` when ``is_noise`` (and keep ``case``, the example's
    arguments); returns ``is_noise``."""
    if is_noise:
        EXCUSALS[kind][1] += 1
        EXCUSED_CASES.append((kind, case))
    return is_noise


def first_divergence_is_rounding_noise(model, prm, events) -> bool:
    """Replay kernel and reference event by event to their first disagreement (a different
    winner, a position apart by more than 1e-9 px, or a different sensitivity).  True when
    it is rounding amplified, not an error: eq. (2) decided between two candidates (or at
    the gate) within 1e-9 in d^2; eqs. (21)-(22) decided on criterion energies all below
    ENERGY_NOISE, or the similarity frame's calm set did (at this spring update, or at the
    one before: the Cartesian springs use the frame one update later); or a position gap
    that crept up from rounding level under identical decisions (chaotic model).  False
    for any other disagreement: a genuine failure."""
    from springtrack.kernel.kernel import Kernel
    from springtrack.instances import ModelSet
    from springtrack.reference import ReferenceTracker
    mset = ModelSet(model, prm)          # one model or several instances
    ref, ker = ReferenceTracker(mset), Kernel(mset, None)
    last_gap = 0.0
    noisy_before: set = set()            # instances whose last spring update was on noise
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(),
                          events["p"].tolist()):
        lead = [ref.predict_dt(i, t) for i in range(ref.n)]          # eq. (M1)
        ex = [x - (ref.mx[i] + ref.vx[i] * lead[i]) for i in range(ref.n)]
        ey = [y - (ref.my[i] + ref.vy[i] * lead[i]) for i in range(ref.n)]
        d2 = sorted(ref.ia[i] * ex[i] ** 2 + ref.ic[i] * ey[i] ** 2 + 2.0 * ref.ib[i] * ex[i] * ey[i]
                    for i in range(ref.n) if ref.sensitive[i]) + [np.inf, np.inf]
        a, b = ref.step(t, x, y, p), ker.step(t, x, y, p)
        snap = ker.snapshot(t)
        rx, ry = (np.array(v) for v in ref.snapshot(t)[:2])      # eq. (M1): predicted to t
        if a != b:
            return (abs(d2[0] - d2[1]) <= 1e-9 * max(1.0, d2[0])
                    or abs(d2[0] - ref.gate) <= 1e-9 * ref.gate)
        gap = max(np.abs(rx - snap["x"]).max(), np.abs(ry - snap["y"]).max())
        differ = np.flatnonzero(np.array(ref.sensitive) != snap["sensitive"])
        # the instances whose spring clocks ran their updates at this event (a valid one
        # moves the clock of the instance that took it, or every clock if none did)
        updated = {g for g in range(ref.ni) if a >= -1 and ref.since_spring[g] == 0
                   and (a < 0 or ref.inst[a] == g)}
        # those whose criterion energies were all rounding noise at this update:
        # eqs. (21)-(22) and the calm set the similarity frame is fitted to decided on it
        noisy = {g for g in updated if max(
            ref.energy[ref.ekinds[g]][ref.c0[g]:ref.c1[g]], default=0.0) < ENERGY_NOISE}
        if len(differ):
            return bool(updated) and {ref.inst[i] for i in differ} <= noisy
        apart = np.flatnonzero(np.maximum(np.abs(rx - snap["x"]), np.abs(ry - snap["y"])) > 1e-9)
        if len(apart) and updated and {ref.inst[i] for i in apart} <= noisy | noisy_before:
            return True
        noisy_before = (noisy_before - updated) | noisy
        if gap > 1e-9:
            # same decisions all along: the gap grew out of rounding (chaotic dynamics: a
            # tracker thrown about by springs at the sensor edge) if it crept up, here by
            # less than 100x in one event; a wrong formula jumps from ~1e-14 at once
            return last_gap >= 1e-11
        last_gap = gap
    return False


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(models(), params(), st.integers(0, 2 ** 31))
def test_kernel_equals_reference_on_random_models(model, prm, seed):
    EXCUSALS["models"][0] += 1
    ev, _ = blob_stream(model, 3000, rate_hz=100_000, noise=0.3, speed_px_s=(30, -20),
                        rot_deg_s=20, seed=seed)
    rng = np.random.default_rng(seed)
    ev = ev.copy()
    # a few events back in time and outside the sensor: skipped identically
    k = rng.integers(0, len(ev), 10)
    ev["t"][k[:5]] -= 50
    ev["x"][k[5:]] = model.width + 3
    try:
        assert_same(model, prm, ev, sample_us=500)
    except AssertionError:
        # not comparable: the reference decided on its own rounding (see ENERGY_NOISE)
        assume(not excused("models", first_divergence_is_rounding_noise(model, prm, ev),
                           (model.to_toml(), prm, seed)))
        raise


# the motion model on (eqs. M1-M9), both edges alone (its path without predictions), and off
MOTION_ON = dict(motion_tau_us=1000.0, polarity_gain=1.0)
EDGES_ON = dict(polarity_gain=1.0)
# both edges without a velocity (eq. M6b) amplify the kernel's ~1-ulp rounding a little
# more than the paper's step: measured 1.02e-9 px at one sample of grid3x3's similarity
# stream below (the kernel's first difference from the reference, 3e-14 px, comes from
# its first spring update)
EDGES_ATOL_PX = 2e-9


@pytest.mark.slow
@pytest.mark.parametrize("model_motion", [{}, MOTION_ON, EDGES_ON], ids=["off", "motion", "edges"])
@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("preset,motion", [("grid3x3", dict(speed_px_s=(15, 8), rot_deg_s=10)),
                                           ("face26", dict(speed_px_s=(10, -5), rot_deg_s=-8,
                                                           wobble_px=4))])
def test_kernel_equals_reference_on_100k_structured_events(preset, motion, frame, model_motion):
    m = springtrack.load_model(preset)
    ev, _ = blob_stream(m, 110_000, noise=0.3, seed=7, **motion)
    prm = dict(pull_frame=frame, cartesian_frame=frame, energy_scale=3.0, **model_motion)
    a = assert_same(m, prm, ev, atol_px=EDGES_ATOL_PX if model_motion is EDGES_ON else 1e-9)
    assert a.counters["events_valid"] >= 100_000
    assert a.counters["events_assigned"] > 0.5 * len(ev)
    if frame == "similarity":       # the frame turned with the scene and changed the result
        assert abs(a.frame()["angle"]) > 0.02
        img = springtrack.Tracker(m, dict(prm, **dict.fromkeys(("pull_frame", "cartesian_frame"),
                                                               "image")))
        img.run(ev, 1000)
        assert np.abs(img.state()["x"] - a.state()["x"]).max() > 1e-3


def test_chunked_processing_equals_whole():
    m = springtrack.load_model("face26")
    ev, _ = blob_stream(m, 20_000, seed=3)
    whole = springtrack.Tracker(m).run(ev, 700)
    tr = springtrack.Tracker(m)
    tr.record(700)
    for s in range(0, len(ev), 1234):
        tr.process(ev[s:s + 1234])
    parts = tr.samples()
    np.testing.assert_array_equal(whole.t_us, parts.t_us)
    np.testing.assert_array_equal(whole.x, parts.x)


def test_activity_equal_across_rescales_and_a_change_of_tau():
    """The kernel keeps activity as a sum seen from a common time it moves every 32 tau
    (springtrack/kernel/kernel.pyx kactivity); with tau = 100 us a 2 s stream moves it hundreds
    of times, and a tau change mid-stream applies from the change on in all three backends
    (the fixed-point one to its own precision).  One mean for both polarities
    (polarity_gain 0, the default): with both edges the chaotic amplification of the
    integer kernel's rounding moves its means by up to ~1e-4 px here and eq. (6)'s sums
    by ~2e-5."""
    model = grid3x3()
    ev, _ = blob_stream(model, 60_000, rate_hz=30_000, noise=0.3, seed=4, speed_px_s=(5, 3))
    trackers = [springtrack.Tracker(model, {"activity_tau_us": 100.0, "polarity_gain": 0.0},
                                    backend=b)
                for b in ("cython", "reference", "fixed")]
    half = len(ev) // 2
    runs = []
    for tr in trackers:
        first = tr.run(ev[:half], 1000)
        tr.set_params(activity_tau_us=5000.0)
        runs.append((first, tr.run(ev[half:], 1000)))
    (a1, a2), (b1, b2), (f1, f2) = runs
    for a, b in ((a1, b1), (a2, b2)):
        np.testing.assert_allclose(a.activity, b.activity, rtol=1e-12, atol=1e-12)
        assert (a.active == b.active).all()
    for f, b in ((f1, b1), (f2, b2)):        # the integer kernel, within its Q.32 tables
        np.testing.assert_allclose(f.activity, b.activity, rtol=1e-6, atol=1e-6)
    assert trackers[0].counters["events_assigned"] > 10_000
    assert np.ptp(runs[0][1].activity) > 1.0     # the activities tested are not all ~0


def test_activity_log_gives_the_same_sums_event_by_event():
    """The kernel logs eq. (6)'s increments and adds their exps in batches (log_activity,
    flushed when full, before a rescale and at the end of every batch of events); one event
    at a time (Kernel.step, a flush per event) gives bit-identical activities, over logs
    filled many times and rescales of the common time (tau = 200 us)."""
    from springtrack.kernel.kernel import Kernel
    from springtrack.tracker import resolve_params
    m = springtrack.load_model("face26")
    p = resolve_params(m, {"activity_tau_us": 200.0})
    ev, _ = blob_stream(m, 20_000, rate_hz=300_000, noise=0.3, seed=2, speed_px_s=(10, -5))
    whole, single = Kernel(m, p), Kernel(m, p)
    whole.run(ev, 0, 0, 0)
    for t, x, y, pol in zip(*(ev[k].tolist() for k in "txyp")):
        single.step(t, x, y, pol)
    t_end = int(ev["t"][-1])
    a, b = whole.snapshot(t_end), single.snapshot(t_end)
    assert whole.counters()["events_assigned"] > 5 * 256
    assert np.array_equal(a["activity"], b["activity"]) and np.array_equal(a["x"], b["x"])
    assert a["activity"].max() > 0.5


@pytest.mark.slow
def test_kernel_equals_reference_beyond_64_connections():
    """More than 64 connections (the kernel's energy criteria, eqs. 21-22, reduce per-
    connection end masks, csrc/springs.h st_over_ends); a ring of
    30 trackers, each linked to its next three neighbours (90 connections), with a low
    energy_scale so that many connections are over threshold and trackers turn
    insensitive."""
    n = 30
    ang = 2 * np.pi * np.arange(n) / n
    trackers = [TrackerSpec(f"t{i}", 150 + 80 * np.cos(a), 120 + 80 * np.sin(a),
                            (9.0, 0.0, 9.0), 1.0) for i, a in enumerate(ang)]
    conns = [Connection(f"t{i}", f"t{(i + d) % n}", ("euclidean", "cartesian"), 0.01)
             for d in (1, 2, 3) for i in range(n)]
    m = ShapeModel("ring90", 304, 240, trackers, conns)
    ev, _ = blob_stream(m, 40_000, noise=0.3, seed=5, speed_px_s=(20, -10), rot_deg_s=15)
    prm = dict(energy_scale=0.7, energy_gain=0.05, spring_period=20, energy_kind="euclidean")
    a = assert_same(m, prm, ev)
    b = springtrack.Tracker(m, prm, backend="reference")
    insensitive = 0
    for s in range(0, len(ev), 2000):             # the criteria acted on high connections
        b.process(ev[s:s + 2000])
        insensitive += int((~b.state()["sensitive"][20:]).sum())
    assert insensitive > 0
    assert a.counters["spring_updates"] == len(ev) // 20


def turned_face(turn, rng, jitter_px=1.5):
    """face26's rest means turned by `turn` rad about their centroid, each jittered."""
    m = springtrack.load_model("face26")
    x = np.array([t.x for t in m.trackers])
    y = np.array([t.y for t in m.trackers])
    cx, cy = x.mean(), y.mean()
    c, s = np.cos(turn), np.sin(turn)
    return (m, cx + c * (x - cx) - s * (y - cy) + rng.normal(0, jitter_px, len(x)),
            cy + s * (x - cx) + c * (y - cy) + rng.normal(0, jitter_px, len(x)))


def assert_springs_equal(ker, ref, x, y):
    for i in range(len(x)):
        kp.place(ker, i, x[i], y[i])
    ref.mx, ref.my = [float(v) for v in x], [float(v) for v in y]
    ker.springs()
    ref.springs()
    snap = ker.snapshot(0)
    np.testing.assert_allclose(snap["x"], ref.mx, rtol=0, atol=1e-12)
    np.testing.assert_allclose(snap["y"], ref.my, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ker.energies(), np.array(ref.energy), rtol=1e-12, atol=1e-15)
    assert snap["sensitive"].tolist() == list(ref.sensitive)


def test_spring_update_equals_reference_while_the_face_turns_round():
    """eq. (14): the kernel measures the angles in a frame that follows the mean angle
    (st_torsion_angles_framed, fast while every connection is within 3 pi/8 of its frame
    direction; the full atan2 otherwise).  A face turning a whole circle in steps of 0.05 rad
    moves that frame, a tracker thrown 90 degrees off makes the fast path fall back, and
    every spring update equals the reference's, the wrap at +-pi included."""
    from springtrack.kernel.kernel import Kernel
    from springtrack.reference import ReferenceTracker
    from springtrack.tracker import resolve_params
    rng = np.random.default_rng(5)
    m = springtrack.load_model("face26")
    p = resolve_params(m, None)
    ker, ref = Kernel(m, p), ReferenceTracker(m, p)
    missed = []
    for turn in np.arange(0.0, 2 * np.pi + 0.1, 0.05):
        _, x, y = turned_face(turn, rng)
        before = ker.frame_stats()["frame_misses"]
        assert_springs_equal(ker, ref, x, y)
        if ker.frame_stats()["frame_misses"] > before:
            missed.append(turn)
    fast = ker.frame_stats()
    assert fast["frame_moves"] >= 10, fast
    # only upside down: the angles straddle the wrap at +-pi (eq. 14 wraps each one), so
    # their mean (eq. 15) lies far from some of them and the frame cannot follow
    assert 0 < len(missed) <= 8 and all(abs(t - np.pi) < 0.3 for t in missed), missed
    _, x, y = turned_face(1.0, rng)
    x[6], y[6] = x[16] + (y[17] - y[16]), y[16] - (x[17] - x[16])     # mouth 90 deg off
    assert_springs_equal(ker, ref, x, y)
    assert ker.frame_stats()["frame_misses"] == fast["frame_misses"] + 1


@pytest.mark.parametrize("changes", [{}, dict(alpha_position=0.5, alpha_covariance=0.05),
                                     dict(MOTION_ON, prediction_horizon_us=3000.0)])
def test_spatial_index_invariant_holds_throughout_a_stream(changes):
    """The kernel re-indexes a tracker only when its mean has moved, or its variances grown,
    past the slack reindex() left (st_box_left, a sufficient test); the exact gate box must
    then still lie inside the indexed box, checked every 500 events here, including with
    fast-moving means and fast-changing covariances, and across spring updates."""
    m = springtrack.load_model("face26")
    ev, _ = blob_stream(m, 60_000, rate_hz=300_000, noise=0.3, seed=4, speed_px_s=(40, -20),
                        rot_deg_s=30, wobble_px=6)
    tr = springtrack.Tracker(m, changes)
    for k in range(0, len(ev), 500):
        tr.process(ev[k:k + 500])
        assert kp.check_index(tr._b), k
    assert tr.counters["index_updates"] > 100


# ---- several model instances ------------------------------------------------------------
def instance_params(draw):
    """Each instance's own parameters (springtrack.instances.INSTANCE_PARAMS), as a
    model's [params] table."""
    return dict(alpha_position=draw(st.floats(0.001, 0.5)),
                alpha_covariance=draw(st.floats(1e-5, 0.05)),
                energy_scale=draw(st.floats(0.5, 10.0)),
                energy_gain=draw(st.floats(0.0, 0.5)),
                energy_kind=draw(st.sampled_from(ENERGY_KINDS)),
                pull_frame=draw(st.sampled_from(FRAMES)),
                cartesian_frame=draw(st.sampled_from(FRAMES)))


@st.composite
def instance_sets(draw):
    """2-4 random models on one sensor, each with its own [params], and the copies of
    each (1-3); shared parameters as overrides."""
    size = (draw(st.integers(60, 400)), draw(st.integers(40, 300)))
    ms = []
    for _ in range(draw(st.integers(2, 4))):
        m = draw(models(size=size))
        m.params.update(instance_params(draw))
        ms.append(m)
    shared = dict(p_threshold=draw(st.floats(0.01, 0.5)),
                  activity_tau_us=draw(st.floats(100.0, 1e5)),
                  spring_period=draw(st.integers(1, 60)), **draw(motion_params()))
    return ms, draw(st.integers(1, 3)), shared


@pytest.mark.slow
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(instance_sets(), st.integers(0, 2 ** 31))
def test_kernel_equals_reference_on_random_instance_sets(drawn, seed):
    """Random sets: an event feeds one tracker of one instance (ties: the lowest index),
    springs and criteria per instance with its own parameters; up to 4 x 3 x 12 trackers,
    so beyond one mask word too."""
    EXCUSALS["instance_sets"][0] += 1
    ms, copies, shared = drawn
    rng = np.random.default_rng(seed)
    parts = [blob_stream(m, 1500, rate_hz=100_000, noise=0.3,
                         speed_px_s=tuple(rng.uniform(-30, 30, 2)), rot_deg_s=rng.uniform(-20, 20),
                         seed=seed + k)[0] for k, m in enumerate(ms)]
    ev = np.sort(np.concatenate(parts), order="t", kind="stable")
    try:
        assert_same(ms, shared, ev, sample_us=500, instances=copies)
    except AssertionError:
        # not comparable: the reference decided on its own rounding (see ENERGY_NOISE)
        assume(not excused("instance_sets", first_divergence_is_rounding_noise(
            [m for m in ms for _ in range(copies)], shared, ev),
            ([m.to_toml() for m in ms], copies, shared, seed)))
        raise


def _faces_and_grid(width=400, height=240, faces=3):
    """``faces`` face26 (smaller, side by side) and a grid; each face's stream moves and
    turns, the grid's moves."""
    from springtrack.model import face26, grid3x3
    ms = [face26(cx=70 + 130 * (k % 3), cy=70 + 100 * (k // 3), scale=60, width=width,
                 height=height) for k in range(faces)]
    ms.append(grid3x3(cx=330, cy=190, spacing=18, sigma_px=3, width=width, height=height))
    ev = np.sort(np.concatenate([blob_stream(m, 12_000, noise=0.2, speed_px_s=(6, -4),
                                             rot_deg_s=6, seed=k)[0]
                                 for k, m in enumerate(ms)]), order="t", kind="stable")
    return ms, ev


@pytest.mark.slow
@pytest.mark.parametrize("faces", [1, 3])
def test_instances_lost_moved_and_placed_mid_stream_equal_the_reference(faces):
    """Faces and a grid (35 trackers: one mask word; 87: two, the third face straddling
    them) run in three parts; between them the grid is lost (insensitive, springs off),
    then the first face moved rigidly keeping its state, the last face re-placed, and the
    grid resumes: the kernel equals the reference through all of it."""
    from springtrack.instances import LOST, TRACKING
    from support.moves import similarity
    ms, ev = _faces_and_grid(faces=faces)
    prm = {"pull_frame": "similarity", "cartesian_frame": "similarity", "energy_scale": 2.0}
    a = springtrack.Tracker(ms, prm, backend="cython")
    b = springtrack.Tracker(ms, prm, backend="reference")
    grid, last_face = len(ms) - 1, faces - 1
    sim, moved = similarity(ms[0], 4.0, -3.0, 5.0, 1.05)
    _, placed = similarity(ms[last_face], -5.0, 2.0, -4.0, 0.97)
    cut = [0, len(ev) // 3, len(ev) // 2, len(ev)]
    for step in range(3):
        for tr in (a, b):
            if step == 1:
                tr._ib.set_state(grid, LOST)
            if step == 2:
                tr._ib.move(0, sim, moved)
                tr._ib.place(last_face, placed)
                tr._ib.set_state(grid, TRACKING)
        part = ev[cut[step]:cut[step + 1]]
        ta, tb = a.run(part, 1000), b.run(part, 1000)
        assert_same_run(a, b, ta, tb)
        if step == 1:                   # the lost grid kept its place and took nothing
            assert (ta.state[:, -9:] == LOST).all() and np.ptp(ta.x[:, -9:], axis=0).max() == 0
    assert a._ib.states() == [TRACKING] * len(ms)
    assert a.counters["events_assigned"] > 0.5 * len(ev)
    assert kp.check_index(a._b)


@pytest.mark.parametrize("kind", list(EXCUSALS))
def test_excusals_are_counted_and_rare(kind):
    """The random tests above excused at most MAX_EXCUSED_SHARE of their examples as
    rounding noise in this session (run after them: this module's order)."""
    runs, n = EXCUSALS[kind]
    if runs < MIN_RUNS:
        pytest.skip(f"the {kind} test ran {runs} examples in this session")
    cases = [c for k, c in EXCUSED_CASES if k == kind]
    assert n <= MAX_EXCUSED_SHARE * runs, f"{n} of {runs} {kind} examples excused: {cases}"
