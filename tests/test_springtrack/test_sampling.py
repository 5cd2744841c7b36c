"""The sampling rule, written once per language (springtrack/sampling.py and
springtrack/csrc/sampling.h): the C loops (run_events and the kernels' batch steps, behind
the "cython" and "fixed" backends) and their Python mirrors (ReferenceBackend.run,
ReferenceTracker.run) take the same snapshots on streams with backward times, ties, gaps
longer than a kernel call's sample buffer, negative times and events outside the sensor.
Also: the track record's C view (track.pxd TrackRow) is checked against TRACK_DTYPE."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from springtrack import sampling
from springtrack.events import make
from springtrack.reference import ReferenceTracker
from springtrack.track import TRACK_FIELDS
from springtrack.tracker import SAMPLE_CAP, Tracker

P = 1000
MODEL = "grid3x3"


def stream(times, outside=()):
    """Events at ``times`` near the grid's centre; those at indices ``outside`` off the sensor."""
    n = len(times)
    x = np.full(n, 150)
    x[list(outside)] = 5000
    return make(np.asarray(times, np.int64), x, np.full(n, 120), np.ones(n))


def tracks(ev, chunks=None):
    """The track of each backend, fed whole or in chunks split at ``chunks``."""
    out = {}
    for backend in ("reference", "cython", "fixed"):
        tr = Tracker(MODEL, backend=backend)
        tr.record(P)
        for part in np.split(ev, chunks or []):
            tr.process(part)
        out[backend] = tr.samples()
    return out


def assert_agree(ev, chunks=None):
    got = tracks(ev, chunks)
    ref = ReferenceTracker(Tracker(MODEL).model, Tracker(MODEL).params)
    spec = ref.run(ev, P)
    t_spec = [t for t, _ in spec]
    for backend, track in got.items():
        assert list(track.t_us) == t_spec, backend
    a, b = got["cython"], got["reference"]
    for f in TRACK_FIELDS:                              # the same states at those times
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=0, atol=1e-9, err_msg=f)
    if spec:
        np.testing.assert_allclose(b.x[-1], spec[-1][1][0], rtol=0, atol=0)
    return t_spec


def test_hand_case_backward_time_ties_and_a_gap():
    # 100 sets the first sample time 1000; 2500 takes 1000 and 2000 (state after 100); 1500
    # is back in time: skipped, no sample; 2500 again is a tie, not due; 3000 takes 3000;
    # 7200 takes 4000 .. 7000
    times = [100, 2500, 1500, 2500, 3000, 7200]
    assert assert_agree(stream(times)) == [1000, 2000, 3000, 4000, 5000, 6000, 7000]


def test_an_event_on_a_sample_time_is_after_it():
    # the first event at a multiple of the period: the first sample is at its own time,
    # before it (the initial state); ties at a sample time take it once
    assert assert_agree(stream([2000, 2000, 2000, 3000])) == [2000, 3000]


def test_a_backward_event_across_a_sample_time_takes_no_sample():
    # first sample 2000; 900 and 1000 are back in time (skipped, no sample although 1000 is
    # a sample time); 1999 is not due; 2000 takes 2000 once; 2001 is not due
    assert assert_agree(stream([1200, 900, 1999, 2000, 1000, 2001])) == [2000]


def test_negative_times_and_events_outside_the_sensor():
    # an event off the sensor is not tracked but is time: it moves the clock and samples
    times = [-2500, -1000, -1000, 0, 1, 3001, 2999, 4000]
    assert assert_agree(stream(times, outside=[1, 5])) == [-2000, -1000, 0, 1000, 2000, 3000, 4000]


