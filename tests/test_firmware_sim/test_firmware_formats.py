"""The fused loop on every camera word format (CCam, EVT 2.0, EVT 2.1, EVT 3.0) at the
sensor's own geometry, against the file decoders and the offline tracker; real recordings
replayed through the firmware end to end."""
from __future__ import annotations

import builtins
import re
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import springtrack.io as sio
from springtrack.kernel.kernel import Kernel
from springtrack.events import make
from springtrack.model import face26
from springtrack.tracker import Tracker
from firmware_sim._fused import WORD_FORMATS, Fused, native_geometry
from support.fused import assert_same, collect

SAMPLE = 1000
EVT = [("evt2", False), ("evt21", False), ("evt21", True), ("evt3", False)]


def encoded(fmt, legacy, ev):
    """Words of ``ev`` in ``fmt`` (no header), as a camera sends them."""
    enc = __import__(f"springtrack.io.{fmt}", fromlist=["encode"]).encode
    return enc(ev, legacy) if fmt == "evt21" else enc(ev)


def fused(model, fmt, legacy=False, period=SAMPLE, cap=64, roi=None):
    tr = Tracker(model)
    return Fused(Kernel(tr.model, tr.params), period, cap, fmt=fmt, width=tr.model.width,
                 height=tr.model.height, legacy=legacy, roi=roi)


@pytest.fixture(scope="module")
def wide():
    """A face moving over a 1280 x 720 sensor (the simulator's face scene, scaled up)."""
    from springtrack.sim.sensor import simulate_all
    ev, _ = simulate_all("face_occlusion", 0.3, seed=5)
    ev = ev.copy()
    ev["x"] = ev["x"].astype(np.int64) * 4 + 10
    ev["y"] = ev["y"].astype(np.int64) * 3 + 2
    model = face26(cx=4 * 152 + 10, cy=3 * 120 + 2, scale=360, width=1280, height=720)
    return ev, model


@pytest.mark.parametrize("fmt,legacy", EVT)
def test_fused_evt_words_at_native_geometry_equal_the_offline_tracker(wide, fmt, legacy):
    ev, model = wide
    ref = Tracker(model).run(ev, SAMPLE)
    f = fused(model, fmt, legacy)
    assert_same(ref, collect(f, [encoded(fmt, legacy, ev)]))
    c = f.counters()
    assert c["format"] == fmt and c["events_decoded"] == c["events_tracked"] == len(ev)
    assert not any(c["anomalies"].values())


@pytest.mark.parametrize("fmt,legacy", EVT)
def test_dense_vector_words_fill_the_batch_to_its_end_and_lose_nothing(wide, fmt, legacy):
    """Words of 1 to 32 events (EVT 2.1 masks, EVT 3.0 vectors) meet the end of the fused
    loop's batch at every offset: every event is tracked once, in order."""
    _, model = wide
    rng = np.random.default_rng(7)
    parts = []
    for i in range(3000):                # a group of 32 columns, a random mask, one time
        x0 = 32 * int(rng.integers(12, 26))
        xs = np.flatnonzero(rng.random(32) < rng.random()) + x0
        if len(xs):
            parts.append(make(np.full(len(xs), 1000 + 7 * i), xs,
                              np.full(len(xs), int(rng.integers(250, 470))),
                              np.full(len(xs), i % 2)))
    ev = np.concatenate(parts)
    f = fused(model, fmt, legacy)
    assert_same(Tracker(model).run(ev, SAMPLE), collect(f, [encoded(fmt, legacy, ev)]))
    c = f.counters()
    assert c["events_decoded"] == c["events_tracked"] == len(ev)


@settings(max_examples=10, deadline=None)
@given(st.sampled_from(EVT), st.lists(st.integers(1, 40_000), min_size=1, max_size=30),
       st.integers(1, 5))
def test_any_split_of_an_evt_stream_gives_the_same_track(wide, fmt_legacy, cuts, cap):
    fmt, legacy = fmt_legacy
    ev, model = wide
    ev = ev[:60_000]
    words = encoded(fmt, legacy, ev)
    pos, pieces = 0, []
    for c in cuts:
        pieces.append(words[pos:pos + c])
        pos += c
    pieces.append(words[pos:])
    whole = collect(fused(model, fmt, legacy, cap=4096), [words])
    got = collect(fused(model, fmt, legacy, cap=cap), [p for p in pieces if p])
    assert all(np.array_equal(whole[k], got[k]) for k in whole)


