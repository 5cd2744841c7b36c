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
    """One kernel call into a buffer sized for the run (Tracker.run's room), the same
    overflowing into per-call buffers, a room mostly unused, ~70 calls of 7 rows, and
    process + samples in 13 pieces: the same samples, bit for bit."""
    def run(cap=None, room=None, end_t=None):
        if cap is not None:
            monkeypatch.setattr(tracker_mod, "SAMPLE_CAP", cap)
        if room is not None:
            monkeypatch.setattr(tracker_mod, "ROOM_BYTES", room)
        ev = events
        if end_t is not None:              # the last event's time sizes the room
            ev = events.copy()
            ev["t"][-1] = end_t
        got = Tracker("face26", backend=backend).run(ev, P)
        monkeypatch.undo()
        return got

    whole = run(room=0)                                 # one call, SAMPLE_CAP rows
    assert len(whole) > 400 and whole.rows() is not None
    assert_same(whole, run(cap=7, room=0))              # ~70 calls joined
    assert_same(whole, run(cap=7))                      # one call into the room
    last = int(events["t"][-2])
    short = run(cap=7, end_t=last)                      # the room one row short: the rest
    assert_same(whole, short)                           # in calls of 7 rows
    stretched = run(cap=7, end_t=last + 5000 * P)       # the room mostly unused: copied
    assert_same(stretched, run(cap=7, room=0, end_t=last + 5000 * P))
    rows = stretched.rows()
    assert len(stretched) < len(whole) + 10 and rows.base.nbytes == rows.nbytes
    tr = Tracker("face26", backend=backend)
    tr.record(P)
    for part in np.array_split(events, 13):
        tr.process(part)
    assert_same(whole, tr.samples())
    monkeypatch.setattr(tracker_mod, "SAMPLE_CAP", 7)
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


def test_run_writes_its_rows_once_into_a_buffer_sized_ahead(events, monkeypatch):
    """Tracker.run sizes one buffer from the events' span: the kernel writes every row
    there in one call, nothing is joined afterwards."""
    monkeypatch.setattr(tracker_mod, "SAMPLE_CAP", 7)
    joined = []
    concat = Track.concat.__func__
    monkeypatch.setattr(Track, "concat", classmethod(
        lambda cls, parts, ids: joined.append(len(parts)) or concat(cls, parts, ids)))
    got = Tracker("face26").run(events, P)
    assert len(got) > 400 and not joined
