"""Several model instances in one tracker (springtrack.instances) in the reference, the
specification: one event assignment over the union, springs and criteria per instance,
ids, limits, parameters, and the loss rule; the float kernel holds them too
(tests/test_springtrack/kernel/test_equivalence.py holds it to the reference), the fixed and mcu kernels refuse
a set."""
import numpy as np
import pytest

import springtrack
from springtrack.events import make
from springtrack.instances import LOST, SEARCHING, SHARED_PARAMS, TRACKING, ModelSet
from springtrack.acquisition.loss import LOSS_CHECK_US, LossRule, loss_hold_us
from springtrack.limits import MAX_INSTANCES, MAX_SET_TRACKERS
from springtrack.model import Connection, ModelError, ShapeModel, TrackerSpec, face26, grid3x3
from springtrack.params import Params
from springtrack.reference import NO_TRACKER, SPRING_BOX_PX, ReferenceTracker
from springtrack.sim.synthetic import blob_stream

W, H = 400, 240


def two_grids():
    return [grid3x3(cx=100, cy=120, spacing=30, width=W, height=H),
            grid3x3(cx=300, cy=120, spacing=30, width=W, height=H)]


def test_ids_stay_when_unique_and_are_prefixed_on_a_collision():
    a, b = two_grids()
    s = ModelSet([a, b])
    assert s.ids[:2] == ["grid3x3#1/r0c0", "grid3x3#1/r0c1"] and s.ids[9] == "grid3x3#2/r0c0"
    f = face26(width=W, height=H)
    s = ModelSet([a, f])
    assert s.ids == a.ids + f.ids                      # unique: as written
    assert [i.label for i in s] == ["grid3x3#1", "face26#1"]
    assert (s[1].t0, s[1].t1, s[1].c0, s[1].c1) == (9, 35, 12, 52)
    s = ModelSet([f], instances=3)
    assert len(s) == 3 and s.ids[26] == "face26#2/brow_l" and len(set(s.ids)) == 78


def test_capacity_and_sensor_errors_name_the_counts():
    f = face26()
    with pytest.raises(ModelError, match=f"exceed the limit of {MAX_INSTANCES}"):
        ModelSet([f], instances=MAX_INSTANCES + 1)
    big = ShapeModel("big", 304, 240, [TrackerSpec(f"t{i}", 10.0 + i, 10.0, (4.0, 0.0, 4.0))
                                       for i in range(64)], [])
    with pytest.raises(ModelError, match=f"320 trackers, beyond the limit of {MAX_SET_TRACKERS}"):
        ModelSet([big], instances=5)
    with pytest.raises(ModelError, match="share its sensor"):
        ModelSet([face26(), face26(width=640, height=480)])


def test_parameters_per_instance_and_shared():
    a, f = grid3x3(width=W, height=H), face26(width=W, height=H)
    s = ModelSet([f, a])
    assert s[0].params.alpha_position == 0.2 and s[1].params.alpha_position == 0.02
    e = ModelSet([f, grid3x3(width=W, height=H, springs=("euclidean",))])
    assert e[1].params.energy_kind == "euclidean" and e[0].params.energy_kind == "cartesian"
    s = ModelSet([f, a], {"energy_gain": 0.3})           # --params: over both
    assert s[0].params.energy_gain == s[1].params.energy_gain == 0.3
    a2 = grid3x3(width=W, height=H)
    a2.params["spring_period"] = 20                       # a shared one differs
    with pytest.raises(ModelError, match="spring_period=20 differs from 55"):
        ModelSet([f, a2])
    assert ModelSet([f, a2], {"spring_period": 30})[1].params.spring_period == 30
    assert "spring_period" in SHARED_PARAMS


def test_an_event_feeds_one_tracker_of_one_instance_ties_to_the_first():
    one = ShapeModel("p", 64, 48, [TrackerSpec("a", 20.0, 20.0, (4.0, 0.0, 4.0))], [])
    two = ShapeModel("p", 64, 48, [TrackerSpec("a", 24.0, 20.0, (4.0, 0.0, 4.0))], [])
    ref = ReferenceTracker(ModelSet([one, two], {"spring_period": 10 ** 6}))
    assert ref.step(0, 21, 20) == 0          # nearer to the first
    assert ref.step(1, 25, 20) == 1          # nearer to the second instance's tracker
    ref = ReferenceTracker(ModelSet([one, one], {"spring_period": 10 ** 6}))
    assert ref.step(0, 20, 20) == 0          # a tie: the lowest index, the first instance
    assert ref.n_assigned == 1 and ref.act[1] == 0.0
    assert ref.step(1, 60, 40) == NO_TRACKER


