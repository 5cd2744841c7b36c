"""Property tests (hypothesis): exact round trips, and arbitrary bytes never crash and
decode the same however they are split."""
from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings, strategies as st

import springtrack.io as sio
from springtrack.io import ccam, dat, es, evt2, evt3
from springtrack.events import EVENT_DTYPE, make
import pytest

SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


@st.composite
def event_arrays(draw, width=304, height=240, max_gap=1 << 20, max_n=60):
    n = draw(st.integers(0, max_n))
    gaps = draw(st.lists(st.one_of(st.integers(0, 3), st.integers(0, max_gap)),
                         min_size=n, max_size=n))
    t0 = draw(st.integers(0, 1 << 30))
    t = t0 + np.cumsum(np.array(gaps, dtype=np.int64)) if n else np.empty(0, np.int64)
    x = draw(st.lists(st.integers(0, width - 1), min_size=n, max_size=n))
    y = draw(st.lists(st.integers(0, height - 1), min_size=n, max_size=n))
    p = draw(st.lists(st.integers(0, 1), min_size=n, max_size=n))
    return make(t, x, y, p)


def split_decode(dec, data, cuts):
    cuts = sorted(set(c for c in cuts if 0 < c < len(data)))
    parts, prev = [], 0
    for c in cuts + [len(data)]:
        parts.append(dec.decode(data[prev:c]))
        prev = c
    return np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)


CUTS = st.lists(st.integers(0, 4000), max_size=12)


@SETTINGS
@given(event_arrays(width=2048, height=2048, max_gap=1 << 36), CUTS)
def test_evt2_round_trip(ev, cuts):
    out = split_decode(sio.decoder("evt2"), evt2.encode(ev), cuts)
    np.testing.assert_array_equal(out, ev)


@pytest.mark.slow
@SETTINGS
@given(event_arrays(width=2048, height=2048, max_gap=1 << 26), CUTS)
def test_evt3_round_trip(ev, cuts):
    dec = sio.decoder("evt3")
    out = split_decode(dec, evt3.encode(ev), cuts)
    np.testing.assert_array_equal(out, ev)
    assert dec.stats.total_anomalies == 0


@SETTINGS
@given(event_arrays(max_gap=1 << 24), st.data(), CUTS)
def test_ccam_round_trip(ev, data, cuts):
    flags = np.array(data.draw(st.lists(st.booleans(), min_size=len(ev), max_size=len(ev))),
                     dtype=bool)
    dec = sio.decoder("ccam", keep_exposure=True)
    out = split_decode(dec, ccam.encode(ev, flags), cuts)
    np.testing.assert_array_equal(out, ev[~flags])
    np.testing.assert_array_equal(dec.take_exposure(), ev[flags])
    assert dec.stats.total_anomalies == 0


@SETTINGS
@given(event_arrays(width=65535, height=65535, max_gap=3000), st.data(), CUTS)
def test_es_round_trip(ev, data, cuts):
    ev["t"] -= ev["t"][0] if len(ev) else 0       # Event Stream time starts at 0
    out = split_decode(sio.decoder("es", event_type="dvs"), es.encode(ev, "dvs"), cuts)
    np.testing.assert_array_equal(out, ev)
    flags = np.array(data.draw(st.lists(st.booleans(), min_size=len(ev), max_size=len(ev))),
                     dtype=bool)
    dec = sio.decoder("es", event_type="atis", keep_exposure=True)
    out = split_decode(dec, es.encode(ev, "atis", flags), cuts)
    np.testing.assert_array_equal(out, ev[~flags])
    np.testing.assert_array_equal(dec.take_exposure(), ev[flags])


@SETTINGS
@given(event_arrays(width=16384, height=16384, max_gap=1 << 20), CUTS)
def test_dat_round_trip(ev, cuts):
    ev = ev[ev["t"] < (1 << 32)]
    out = split_decode(sio.decoder("dat"), dat.encode(ev), cuts)
    np.testing.assert_array_equal(out, ev)


DECODERS = [("evt2", {}), ("evt3", {}), ("ccam", {"keep_exposure": True}),
            ("es", {"event_type": "dvs"}), ("es", {"event_type": "atis", "width": 304,
                                                    "height": 240}),
            ("dat", {"width": 640, "height": 480}), ("evt3", {"width": 64, "height": 64}),
            ("evt21", {"width": 320, "height": 320}), ("evt21", {"legacy": True})]


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(DECODERS), st.binary(max_size=3000), CUTS)
def test_any_bytes_decode_consistently(which, data, cuts):
    fmt, opts = which
    whole = sio.decoder(fmt, **opts)
    ref = whole.decode(data)
    pend = whole.finish()
    dec = sio.decoder(fmt, **opts)
    got = split_decode(dec, data, cuts)
    assert dec.finish() == pend
    np.testing.assert_array_equal(got, ref)
    assert dec.stats == whole.stats
    s = whole.stats
    ws = whole.word_size
    assert s.words == len(data) // ws and s.pending_bytes == 0
    assert s.events == len(ref)
    if fmt in ("evt2", "dat", "ccam"):
        assert len(ref) <= s.words
    if whole.width:
        assert np.all(ref["x"] < whole.width) and np.all(ref["y"] < whole.height)
    if fmt in ("evt2", "evt21", "evt3", "ccam"):     # time-high formats
        assert s.anomalies["truncated"] == (len(data) % ws != 0)
