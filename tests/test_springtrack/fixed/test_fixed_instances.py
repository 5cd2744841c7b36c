"""Several model instances on the fixed kernel (springtrack.fixed.kernel.FixedSet: one fx_state
per instance, one event assignment over all): one instance equals FixedKernel bit for
bit, instances that see no common event equal each alone bit for bit, and random sets
(two different models, N copies of one, with moves, with a lost instance) stay within
the fixed kernel's documented bound (tests/support/fixed_bound.py) of the float kernel (equal to
the reference, the specification of several instances, to 1e-9 px)."""
import numpy as np
import pytest

import springtrack
from springtrack.fixed import kernel as _fixed
from springtrack.instances import LOST, SEARCHING, TRACKING, ModelSet
from springtrack.model import ShapeModel, TrackerSpec, face26, grid3x3
from springtrack.params import resolve
from springtrack.sim.synthetic import blob_stream

from support.fixed_bound import figures, violations
from support.moves import similarity

W, H = 400, 240
SPRINGS = {"spring_period": 5}


def _merged(*streams):
    return np.sort(np.concatenate(streams), order="t", kind="stable")


def _raw(k):
    return {key: v.copy() for key, v in k.raw_state().items()}


def test_one_instance_set_equals_the_fixed_kernel_bit_for_bit():
    f = face26(width=W, height=H)
    ev, _ = blob_stream(f, 20000, noise=0.2, speed_px_s=(9, -4), rot_deg_s=6, seed=2)
    one = _fixed.FixedKernel(f, resolve(f, SPRINGS))
    st = _fixed.FixedSet(ModelSet([f], SPRINGS))
    a = one.run(ev, 1000, -(1 << 63), 4096)
    b = st.run(ev, 1000, -(1 << 63), 4096)
    assert a[:2] == b[:2]
    for key in ("t", "energy"):
        assert np.array_equal(a[2][key], b[2][key]), key
    for f_ in ("x", "y", "sxx", "sxy", "syy", "activity", "active", "sensitive", "state"):
        assert np.array_equal(a[2]["trackers"][f_], b[2]["trackers"][f_]), f_
    assert one.counters() == st.counters()
    assert np.array_equal(one.energies(), st.energies()) and one.frame() == st.frame(0)
    assert one.telemetry_records(int(ev["t"][-1])) == st.telemetry_records(int(ev["t"][-1]))


def test_an_instance_alone_in_its_events_equals_its_model_alone_bit_for_bit():
    """A grid and a face far apart, each with its own parameters (the presets' [params]),
    events of one of them only: that instance's state, energies and frame equal its
    model alone, bit for bit; the other stays where it was placed."""
    g = grid3x3(cx=90, cy=120, spacing=30, sigma_px=4, width=W, height=H)
    f = face26(cx=290, cy=120, scale=110, width=W, height=H)
    eg, _ = blob_stream(g, 8000, noise=0.0, speed_px_s=(8, 4), seed=1)
    ef, _ = blob_stream(f, 16000, noise=0.0, speed_px_s=(-6, 3), seed=2)
    mset = ModelSet([g, f], SPRINGS)
    assert mset[0].params.alpha_position != mset[1].params.alpha_position
    for q, (m, ev) in enumerate(((g, eg[eg["x"] < 170]), (f, ef[ef["x"] > 200]))):
        both = _fixed.FixedSet(mset)
        both.run(ev, 0, -(1 << 63), 0)
        alone = _fixed.FixedKernel(m, mset[q].params)
        alone.run(ev, 0, -(1 << 63), 0)
        t = int(ev["t"][-1])
        st, ref = both.snapshot(t), alone.snapshot(t)
        part = slice(mset[q].t0, mset[q].t1)
        for key in ("x", "y", "sxx", "sxy", "syy", "activity", "sensitive"):
            assert np.array_equal(st[key][part], ref[key]), (q, key)
        assert both.frame(q) == alone.frame() and both.mean_energies()[q] == alone.mean_energy
        assert np.array_equal(both.energies()[:, mset[q].c0:mset[q].c1], alone.energies())
        other = mset[1 - q]
        np.testing.assert_allclose(st["x"][other.t0:other.t1], other.model.arrays()["x"],
                                   rtol=0, atol=1e-5)     # its springs at rest: Q.32 rounding
        # its clock counts every event (the other takes none); the other's those no
        # tracker took until its first update (its spring box then held every event), then
        # none: they fall inside the first's box (reference.py: each instance's spring clock)
        assert len(ev) - both.counters()["events_assigned"] >= 10
        assert both.counters()["spring_updates"] == len(ev) // 5 + 1
        assert both.counters()["events_valid"] == len(ev)