def test_instances_far_apart_track_as_alone():
    """Instance A with B far away (no event near B) equals A alone, float for float:
    springs, energies, frame and criteria are A's own; B stays at rest."""
    a, b = two_grids()
    prm = {"energy_scale": 2.0}
    ev, _ = blob_stream(a, 8000, noise=0.0, speed_px_s=(10, 5), rot_deg_s=8, seed=3)
    ev = ev[ev["x"] < 200]
    both = ReferenceTracker(ModelSet([a, b], prm))
    alone = ReferenceTracker(ModelSet([a], prm))
    for t, x, y in zip(ev["t"].tolist(), ev["x"].tolist(), ev["y"].tolist()):
        assert both.step(t, x, y) == alone.step(t, x, y)
    assert both.mx[:9] == alone.mx and both.my[:9] == alone.my
    assert both.mean_energies[0] == alone.mean_energy and both.frame(0) == alone.frame()
    assert both.energy[2][:12] == alone.energy[2]
    assert both.sensitive[:9] == alone.sensitive
    rest = b.arrays()
    assert both.mx[9:] == list(rest["x"]) and both.mean_energies[1] == 0.0


def _on_trackers(model, n, t):
    """``n`` events at times ``t`` placed exactly on ``model``'s tracker means in turn
    (integer positions at rest): each one lands at d^2 = 0 of its tracker."""
    a = model.arrays()
    k = np.arange(n) % len(a["x"])
    return make(t, a["x"][k].astype(np.int64), a["y"][k].astype(np.int64), k % 2)


@pytest.mark.parametrize("backend", ["reference", "cython", "fixed"])
def test_an_object_keeps_its_spring_pace_when_another_comes_into_view(backend):
    """Each instance's spring clock counts the events it takes and those no tracker takes
    near it or near no instance: object A's events as in a run alone, object B far away
    with as many events, each exactly on one of B's trackers (all taken by B): A's track
    equals A alone, sample for sample, and its springs ran as often.  (With one clock for
    all, B's events would double the pace of A's springs.)"""
    a, b = two_grids()
    prm = {"spring_period": 5}
    ev, _ = blob_stream(a, 6000, noise=0.1, speed_px_s=(10, 5), rot_deg_s=8, seed=3)
    ev = np.sort(ev[ev["x"] < 200], order="t", kind="stable")    # (its noise comes last)
    t = np.sort(np.random.default_rng(4).integers(int(ev["t"][0]) + 1, int(ev["t"][-1]), len(ev)))
    both_ev = np.sort(np.concatenate([ev, _on_trackers(b, len(ev), t)]), order="t", kind="stable")
    alone = springtrack.Tracker(a, prm, backend=backend)
    both = springtrack.Tracker([a, b], prm, backend=backend)
    ta, tb = alone.run(ev, 1000), both.run(both_ev, 1000)
    rows = len(ta)
    assert rows > 10 and np.array_equal(ta.t_us, tb.t_us[:rows])
    for f in ("x", "y", "sxx", "syy", "sensitive"):
        assert np.array_equal(getattr(ta, f), getattr(tb, f)[:rows, :9]), f
    ca, cb = alone.counters, both.counters
    assert cb["events_assigned"] == ca["events_assigned"] + len(ev)     # B took all of its own
    free = len(ev) - ca["events_assigned"]
    assert ca["spring_updates"] == len(ev) // 5 > 100
    # B's clock: its own events, and of A's that no one took those before its first update
    # (its spring box then holds every event) and those outside A's box
    assert len(ev) // 5 < cb["spring_updates"] - ca["spring_updates"] < (len(ev) + free) // 5