def test_more_samples_than_one_call_s_sample_buffer():
    # gaps of HOLD - 1 periods: every sample time is taken, more than a kernel call holds
    gap = (sampling.HOLD - 1) * P
    times = assert_agree(stream(5 + gap * np.arange(SAMPLE_CAP // (sampling.HOLD - 1) + 20)))
    assert times == list(range(P, times[-1] + 1, P)) and len(times) > SAMPLE_CAP


def test_an_empty_stretch_is_sampled_for_hold_periods_then_skipped():
    # after the event at 10, the sample times up to 10 + HOLD P; none until the next event;
    # from it sampling resumes as at a first event (its own time, a multiple, included)
    hold = sampling.HOLD * P
    t_end = 100 * hold
    times = assert_agree(stream([5, 10, t_end, t_end + 1, t_end + 2500]))
    assert times == list(range(P, hold + 1, P)) + [t_end, t_end + P, t_end + 2 * P]
    tr = Tracker(MODEL)
    tr.run(stream([5, 10, t_end, t_end + 1, t_end + 2500]), P)
    assert tr.counters["samples_skipped"] == t_end // P - 1 - sampling.HOLD   # 65 P .. t_end - P
    # a stretch of exactly HOLD periods loses nothing
    assert assert_agree(stream([10, hold + 10])) == list(range(P, hold + 1, P))


def test_next_sample():
    h = sampling.HOLD * P
    assert sampling.next_sample(5 * h, 3000, 2500, P) == 3000          # within the hold
    assert sampling.next_sample(5 * h, h + 3000, 2500, P) == 5 * h     # past it: skip to t
    assert sampling.next_sample(5 * h + 1, h + 3000, 2500, P) == 5 * h + P
    assert sampling.next_sample(h + 3000, h + 3000, 2500, P) == h + 3000   # t itself
    assert sampling.next_sample(-h - 1, -5 * h, -8 * h, P) == -h          # before 0 too


STEP = st.one_of(st.integers(-2500, 4000),
                 st.integers((sampling.HOLD - 2) * P, (sampling.HOLD + 2) * P),
                 st.integers(sampling.HOLD * P, 10 ** 9))


@settings(max_examples=60, deadline=None)
@given(st.lists(STEP, min_size=1, max_size=60),
       st.integers(-10_000, 10_000), st.lists(st.integers(1, 59), max_size=4))
def test_random_streams_with_backward_steps_ties_and_gaps(steps, t0, cuts):
    """Times as a walk with backward steps, repeats (step 0), jumps over several sample
    times and empty stretches around and far beyond HOLD periods, fed whole and in chunks:
    every backend and the specification agree."""
    times = t0 + np.cumsum(steps)
    ev = stream(times)
    whole = assert_agree(ev)
    cuts = sorted({c for c in cuts if c < len(ev)})
    assert assert_agree(ev, cuts) == whole


def test_first_sample_time_is_a_ceiling_multiple():
    assert [sampling.first_sample_time(t, 1000) for t in (-2500, -1000, 0, 1, 999, 1000)] == [
        -2000, -1000, 0, 1000, 1000, 1000]
    assert sampling.sample_due(5, 5, 5) and not sampling.sample_due(5, 6, 0)
    assert not sampling.sample_due(5, 0, 6)


def test_the_track_row_check_catches_a_layout_that_differs(monkeypatch):
    """_samples checks TrackRow (C) against TRACK_DTYPE at import; a dtype with two fields
    swapped or one missing fails that check."""
    import springtrack.backends.samples as samples
    from springtrack.track import TRACK_DTYPE
    samples._check_track_row()                                     # the real pair agrees
    fields = [(f, TRACK_DTYPE[f]) for f in TRACK_FIELDS]
    swapped = fields[:]
    swapped[0], swapped[1] = swapped[1], swapped[0]
    for bad, names in ((swapped, ("y", "x") + TRACK_FIELDS[2:]),
                       (fields[:-1] + [("sensitive_", "?")], TRACK_FIELDS[:-1] + ("sensitive_",))):
        monkeypatch.setattr(samples, "TRACK_DTYPE", np.dtype(bad, align=True))
        monkeypatch.setattr(samples, "TRACK_FIELDS", names)
        with pytest.raises(AssertionError):
            samples._check_track_row()


def test_finite_rows_flags_exactly_the_rows_with_a_non_finite_float_field():
    """The firmware's check before a snapshot is sent: every float field counts, the flags
    and the state do not; a strided view is read as the rows it shows."""
    from springtrack.backends.samples import finite_rows
    from springtrack.track import FLOAT_FIELDS, TRACK_DTYPE
    rows = np.zeros((2 * len(FLOAT_FIELDS) + 2, 3), TRACK_DTYPE)
    bad = np.zeros(len(rows), bool)
    for i, f in enumerate(FLOAT_FIELDS):
        rows[2 * i][f][i % 3] = np.nan
        rows[2 * i + 1][f][2] = -np.inf
        bad[2 * i] = bad[2 * i + 1] = True
    rows[-1]["state"] = 255
    rows[-1]["active"] = True
    assert np.array_equal(finite_rows(rows), ~bad)
    assert np.array_equal(finite_rows(rows[::2]), ~bad[::2])
    with pytest.raises(TypeError, match="finite_rows takes"):
        finite_rows(np.zeros((2, 3)))
