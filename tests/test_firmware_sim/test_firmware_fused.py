"""The fused decode+track loop (firmware_sim._fused) against the offline tracker."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from springtrack import sampling
from springtrack.kernel.kernel import Kernel
from springtrack.events import make
from springtrack.io.ccam import encode
from springtrack.tracker import Tracker
from firmware_sim._fused import Fused
from springtrack.sim.sensor import simulate_all
from support.fused import assert_same, collect

SAMPLE = 1000


@pytest.fixture(scope="module")
def face():
    ev, _ = simulate_all("face_occlusion", 0.4, seed=3)
    words = encode(ev)
    ref = Tracker("face26").run(ev, SAMPLE)
    return ev, words, ref


def fused(model="face26", period=SAMPLE, cap=64):
    tr = Tracker(model)
    return Fused(Kernel(tr.model, tr.params), period, cap)


def test_fused_equals_the_tracker_bit_for_bit(face):
    ev, words, ref = face
    f = fused()
    got = collect(f, [words])
    assert_same(ref, got)
    c = f.counters()
    assert c["events_decoded"] == c["events_tracked"] == len(ev)
    assert not any(c["anomalies"].values())


@settings(max_examples=15, deadline=None)
@given(st.lists(st.integers(1, 70_000), min_size=1, max_size=40), st.integers(1, 7))
def test_any_split_of_the_byte_stream_gives_the_same_track(face, cuts, cap):
    """Transfers of any length (odd ones split words) and a tiny snapshot buffer (events
    whose snapshots do not fit are finished by the next call) change nothing."""
    ev, words, ref = face
    pos, pieces = 0, []
    for c in cuts:
        pieces.append(words[pos:pos + c])
        pos += c
    pieces.append(words[pos:])
    f = fused(cap=cap)
    assert_same(ref, collect(f, [p for p in pieces if p]))


def word_th(th):
    return bytes([th & 0xFF, (th >> 8) & 0xFF, (th >> 16) & 0xFF, 0x80])


def word_ev(lo, x, y, p=1):
    return bytes([239 - y, x & 0xFF, ((lo & 0x7F) << 1) | (x >> 8), (lo >> 7) | (p << 4)])


def test_time_stays_monotonic_across_a_time_high_wrap():
    f = fused(period=0)
    f.feed(word_th(0xFFFFFF) + word_ev(2000, 150, 120) + word_th(0) + word_ev(3, 150, 120))
    c = f.counters()
    assert c["time_wraps"] == 1 and c["events_tracked"] == 2
    assert c["anomalies"]["tracker_back_in_time"] == 0
    assert f.last_t == ((1 << 24) << 11) + 3


def test_after_a_gap_events_wait_for_the_next_time_high_word():
    f = fused(period=0)
    f.feed(word_th(5) + word_ev(10, 100, 100))
    f.gap()                                   # a transfer was dropped
    f.feed(word_ev(20, 100, 100) + word_ev(30, 100, 100) + word_th(9) + word_ev(1, 100, 100))
    c = f.counters()
    assert c["anomalies"]["skipped_after_gap"] == 2
    assert c["events_tracked"] == 2 and c["gaps"] == 1
    assert f.last_t == 9 * 2048 + 1


def test_stream_start_without_time_base_is_skipped_and_counted():
    f = fused(period=0)
    f.feed(word_ev(7, 10, 10) + word_th(1) + word_ev(7, 10, 10))
    c = f.counters()
    assert c["anomalies"]["skipped_after_gap"] == 1 and c["events_tracked"] == 1


def test_corrupt_words_are_counted_by_kind_and_not_tracked():
    bad_type = bytes([0, 0, 0, 0xC0])
    bad_row = bytes([0xFF, 10, 0, 0])
    bad_col = bytes([0, 0x40, 1, 0])                 # x = 0x140 = 320 >= 304
    f = fused(period=0)
    f.feed(word_th(1) + bad_type + word_ev(1, 5, 5) + bad_row + bad_col + word_ev(2, 5, 5))
    c = f.counters()
    assert c["anomalies"]["unknown_type"] == 1
    assert c["anomalies"]["out_of_geometry"] == 2
    assert c["events_tracked"] == 2


def test_snapshot_sampling_rule_matches_the_kernel_on_a_hand_case():
    # events at 100, 2500 us: samples at 1000 and 2000 hold the state after the event at 100
    ev = make([100, 2500, 3100], [150, 150, 150], [120, 120, 120], [1, 1, 1])
    ref = Tracker("face26").run(ev, SAMPLE)
    got = fused().feed(encode(ev))
    assert list(got["t"]) == [1000, 2000, 3000] == list(ref.t_us)
    assert np.array_equal(got["trackers"]["x"], ref.x)


def test_model_swap_marks_the_first_event_of_the_new_kernel(face):
    ev, words, _ = face
    f = fused(period=0)
    half = len(words) // 2 // 4 * 4
    f.feed(words[:half])
    t_before = f.last_t
    tr = Tracker("grid3x3")
    f.set_kernel(Kernel(tr.model, tr.params))
    assert f.first_t == -1
    f.feed(words[half:])
    assert f.first_t >= t_before
    assert f.kernel_obj.counters()["events_valid"] + f.kernel_obj.counters()["skipped_outside_sensor"] > 0


def test_a_camera_counter_restart_is_rebased_so_time_never_goes_back():
    """A reconnected camera may restart its time counter: the time base is rebased (counted
    as time_backwards) and tracking continues with monotonic timestamps."""
    f = fused(period=0)
    f.feed(word_th(100) + word_ev(50, 150, 120))
    f.gap()                                     # reconnect
    f.feed(word_th(3) + word_ev(10, 150, 120) + word_ev(20, 151, 120))
    c = f.counters()
    assert c["anomalies"]["time_backwards"] == 1
    assert c["events_tracked"] == 3 and c["anomalies"]["tracker_back_in_time"] == 0
    assert f.last_t == 101 * 2048 + 20


def test_the_fused_loop_stamps_events_as_the_file_decoder_does():
    """The same bytes, with a wrap of the time-high counter and a backward jump, through the
    file decoder and through the fused loop: the same timestamps event by event, and the
    same track as the offline tracker on the decoded events (one time base for both)."""
    import springtrack.io as sio
    rng = np.random.default_rng(11)
    data = b""
    for th in (0xFFFFFE, 0xFFFFFF, 0, 1, 0, 1, 3, 2, 5):     # a wrap, two steps back
        data += word_th(th)
        for lo in np.sort(rng.integers(0, 2048, 40)):
            data += word_ev(int(lo), int(rng.integers(120, 180)), int(rng.integers(90, 150)))
    dec = sio.decoder("ccam")
    ev = dec.decode(data)
    assert dec.stats.info["time_wraps"] == 1 and dec.stats.anomalies["time_backwards"] == 2

    f = fused(period=0)
    stamped = []
    for i in range(0, len(data), 4):
        f.feed(data[i:i + 4])
        if data[i + 3] != 0x80:                           # an event word
            stamped.append(f.last_t)
    assert stamped == list(ev["t"])
    c = f.counters()
    assert (c["time_wraps"], c["anomalies"]["time_backwards"]) == (1, 2)
    assert c["anomalies"]["tracker_back_in_time"] == 0

    ref = Tracker("face26").run(ev, SAMPLE)
    assert_same(ref, collect(fused(), [data]))


def test_block_decoding_equals_word_by_word_in_the_fused_loop():
    """The fused loop decodes runs of plain event words 32 at a time (io/ccam_block.h);
    fed one word per call it never does, and tracks, samples and counts the same."""
    from support.words import ccam_mixed_words
    data = ccam_mixed_words(7, n_events=6000, n_special=80)
    whole, single = fused(cap=4096), fused(cap=4096)
    a = collect(whole, [data])
    b = collect(single, [data[i:i + 4] for i in range(0, len(data), 4)])
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    assert whole.counters() == single.counters()
    assert whole.counters()["events_tracked"] > 5000 and len(a["t"]) > 10


def test_one_feed_of_many_snapshots_reaches_the_sink_in_parts_of_at_most_the_capacity():
    """Events sampling.PER_EVENT periods apart (4,001 at 5 ms: no sample time skipped) make one
    feed take 20,000 snapshots: with a sink they leave part by part (memory bounded by the
    capacity, not by the time span), the same rows."""
    gap = sampling.PER_EVENT * 1000
    n = 20_000_000 // gap + 1
    ev = make(t=100 + gap * np.arange(n), x=150 + np.arange(n) % 2, y=np.full(n, 120),
              p=np.ones(n))
    words = encode(ev)
    ref = collect(fused(cap=64), [words])
    f = fused(cap=64)
    parts = []
    assert f.feed(words, sink=parts.append) is None
    assert len(parts) > 300 and max(len(p["t"]) for p in parts) <= 64
    got = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    assert len(got["t"]) == 20_000 and np.array_equal(got["t"], ref["t"])