@pytest.mark.parametrize("fmt,legacy", EVT)
def test_the_fused_loop_stamps_evt_words_as_the_file_decoder_does(fmt, legacy):
    """Time-high wraps and a step back, decoded by the fused loop word by word and by the
    file decoder: the same timestamps (one time base for both)."""
    rng = np.random.default_rng(2)
    bits = {"evt2": 34, "evt21": 34, "evt3": 24}[fmt]
    t = np.sort(np.concatenate([rng.integers(0, 40_000, 300),
                                (1 << bits) - 30_000 + rng.integers(0, 60_000, 300)]))
    ev = make(t, rng.integers(100, 200, 600), rng.integers(50, 150, 600), 1)
    words = encoded(fmt, legacy, ev)
    dec = sio.decoder(fmt, **({"legacy": legacy} if fmt == "evt21" else {}))
    want = dec.decode(words)
    assert np.array_equal(want, ev) and dec.stats.info["time_wraps"] == 1
    f = fused("face26", fmt, legacy, period=0)
    ws = WORD_FORMATS[fmt][1]
    stamped = []
    for i in range(0, len(words), ws):
        before = f.counters()["events_tracked"]
        f.feed(words[i:i + ws])
        if f.counters()["events_tracked"] > before:
            stamped.append(f.last_t)
    assert stamped[-1] == ev["t"][-1] and stamped == sorted(stamped)
    c = f.counters()
    assert c["time_wraps"] == 1 and c["events_tracked"] == len(ev)
    assert c["anomalies"]["tracker_back_in_time"] == 0


@pytest.mark.parametrize("fmt,legacy", EVT)
def test_after_a_gap_evt_events_wait_for_the_next_time_high_word(fmt, legacy):
    ev = make([100, 200, 300, 5000, 5100], [10, 11, 12, 13, 14], [10, 10, 10, 11, 11], 1)
    f = fused("face26", fmt, legacy, period=0)
    f.feed(encoded(fmt, legacy, ev))
    assert f.counters()["events_tracked"] == 5
    f.gap()                                      # a transfer was dropped
    # the stream goes on: two events of one time-high period, its time-high word lost
    tail = encoded(fmt, legacy, make([5200, 5210], [20, 21], [12, 12], 1))
    f.feed(tail[WORD_FORMATS[fmt][1]:])         # the words after the time-high word
    c = f.counters()
    assert c["events_tracked"] == 5 and c["gaps"] == 1
    assert c["anomalies"]["skipped_after_gap"] == 2
    f.feed(tail)                                 # from a time-high word on: tracked again
    assert f.counters()["events_tracked"] == 7 and f.last_t == 5210


def test_stream_start_without_a_time_base_is_skipped_and_counted():
    words = encoded("evt2", False, make([100, 110], [5, 6], [5, 5], 1))
    f = fused("face26", "evt2", period=0)
    f.feed(words[4:] + words)                   # an event word before any time-high
    c = f.counters()
    assert c["anomalies"]["skipped_after_gap"] == 2 and c["events_tracked"] == 2


@pytest.mark.parametrize("fmt,legacy", [("ccam", False)] + EVT)
def test_a_region_of_interest_tracks_only_its_events_and_counts_the_rest(fmt, legacy):
    from springtrack.sim.sensor import simulate_all
    ev, _ = simulate_all("face_occlusion", 0.2, seed=1)
    roi = (60, 40, 180, 150)
    inside = ((ev["x"] >= 60) & (ev["x"] < 240) & (ev["y"] >= 40) & (ev["y"] < 190))
    words = encoded(fmt, legacy, ev)
    f = fused("face26", fmt, legacy, roi=roi)
    got = collect(f, [words])
    assert_same(Tracker("face26").run(ev[inside], SAMPLE), got)
    c = f.counters()
    assert c["outside_roi"] == int((~inside).sum()) and c["events_tracked"] == int(inside.sum())
    assert f.roi == roi


def test_geometry_is_checked_per_format():
    assert native_geometry("ccam") == (304, 240)
    assert native_geometry("evt3", 1280, 720) == (1280, 720)
    assert native_geometry("evt2", 2048, 2048) == (2048, 2048)
    with pytest.raises(ValueError, match="CCam ATIS words are 304x240"):
        native_geometry("ccam", 640, 480)
    with pytest.raises(ValueError, match="up to 2048x2048"):
        native_geometry("evt3", 4096, 720)
    with pytest.raises(ValueError, match="up to 2048x2048"):
        native_geometry("evt2")
    with pytest.raises(ValueError, match="decodes ccam, evt2, evt21, evt3 words, not 'es'"):
        native_geometry("es", 320, 240)
    with pytest.raises(ValueError, match="inside the 304x240 sensor"):
        fused("face26", "ccam", roi=(300, 0, 10, 10))
    with pytest.raises(ValueError, match="legacy word order applies to EVT 2.1"):
        fused("face26", "evt3", legacy=True)


