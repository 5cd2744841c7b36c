"""The hand-written C peers of benchmarks/ctrackers (the yardstick of benchmarks/c_peers.py)
track like the specification, springtrack/reference.py, on the same events: every tracker's
position within 1e-9 px and its covariance within 1e-9 of its size at every sample, the
counters equal.  Each peer is built here (a C compiler is needed, as for the kernels); the
SIMD peer in both of its builds (AVX-512 where the processor has it, and AVX2).  The peers
implement the paper's step (one mean for both polarities): polarity_gain = 0 here."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from support import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
from _ctrackers import PACKED, CTracker  # noqa: E402
from _report import cpu_info  # noqa: E402

import springtrack  # noqa: E402
from springtrack.reference import ReferenceTracker  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402
from springtrack.sim.synthetic import blob_stream  # noqa: E402

FLAGS = cpu_info()[2]
KINDS = ["plain",
         pytest.param("simd", marks=pytest.mark.skipif("avx2" not in FLAGS, reason="no AVX2")),
         pytest.param("simd-avx2", marks=pytest.mark.skipif("avx2" not in FLAGS,
                                                              reason="no AVX2"))]
EVENTS = 12_000
EVERY = 500          # events between samples
TOL_PX = 1e-9
TOL_COV = 1e-9
PAPER_STEP = {"polarity_gain": 0.0}     # the peers' eq. (3): no half offsets (eq. M6b)


def packed(ev) -> np.ndarray:
    out = np.empty(len(ev), PACKED)
    for f in ("t", "x", "y", "p"):
        out[f] = ev[f]
    return out


def streams():
    """face26 on the simulator's occlusion scene (most events assigned, trackers pulled and
    made insensitive by the energy criteria) and on a drifting, turning blob stream with
    62 % noise (the index re-indexes as the face moves); grid3x3 on its blob stream."""
    ev, _ = simulate_all("face_occlusion", 5.0, seed=0)
    yield "face26", packed(ev[:EVENTS])
    for preset, motion in (("face26", dict(speed_px_s=(300, -200), rot_deg_s=-150)),
                           ("grid3x3", dict(speed_px_s=(250, 150), rot_deg_s=120))):
        ev, _ = blob_stream(springtrack.load_model(preset), EVENTS, rate_hz=300_000,
                            noise=0.62, seed=1, **motion)
        yield preset, packed(ev)


STREAMS = list(streams())


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("stream", range(len(STREAMS)), ids=[s[0] for s in STREAMS])
def test_peer_tracks_like_the_reference(kind, stream):
    preset, events = STREAMS[stream]
    tracker = springtrack.Tracker(preset, PAPER_STEP)  # the default frame, the paper's step
    ref = ReferenceTracker(tracker.model, tracker.params)
    peer = CTracker(kind, tracker.model, tracker.params)
    worst_px = worst_cov = 0.0
    for start in range(0, len(events), EVERY):
        chunk = events[start:start + EVERY]
        for t, x, y in zip(chunk["t"].tolist(), chunk["x"].tolist(), chunk["y"].tolist()):
            ref.step(t, x, y)
        peer.process(chunk)
        st = peer.state(int(chunk["t"][-1]))
        worst_px = max(worst_px, np.abs(st[:, 0] - ref.mx).max(), np.abs(st[:, 1] - ref.my).max())
        size = np.sqrt(np.array(ref.sxx) * np.array(ref.syy))
        for j, ours in ((2, ref.sxx), (3, ref.sxy), (4, ref.syy)):
            worst_cov = max(worst_cov, (np.abs(st[:, j] - ours) / size).max())
    assert worst_px <= TOL_PX, worst_px
    assert worst_cov <= TOL_COV, worst_cov
    c = peer.counters
    assert c["events_valid"] == ref.n_valid
    assert c["events_assigned"] == ref.n_assigned
    assert c["spring_updates"] == ref.n_spring_updates
    assert ref.n_spring_updates > 100 and ref.n_assigned > EVENTS // 5   # the stream tracks
    assert ref.n_resets == 0


def test_the_index_follows_a_moving_shape():
    """The index re-indexes trackers as they move (a peer that never re-indexed would lose
    the events of a drifting face, and the test above would fail on positions)."""
    preset, events = STREAMS[1]
    tracker = springtrack.Tracker(preset, PAPER_STEP)
    peer = CTracker("plain", tracker.model, tracker.params)
    peer.process(events)
    n = len(tracker.model.arrays()["x"])                 # each tracker indexed once at start
    assert peer.counters["reindexed"] > n + 10