@pytest.mark.parametrize("backend", ["reference", "cython", "fixed"])
def test_an_event_no_tracker_takes_counts_on_the_clocks_near_it(backend):
    """Each instance's spring box (reference.py, SPRING_BOX_PX): after an instance's
    first spring update, an event no tracker takes within SPRING_BOX_PX of its means
    counts on its clock only; one outside every box on every clock."""
    a = ShapeModel("a", W, H, [TrackerSpec("a", 40.0, 40.0, (4.0, 0.0, 4.0))], [])
    b = ShapeModel("b", W, H, [TrackerSpec("b", 200.0, 150.0, (4.0, 0.0, 4.0))], [])
    tr = springtrack.Tracker([a, b], {"spring_period": 4}, backend=backend)

    def run(t0, xs, ys):
        tr.process(make(np.arange(t0, t0 + len(xs)), np.array(xs), np.array(ys),
                        np.arange(len(xs)) % 2))
        return tr.counters["spring_updates"], tr.counters["events_assigned"]

    assert run(1, [40] * 4 + [200] * 4, [40] * 4 + [150] * 4) == (2, 8)   # each its own
    d = SPRING_BOX_PX
    assert run(10, [40 + d] * 8, [40 - d] * 8) == (4, 8)        # A's box corner: A's only
    assert run(20, [40 + d + 1] * 8, [40] * 8) == (8, 8)        # outside both: both
    assert run(30, [200] * 8, [150 + d] * 8) == (10, 8)         # B's box: B's only
    assert run(40, [200 - d - 1] * 4, [150] * 4) == (12, 8)     # outside both again


def test_mixed_models_each_with_its_own_criteria():
    """A face (Euclidean energy, alpha1 0.2) and a grid (Cartesian, alpha1 0.02) in one
    tracker track their own blobs."""
    g = grid3x3(cx=90, cy=120, spacing=30, sigma_px=4, width=W, height=H)
    f = face26(cx=290, cy=120, scale=110, width=W, height=H)
    eg, _ = blob_stream(g, 20000, noise=0.1, speed_px_s=(8, 4), seed=1)
    ef, _ = blob_stream(f, 40000, noise=0.1, speed_px_s=(-6, 3), seed=2)
    ev = np.sort(np.concatenate([eg, ef]), order="t")
    tr = springtrack.Tracker([g, f], backend="reference")
    tr.run(ev, 10_000)
    st = tr.state()
    t = ev["t"][-1] / 1e6
    assert np.allclose(st["x"][:9], np.array(g.arrays()["x"]) + 8 * t, atol=2.5)
    assert np.allclose(st["x"][9:], np.array(f.arrays()["x"]) - 6 * t, atol=4.0)
    e = tr.energies()
    assert e["means"][0] > 0 and e["means"][1] > 0 and len(e["euclidean"]) == 12 + 40


def test_loss_rule_counts_active_trackers_over_the_hold():
    rule = LossRule([(0, 9), (9, 35)], 3000)
    act = np.zeros(35, bool)
    act[9:35] = True
    act[:3] = True                                  # 3 of 9: not below a third
    assert rule.check(0, act, [True, True]) == []
    act[2] = False                                  # 2 of 9: low from t = 1000
    for t in (1000, 2000, 3000):
        assert rule.check(t, act, [True, True]) == []
    assert rule.check(4000, act, [True, True]) == [0]
    assert rule.check(5000, act, [False, True]) == []   # lost: no longer watched
    act[:] = False
    rule.check(6000, act, [True, True])
    act[:5] = act[10:20] = True                     # back above a third: the clocks restart
    rule.check(7000, act, [True, True])
    act[:] = False
    assert rule.check(9500, act, [True, True]) == [] and rule.check(12500, act, [True, True]) == [0, 1]


def _face_then_grid():
    """A face whose events stop at 0.1 s while a grid keeps the clock running."""
    f = face26(cx=100, cy=120, scale=100, width=W, height=H)
    g = grid3x3(cx=300, cy=120, spacing=30, width=W, height=H)
    ef, _ = blob_stream(f, 30000, noise=0.0, speed_px_s=(0, 0), seed=5)     # 0.1 s
    eg, _ = blob_stream(g, 90000, noise=0.0, speed_px_s=(0, 0), seed=6)     # 0.3 s
    return f, g, ef, np.sort(np.concatenate([ef, eg]), order="t")


