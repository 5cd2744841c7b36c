"""Event arrays of any common layout reach the kernels as they are (springtrack.backends.stepper:
converted block by block inside the loop): the same track, bit for bit, as EVENT_DTYPE."""
from __future__ import annotations

import numpy as np
import pytest

from springtrack.backends.stepper import in_range, layout_of
from springtrack.events import EVENT_DTYPE, T_MAX, T_MIN, EventError, as_events, check
from springtrack.sim.sensor import simulate_all
from springtrack.sampling import UNSET
from springtrack.tracker import Tracker, make_backend

LAYOUTS = {
    "packed i64/i16/bool": ([("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "?")], False),
    "aligned u64/u16/u8, t last": ([("x", "<u2"), ("y", "<u2"), ("p", "u1"), ("t", "<u8")], True),
    "packed i32 t, i32 p": ([("t", "<i4"), ("x", "<u2"), ("y", "<u2"), ("p", "<i4")], False),
    "u32 t, i64 x/y, extra field": ([("p", "<i2"), ("t", "<u4"), ("extra", "<f8"),
                                     ("y", "<i8"), ("x", "<i8")], False),
}


@pytest.fixture(scope="module")
def face():
    ev, _ = simulate_all("face_occlusion", 0.3, seed=2)
    return ev


def as_layout(ev, fields, align):
    out = np.zeros(len(ev), np.dtype(fields, align=align))
    for f in ("t", "x", "y", "p"):
        out[f] = ev[f]
    return out


@pytest.mark.parametrize("name", LAYOUTS)
@pytest.mark.parametrize("backend", ["cython", "fixed"])
def test_every_layout_tracks_bit_for_bit_like_event_dtype(face, name, backend):
    arr = as_layout(face, *LAYOUTS[name])
    assert layout_of(arr) is not None
    ref = Tracker("face26", backend=backend).run(face, 1000)
    tr = Tracker("face26", backend=backend)
    got = tr.run(arr, 1000)
    assert np.array_equal(got.t_us, ref.t_us) and np.array_equal(got.x, ref.x)
    assert np.array_equal(got.syy, ref.syy) and np.array_equal(got.energy, ref.energy)
    assert tr.counters["events_valid"] == len(face)


def test_a_strided_view_and_a_full_sample_buffer_mid_block(face):
    """Every other event of a packed array (a strided view), through Kernel.run with a
    sample buffer of 3 rows: the loop stops inside a converted block and resumes there."""
    arr = as_layout(face, *LAYOUTS["packed i64/i16/bool"])[::2]
    want = as_events(arr)
    a, b = (make_backend("cython", Tracker("face26").model, Tracker("face26").params)
            for _ in range(2))
    outs = []
    for kern, ev in ((a, want), (b, arr)):
        pos, nt, rows = 0, UNSET, []
        while pos < len(ev):
            c, nt, s = kern.run(ev[pos:], 1000, nt, 3)
            pos += c
            rows.append(s["trackers"]["x"])
        outs.append(np.concatenate(rows))
    assert np.array_equal(outs[0], outs[1]) and len(outs[0]) > 100


def test_other_layouts_are_converted_or_refused_clearly(face):
    flt = np.zeros(10, [("t", "<f8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])
    assert layout_of(flt) is None and layout_of(face[["t", "x"]]) is None
    assert layout_of(np.zeros(4, [("t", ">i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])) is None
    k = make_backend("cython", Tracker("face26").model, Tracker("face26").params)
    with pytest.raises(TypeError, match="integer fields t, x, y, p"):
        k.run(flt, 1000, UNSET, 4)
    flt["t"] = np.arange(10) * 100.0
    flt["x"], flt["y"] = 150, 120
    tr = Tracker("face26")
    tr.process(flt)                      # converted first (as_events), then tracked
    assert tr.counters["events_valid"] == 10
    assert as_events(flt).dtype == EVENT_DTYPE


CHECKED = {
    "packed i64/i16/u8": [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")],
    "packed u64/u16/i8": [("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")],
    "EVENT_DTYPE": EVENT_DTYPE,
    "packed i64/i16/bool": [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "?")],
}
# (field, value) out of springtrack.events.RANGES where the field's type can hold it
BAD = [("t", T_MIN - 1), ("t", T_MAX + 1), ("t", 1 << 63), ("x", -1), ("y", -32768),
       ("p", 2), ("p", -1), ("p", 255)]


@pytest.mark.parametrize("name", CHECKED)
def test_the_one_pass_range_check_agrees_with_check(face, name):
    """in_range (one pass over the records, before the kernels read them as they are)
    finds an event out of range exactly where springtrack.events.check raises for it."""
    dt = np.dtype(CHECKED[name])
    ev = np.zeros(len(face), dt)
    for f in ("t", "x", "y", "p"):
        ev[f] = face[f]
    assert in_range(ev) is True
    assert in_range(ev[:0]) is True
    rng = np.random.default_rng(3)
    tried = 0
    for field, value in BAD:
        kind, size = dt.fields[field][0].kind, dt.fields[field][0].itemsize
        info = np.iinfo(dt.fields[field][0]) if kind in "iu" else None
        if info is None or not info.min <= value <= info.max:
            continue                     # the type cannot hold it: nothing to find
        bad = ev.copy()
        i = int(rng.integers(len(bad)))
        bad[field][i] = value
        with pytest.raises(EventError) as err:
            check(bad)
        assert err.value.index == i
        assert in_range(bad) is False
        with pytest.raises(EventError):
            Tracker("face26").process(bad)
        tried += 1
    assert tried >= 3


def test_the_range_check_leaves_other_layouts_to_check(face):
    odd = np.zeros(4, [("t", "<i4"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])
    assert in_range(odd) is None
    assert in_range(np.zeros(4, [("t", "<i8"), ("x", "<i2"), ("y", "<u2"), ("p", "u1")])) is None
    assert in_range(np.zeros(4)) is None
