"""A Track keeps the kernel's sample rows (its fields views of them) and joins parts row by
row: the sampled values are the same bit for bit however the samples are taken (one
kernel call or many, ``run``, ``process`` + ``samples`` or ``stream``), and a Track whose
field was replaced is joined field by field."""
import numpy as np
import pytest

import springtrack.tracker as tracker_mod
from springtrack import Tracker
from springtrack.sim.synthetic import blob_stream
from springtrack.track import TRACK_DTYPE, TRACK_FIELDS, Track

P = 250                                  # µs: ~75 samples per 300 k events/s stretch


@pytest.fixture(scope="module")
def events():
    model = Tracker("face26").model
    ev, _ = blob_stream(model, 40_000, noise=0.3, speed_px_s=(15, -8), rot_deg_s=5, seed=4)
    return ev


def assert_same(a: Track, b: Track):
    assert np.array_equal(a.t_us, b.t_us)
    for f in TRACK_FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f),
                              equal_nan=getattr(a, f).dtype.kind == "f"), f
    assert np.array_equal(a.energy, b.energy)


@pytest.mark.parametrize("backend", ["cython", "fixed"])
def test_chunked_and_unchunked_samples_are_identical(events, backend, monkeypatch):
    whole = Tracker("face26", backend=backend).run(events, P)
    assert len(whole) > 400 and whole.rows() is not None
    monkeypatch.setattr(tracker_mod, "SAMPLE_CAP", 7)               # ~70 kernel calls
    chunked = Tracker("face26", backend=backend).run(events, P)
    assert_same(whole, chunked)
    tr = Tracker("face26", backend=backend)
    tr.record(P)
    for part in np.array_split(events, 13):
        tr.process(part)
    assert_same(whole, tr.samples())
    tr = Tracker("face26", backend=backend)
    tr.record(P)
    parts = list(tr.stream(events))
    assert len(parts) > 50 and all(len(p) <= 7 for p in parts)
    by_field = Track(np.concatenate([p.t_us for p in parts]), tr.ids,
                     energy=np.concatenate([p.energy for p in parts]),
                     **{f: np.concatenate([getattr(p, f) for p in parts]) for f in TRACK_FIELDS})
    assert_same(whole, by_field)


def test_run_keeps_its_samples_once(events):
    tr = Tracker("face26")
    got = tr.run(events, P)
    kept = tr.samples()
    assert_same(got, kept)
    assert np.shares_memory(got.x, kept.x)          # not copied a second time
    assert len(tr.samples()) == 0


def test_a_replaced_field_is_joined_field_by_field(events):
    tr = Tracker("face26")
    tr.record(P)
    (a,), (b,) = list(tr.stream(events[:10_000])), list(tr.stream(events[10_000:20_000]))
    assert a.rows() is not None
    a.x = a.x + 1.0                                   # no longer a view of its rows
    assert a.rows() is None
    joined = Track.concat([a, b], tr.ids)
    assert np.array_equal(joined.x, np.concatenate([a.x, b.x]))
    assert np.array_equal(joined.sxx, np.concatenate([a.sxx, b.sxx]))
    rows = Track.concat([b, b], tr.ids)
    assert rows.rows() is not None and rows.rows().dtype == TRACK_DTYPE
    assert np.array_equal(rows.state, np.concatenate([b.state, b.state]))