@pytest.mark.parametrize("name,fmt,geometry", [("evt2_sample.raw", "evt2", (640, 480)),
                                               ("evt3_sample.raw", "evt3", (1280, 720))])
def test_fused_loop_on_a_real_recording_equals_the_file_decoder_and_tracker(
        data_file, name, fmt, geometry):
    """The recorded bytes through the fused loop at the sensor's geometry: every event
    tracked, the same track as the offline tracker on the file decoder's events."""
    path = data_file(name)
    r = sio.open(path)
    ev = r.read()
    with builtins.open(path, "rb") as fh:
        payload = fh.read()[r.offset:]
    w, h = geometry
    model = face26(cx=w / 2, cy=h / 2, scale=h / 2, width=w, height=h)
    f = fused(model, fmt, cap=256)
    got = collect(f, [payload[i:i + 16384] for i in range(0, len(payload), 16384)])
    assert_same(Tracker(model).run(ev, SAMPLE), got)
    c = f.counters()
    assert c["events_decoded"] == c["events_tracked"] == len(ev)
    assert c["anomalies"]["out_of_geometry"] == 0


@pytest.mark.parametrize("name,events,geometry", [("evt2_sample.raw", 539_481, "640x480"),
                                                  ("evt3_sample.raw", 219_596, "1280x720")])
def test_firmware_replays_a_real_recording_and_tracks_every_event(data_file, name, events,
                                                                   geometry):
    """The issue's done-when: ``firmware-sim run --source replay:FILE --max-speed`` tracks
    every event of the real recordings at their native geometry, no geometry drop."""
    path = data_file(name)
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        f"replay:{path}", "--max-speed", "--stats-every", "0"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    line = r.stdout.strip().splitlines()[-1]
    assert line.startswith("stats: ")
    assert f" decoded={events} tracked={events} geometry_drops=0 " in line
    assert f"sensor={geometry}" in line
    an = re.search(r"anomalies=(\S+|\{.*?\})", line).group(1)
    assert "out_of_geometry" not in an and "outside_sensor" not in an, line


@pytest.mark.parametrize("name,events", [("evt2_sample.raw", 539_481),
                                         ("evt3_sample.raw", 219_596)])
def test_a_replay_takes_the_corrupt_fault_in_its_own_words(data_file, name, events):
    """``--faults corrupt`` on a replayed recording spoils its own words (EVT 2.0, 3.0):
    every event of the file is decoded, or counted as lost to an undefined word type or
    a coordinate outside the sensor."""
    path = data_file(name)
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        f"replay:{path}", "--max-speed", "--faults", "corrupt",
                        "--stats-every", "0"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    line = r.stdout.strip().splitlines()[-1]
    decoded = int(re.search(r" decoded=(\d+) ", line).group(1))
    unknown = int(re.search(r"'unknown_type': (\d+)", line).group(1))
    outside = int(re.search(r"'out_of_geometry': (\d+)", line).group(1))
    assert unknown > 50 and outside > 50
    assert decoded + unknown + outside == events


def test_sparse_events_far_apart_give_a_bounded_telemetry():
    """Events seconds apart (every gap far past the sampling rule's HOLD periods): the
    fused loop takes the offline tracker's samples, at most sampling.PER_EVENT per event,
    and counts the sample times it skipped as the tracker does."""
    from springtrack import sampling
    rng = np.random.default_rng(11)
    t = np.cumsum(rng.integers(10 * SAMPLE, 3_000_000, 300))
    tr = Tracker("grid3x3")
    ev = make(t, rng.integers(100, 200, len(t)), rng.integers(80, 160, len(t)), np.ones(len(t)))
    ref = tr.run(ev, SAMPLE)
    f = fused("grid3x3", "evt2")
    assert_same(ref, collect(f, [encoded("evt2", False, ev)]))
    assert len(ref.t_us) <= sampling.PER_EVENT * len(ev)
    assert f.counters()["samples_skipped"] == tr.counters["samples_skipped"] > 1000 * len(ev)
