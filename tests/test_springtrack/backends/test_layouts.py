"""Event arrays of any common layout reach the kernels as they are (springtrack.backends.stepper:
converted block by block inside the loop): the same track, bit for bit, as EVENT_DTYPE."""
from __future__ import annotations

import numpy as np
import pytest

from springtrack.backends.stepper import layout_of
from springtrack.events import EVENT_DTYPE, as_events
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