def test_loss_rule_marks_an_instance_lost_when_its_events_stop():
    """Two instances on the reference: once fewer than a third of the face's trackers
    are active for 3 tau, the face is lost (insensitive, its positions kept); the grid is
    not."""
    f, g, ef, ev = _face_then_grid()
    tr = springtrack.Tracker([f, g], backend="reference", acquire=True,
                             acquire_bounds={"angle_deg": (-10, 10), "scale": (0.9, 1.1)})
    tr.process(ev[ev["t"] < 60_000])
    assert tr._ib.states() == [TRACKING, TRACKING]
    tr.process(ev[ev["t"] >= 60_000])
    assert [c[1:] for c in tr.changes] == [("face26#1", "acquired"), ("grid3x3#1", "acquired"),
                                           ("face26#1", "lost")]
    assert tr._ib.states() == [LOST, TRACKING]
    lost_at = tr.changes[2][0]
    stop, hold = int(ef["t"][-1]), loss_hold_us(tr.params)
    # inactive after ~tau ln(A / A_up), then the hold, checked every LOSS_CHECK_US
    assert stop + hold < lost_at < stop + hold + 4 * tr.params.activity_tau_us + 2 * LOSS_CHECK_US
    st = tr.state()
    assert (st["state"][:26] == LOST).all() and (st["state"][26:] == TRACKING).all()
    assert not st["sensitive"][:26].any() and st["sensitive"][26:].all()
    c = tr.counters
    assert c["lost"] == 1 and c["acquired"] == 2 and c["reacquired"] == 0
    assert c["reacquire_attempts"] >= 1             # searched for, not found


@pytest.mark.parametrize("backend", ["cython", "fixed", "reference"])
def test_loss_rule_is_the_same_in_every_backend(backend):
    """One face whose events stop: lost at the same check time in every backend; while
    lost its trackers take no event and keep their positions; the rows say lost."""
    f, g, ef, ev = _face_then_grid()
    ev = ev[ev["x"] < 200]                              # the face alone, then silence ...
    tail = ev[-1:].copy()
    far = np.array([(t, 399, 239, 1) for t in range(int(ev["t"][-1]) + 500, 200_000, 200)],
                   ev.dtype)                            # ... but for one hot pixel far away
    ev = np.concatenate([ev, far])
    tr = springtrack.Tracker(f, backend=backend, acquire=True,
                             acquire_bounds={"angle_deg": (-10, 10), "scale": (0.9, 1.1)})
    track = tr.run(ev, 5000)
    kinds = [(c[1], c[2]) for c in tr.changes]
    assert kinds == [("face26#1", "acquired"), ("face26#1", "lost")]
    lost_at = tr.changes[1][0]
    stop = int(ef["t"][-1])
    assert stop + loss_hold_us(tr.params) < lost_at < stop + 80_000
    after = track.t_us >= lost_at                       # a change at T shows from the row at T
    assert (track.state[after] == LOST).all() and (track.state[~after] == TRACKING).all()
    assert np.ptp(track.x[after], axis=0).max() == 0.0   # positions kept
    assert tr.counters["events_valid"] == len(ev)
    global _LOST_AT
    if backend == "cython":
        _LOST_AT = lost_at
    else:
        assert lost_at == _LOST_AT


def test_placing_an_instance_resets_it_to_the_placed_model():
    f = face26(width=W, height=H)
    ref = ReferenceTracker(ModelSet([f, f], {"spring_period": 5}))
    ev, _ = blob_stream(f, 2000, seed=1)
    for t, x, y in zip(ev["t"].tolist(), ev["x"].tolist(), ev["y"].tolist()):
        ref.step(t, x, y)
    moved = face26(cx=250, cy=100, scale=80, width=W, height=H)
    ref.set_state(1, LOST)
    ref.place(1, moved)
    fresh = ReferenceTracker(ModelSet([moved]))
    assert ref.state[1] == TRACKING and all(ref.sensitive[26:])
    assert ref.mx[26:] == fresh.mx and ref.sxx[26:] == fresh.sxx
    assert ref.l0[40:] == fresh.l0 and ref.frame(1) == fresh.frame()
    assert ref.act[26:] == [0.0] * 26


def two_grid_files(tmp_path, count):
    """two_grids() saved as a.toml, b.toml and ``count`` events of each in ev.npy."""
    a, b = two_grids()
    pa, pb = tmp_path / "a.toml", tmp_path / "b.toml"
    a.save(pa)
    b.save(pb)
    ev = np.sort(np.concatenate([blob_stream(a, count, seed=1)[0],
                                 blob_stream(b, count, seed=2)[0]]), order="t")
    np.save(tmp_path / "ev.npy", ev)
    return pa, pb


