"""The reader thread alone: buffer pool, coalescing of small transfers, load shedding."""
from __future__ import annotations

import time

import numpy as np

from springtrack.kernel.kernel import Kernel
from springtrack.tracker import Tracker
from firmware_sim import camera as camusb
from firmware_sim._fused import Fused
from firmware_sim.reader import Reader
from springtrack.sim.sensor import simulate_all
from firmware_sim.simcam import SimBackend, SimCamera
from firmware_sim.sources import events_source


def drain(reader, f):
    while True:
        item = reader.get(0.05)
        if item is None:
            return
        idx, n, gap = item
        if gap:
            f.gap()
        f.feed(reader.pool[idx], n)
        reader.release(idx)


def test_a_stalled_consumer_costs_bytes_not_buffers():
    """Real time, the consumer sleeps 0.4 s: hundreds of short transfers arrive meanwhile,
    are coalesced into a few buffers, and nothing is dropped."""
    ev, _ = simulate_all("face_occlusion", 0.6, seed=2)
    cam = SimCamera(events_source(ev, 512), realtime=True)
    be = SimBackend(cam)
    r = Reader(lambda: camusb.Camera.open("ccam_atis", backend=be), nbuf=8)
    tr = Tracker("face26")
    f = Fused(Kernel(tr.model, tr.params), 0)
    r.start()
    try:
        time.sleep(0.4)
        assert r.counts["transfers"] > 20 and r.queue_depth() <= 8
        while not cam.finished:
            drain(r, f)
        time.sleep(0.05)
        drain(r, f)
    finally:
        r.stop()
    c = r.counts
    assert c["transfers_dropped"] == 0 and c["coalesced"] > 10
    assert f.tracked == len(ev) and f.bytes_in == c["bytes"]


def test_a_full_pool_drops_the_oldest_whole_transfers_and_marks_the_gap():
    ev, _ = simulate_all("face_occlusion", 0.5, seed=2)
    cam = SimCamera(events_source(ev, 4096), realtime=False)
    be = SimBackend(cam)
    r = Reader(lambda: camusb.Camera.open("ccam_atis", backend=be), nbuf=3,
               transfer_bytes=4096)
    r.start()
    try:
        while not cam.finished:                  # nobody consumes: the pool turns over
            time.sleep(0.01)
    finally:
        r.stop()
    c = r.counts
    assert c["transfers_dropped"] > 0 and c["queue_hwm"] <= 3 and len(r.pool) == 3
    assert c["bytes_dropped"] + sum(n for _, n, _, _ in r.filled) == c["bytes"]
    assert r.filled[0][2]                        # the consumer will be told of the gap
    tr = Tracker("face26")
    f = Fused(Kernel(tr.model, tr.params), 0)
    drain(r, f)
    assert 0 < f.tracked < len(ev) and f.counters()["gaps"] == 1
    assert f.counters()["anomalies"]["tracker_back_in_time"] == 0