def test_an_event_feeds_one_tracker_of_one_instance_ties_to_the_first():
    one = ShapeModel("p", 64, 48, [TrackerSpec("a", 20.0, 20.0, (4.0, 0.0, 4.0))], [])
    two = ShapeModel("p", 64, 48, [TrackerSpec("a", 24.0, 20.0, (4.0, 0.0, 4.0))], [])
    st = _fixed.FixedSet(ModelSet([one, two], {"spring_period": 10 ** 6}))
    assert st.step(0, 21, 20) == 0
    assert st.step(1, 25, 20) == 1
    st = _fixed.FixedSet(ModelSet([one, one], {"spring_period": 10 ** 6}))
    assert st.step(0, 20, 20) == 0                 # a tie: the first instance
    assert st.counters()["events_assigned"] == 1 and st.snapshot(0)["activity"][1] == 0.0
    assert st.step(1, 60, 40) == -1
    st.set_state(0, LOST)                          # not tracking: takes no event
    assert st.step(2, 20, 20) == 1 and st.states() == [LOST, TRACKING]
    assert not st.snapshot(2)["sensitive"][0]


def _copies(model, count, rng):
    """``count`` copies of ``model`` placed apart (moved by random similarities), and their
    events."""
    out = [model]
    for _ in range(count - 1):
        dx = float(rng.uniform(-120, 120))
        out.append(similarity(model, dx, float(rng.uniform(-40, 40)),
                              float(rng.uniform(-20, 20)), float(rng.uniform(0.9, 1.1)))[1])
    return out


CASES = ["grid+face", "3 grids", "2 faces"]