def test_track_cli_several_models_and_collided_ids(tmp_path, capsys):
    from springtrack import cli
    from springtrack.track import read_csv
    pa, pb = two_grid_files(tmp_path, 3000)
    out = tmp_path / "t.csv"
    assert cli.main(["track", str(tmp_path / "ev.npy"), "--model", str(pa), "--model", str(pb),
                     "--backend", "reference", "--out", str(out), "--no-progress"]) == 0
    tr = read_csv(out)
    assert tr.ids[0] == "grid3x3#1/r0c0" and tr.ids[9] == "grid3x3#2/r0c0"
    assert (tr.state == TRACKING).all()
    assert cli.main(["track", str(tmp_path / "ev.npy"), "--model", str(pa), "--instances", "2",
                     "--out", str(out), "--no-progress"]) != 0
    assert "add --acquire" in capsys.readouterr().err


def test_the_float_kernel_holds_a_set_up_to_the_limits():
    """16 instances of a 16-tracker model: 256 trackers (four mask words) and their
    connections; each instance takes the events of its own blobs, as in the reference;
    the fixed kernel within its bound of the float kernel."""
    specs = [TrackerSpec(f"t{j}", 8.0 + 6.0 * (j % 4), 8.0 + 6.0 * (j // 4), (2.0, 0.0, 2.0))
             for j in range(16)]
    conns = [Connection(f"t{j}", f"t{j + 1}", ("euclidean",), 0.05) for j in range(15)]
    models = []
    for k in range(MAX_INSTANCES):
        dx, dy = 40.0 * (k % 8), 40.0 * (k // 8)
        models.append(ShapeModel("sq", 320, 80, [TrackerSpec(s.id, s.x + dx, s.y + dy, s.sigma)
                                                 for s in specs], conns))
    assert sum(len(m.trackers) for m in models) == MAX_SET_TRACKERS
    evs = [blob_stream(m, 250, rate_hz=20_000, noise=0.0, speed_px_s=(40, 20), seed=k)[0]
           for k, m in enumerate(models)]
    ev = np.sort(np.concatenate(evs), order="t", kind="stable")
    tr, ref = springtrack.Tracker(models), springtrack.Tracker(models, backend="reference")
    ta, tb = tr.run(ev, 1000), ref.run(ev, 1000)
    st = tr.state()
    assert len(st) == MAX_SET_TRACKERS
    assert (st["activity"].reshape(MAX_INSTANCES, 16).max(axis=1) > 0).all()   # every instance fed
    assert tr.counters["events_assigned"] > 0.8 * len(ev)
    assert tr.counters["events_assigned"] == ref.counters["events_assigned"]
    np.testing.assert_allclose(ta.x, tb.x, rtol=0, atol=1e-9)
    assert (ta.sensitive == tb.sensitive).all() and not ta.sensitive.all()   # eq. (21) acted
    with pytest.raises(ModelError, match="exceed the limit of 16"):
        springtrack.Tracker(models + models[:1])
    # the integer kernel holds it too (one state per instance), within its bound
    from support.fixed_bound import figures, violations
    fx = springtrack.Tracker(models, backend="fixed")
    tf = fx.run(ev, 1000)
    assert fx.counters["events_assigned"] == tr.counters["events_assigned"]
    assert not violations(figures(ta, tf)), violations(figures(ta, tf))
    with pytest.raises(ModelError, match="exceed the limit of 16"):
        springtrack.Tracker(models + models[:1], backend="fixed")


def test_track_cli_several_models_on_the_default_backend(tmp_path, capsys):
    """``springtrack track --model A --model B --acquire`` without --backend: the float
    kernel holds both; its rows equal the reference's."""
    from springtrack import cli
    from springtrack.track import read_csv
    pa, pb = two_grid_files(tmp_path, 6000)
    rows = {}
    for backend in ("cython", "reference"):
        out = tmp_path / f"{backend}.csv"
        args = ["track", str(tmp_path / "ev.npy"), "--model", str(pa), "--model", str(pb),
                "--acquire", "--out", str(out), "--no-progress"]
        assert cli.main(args + (["--backend", backend] if backend == "reference" else [])) == 0
        rows[backend] = read_csv(out)
    ta, tb = rows["cython"], rows["reference"]
    assert ta.ids == tb.ids and ta.ids[9] == "grid3x3#2/r0c0"
    assert np.array_equal(ta.t_us, tb.t_us) and (ta.state == TRACKING).all()
    np.testing.assert_allclose(ta.x, tb.x, rtol=0, atol=1e-6)