def _case(name, seed):
    rng = np.random.default_rng(seed)
    if name == "grid+face":
        g = grid3x3(cx=float(rng.uniform(70, 120)), cy=120, spacing=30, width=W, height=H)
        f = face26(cx=float(rng.uniform(260, 320)), cy=120, scale=100, width=W, height=H)
        return [g, f], [g, f]
    base = (grid3x3(cx=200, cy=120, spacing=24, width=W, height=H) if name == "3 grids"
            else face26(cx=200, cy=120, scale=70, width=W, height=H))
    placed = _copies(base, 3 if name == "3 grids" else 2, rng)
    return [base], placed


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("name", CASES)
def test_random_sets_stay_within_the_bound_of_the_float_kernel(name, seed):
    """A set (its models, or N copies of one placed apart) on the merged streams of its
    instances' parts, an instance moved rigidly half way (the stream follows it): the
    fixed kernel within its documented bound of the float kernel, before and after the
    move, each instance's frame and mean energy close, the same events assigned."""
    models, placed = _case(name, seed)
    count = len(placed) // len(models)
    rng = np.random.default_rng(100 + seed)
    streams = [blob_stream(m, 20000, noise=0.1, speed_px_s=tuple(rng.uniform(-8, 8, 2)),
                           rot_deg_s=float(rng.uniform(-5, 5)), seed=seed * 10 + q)[0]
               for q, m in enumerate(placed)]
    ev = _merged(*streams)
    half = int(ev["t"][len(ev) // 2])
    g = len(placed) - 1
    sim, moved = similarity(placed[g], 15.0, -10.0, 8.0, 1.05)
    a, b, tx, ty = sim
    late = ev["t"] >= half
    mine = np.isin(np.arange(len(ev)), np.flatnonzero(late)) & _owned(ev, streams[g])
    x, y = ev["x"][mine].astype(float), ev["y"][mine].astype(float)
    ev["x"][mine] = np.clip(np.rint(a * x - b * y + tx), 0, W - 1)
    ev["y"][mine] = np.clip(np.rint(b * x + a * y + ty), 0, H - 1)
    tracks, trackers = {}, {}
    for backend in ("cython", "fixed"):
        tr = springtrack.Tracker(models, SPRINGS, backend=backend, instances=count)
        for q, m in enumerate(placed):
            if m is not tr.models[q].model:
                tr._ib.place(q, m)
        t1 = tr.run(ev[~late], 1000)
        tr._ib.move(g, sim, moved)
        tracks[backend] = (t1, tr.run(ev[late], 1000))
        trackers[backend] = tr
    ref, fx = trackers["cython"], trackers["fixed"]
    for p, q in zip(tracks["cython"], tracks["fixed"]):
        res = figures(p, q)
        assert res["samples"] > 25 and not violations(res), (name, violations(res))
    assert ref.counters["events_assigned"] == fx.counters["events_assigned"]
    assert ref.counters["spring_updates"] == fx.counters["spring_updates"]
    for q in range(len(placed)):
        np.testing.assert_allclose(fx.frame(q)["gx"], ref.frame(q)["gx"], atol=0.05)
        np.testing.assert_allclose(fx.frame(q)["angle"], ref.frame(q)["angle"], atol=1e-3)
    np.testing.assert_allclose(fx.energies()["means"], ref.energies()["means"], rtol=0.02,
                               atol=1e-6)


def _owned(ev, part):
    """Which events of the merged ``ev`` come from ``part`` (by time, x and y)."""
    key = lambda e: e["t"].astype(np.int64) * (1 << 32) + e["x"].astype(np.int64) * 65536 + e["y"]
    return np.isin(key(ev), key(part))


def test_lost_and_searching_instances_as_in_the_float_kernel():
    """The first instance lost, the second searching then placed: neither takes events
    nor runs springs while not tracking; rows carry the states; the same as the float
    kernel within the bound."""
    g = grid3x3(cx=100, cy=120, spacing=30, width=W, height=H)
    f = face26(cx=290, cy=120, scale=100, width=W, height=H)
    ev = _merged(blob_stream(g, 6000, seed=1)[0], blob_stream(f, 12000, seed=2)[0])
    cut = len(ev) // 3
    out = {}
    for backend in ("cython", "fixed"):
        tr = springtrack.Tracker([g, f], SPRINGS, backend=backend)
        tr._ib.set_state(0, LOST)
        tr._ib.set_state(1, SEARCHING)
        t1 = tr.run(ev[:cut], 1000)
        tr._ib.place(1, f)
        out[backend] = (t1, tr.run(ev[cut:], 1000), tr.counters)
    (r1, r2, rc), (f1, f2, fc) = out["cython"], out["fixed"]
    assert (f1.state[:, :9] == LOST).all() and (f1.state[:, 9:] == SEARCHING).all()
    assert not f1.sensitive.any() and np.ptp(f1.x, axis=0).max() == 0.0
    assert (f2.state[:, 9:] == TRACKING).all()
    for p, q in ((r1, f1), (r2, f2)):
        assert np.array_equal(p.state, q.state)
        assert not violations(figures(p, q))
    assert rc["events_assigned"] == fc["events_assigned"] > 0


def test_tracker_holds_several_instances_on_fixed_and_refuses_beyond_the_limits():
    from springtrack.limits import MAX_INSTANCES
    from springtrack.model import ModelError
    g = grid3x3(cx=100, cy=120, spacing=30, width=W, height=H)
    tr = springtrack.Tracker([g, face26(width=W, height=H)], backend="fixed")
    assert len(tr.state()) == 9 + 26 and [i["state"] for i in tr.instances()] == ["tracking"] * 2
    with pytest.raises(ModelError, match=f"{MAX_INSTANCES + 1} instances exceed the limit "
                                         f"of {MAX_INSTANCES}"):
        springtrack.Tracker(g, backend="fixed", instances=MAX_INSTANCES + 1)
