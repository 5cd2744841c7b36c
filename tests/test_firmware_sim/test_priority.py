"""``--rt-priority``: every thread of the process under SCHED_FIFO while the loop runs
(they share the GIL), the ordinary scheduler back after it stops, the output unchanged; a
refused permission is an error at once."""
from __future__ import annotations

import ctypes
import gc
import os
import resource
import subprocess
import sys
import threading

import numpy as np
import pytest

from springtrack.sim.sensor import simulate_all
from springtrack.track import TRACK_FIELDS, Track
from springtrack.tracker import Tracker
from firmware_sim import camera as camusb
from firmware_sim import priority
from firmware_sim.loop import FirmwareLoop
from firmware_sim.simcam import SimBackend, SimCamera
from firmware_sim.sources import events_source
from support.wait import wait_drained

PR_CAPBSET_DROP, CAP_SYS_NICE = 24, 23


def permitted(level: int) -> bool:
    try:
        priority.check(level)
        return True
    except OSError:
        return False


def without_rt_permission():
    """preexec_fn: no rtprio limit, and for root no CAP_SYS_NICE after the exec."""
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
    if os.geteuid() == 0 and ctypes.CDLL(None, use_errno=True).prctl(
            PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0) != 0:
        os._exit(99)


@pytest.mark.skipif(not permitted(7), reason="SCHED_FIFO not permitted to this user "
                                             "(CI runs as root)")
def test_every_thread_runs_under_sched_fifo_while_the_loop_runs_and_tracks_as_before():
    ev, _ = simulate_all("face_occlusion", 0.4, seed=3)
    cam = SimCamera(events_source(ev, 512), realtime=True)
    be = SimBackend(cam)
    eng = FirmwareLoop(lambda: camusb.Camera.open("ccam_atis", backend=be), "face26",
                       record=True, rt_priority=7, nbuf=256)
    assert os.sched_getscheduler(0) == os.SCHED_OTHER       # nothing before start
    eng.start()
    try:
        threads = {t.name: t.native_id for t in threading.enumerate()}
        assert {"usb-reader", "fused-loop", "MainThread"} <= set(threads)
        for name, tid in threads.items():
            assert os.sched_getscheduler(tid) == os.SCHED_FIFO, name
            assert os.sched_getparam(tid).sched_priority == 7, name
        go = threading.Event()
        later = threading.Thread(target=go.wait)                 # started now: inherits it
        later.start()
        try:
            assert os.sched_getscheduler(later.native_id) == os.SCHED_FIFO
        finally:
            go.set()
            later.join()
        assert gc.get_freeze_count() > 0
        wait_drained(cam, eng, 60)
    finally:
        eng.stop()
    assert os.sched_getscheduler(0) == os.SCHED_OTHER and gc.get_freeze_count() == 0
    s = eng.stats()
    assert s["transfers_dropped"] == 0 and s["events_tracked"] == len(ev)
    got = Track.concat([Track.from_samples(b.samples, b.ids) for b in eng.recorder.blocks],
                       eng.recorder.blocks[0].ids)
    ref = Tracker("face26").run(ev, 1000)
    assert np.array_equal(got.t_us, ref.t_us)
    for k in TRACK_FIELDS:
        assert np.array_equal(getattr(got, k), getattr(ref, k)), k
    # the latency's end instant: no snapshot reached the telemetry queue before its sample
    # time occurred on the camera's clock
    assert all(b.wall >= cam.wall_of(int(t)) for b in eng.recorder.blocks
               for t in b.samples["t"])


def test_a_refused_rt_priority_stops_the_cli_at_once_naming_the_ways_out():
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        "sim:face_occlusion", "--seconds", "0.1", "--rt-priority", "5",
                        "--stats-every", "0"], capture_output=True, text=True, timeout=60,
                       preexec_fn=without_rt_permission)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "SCHED_FIFO priority 5 refused" in r.stderr
    for way in ("root", "CAP_SYS_NICE", "ulimit -r", "without --rt-priority"):
        assert way in r.stderr, way
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("level", [0, 100])
def test_a_priority_outside_the_policys_range_is_refused(level):
    with pytest.raises(ValueError, match="outside SCHED_FIFO's 1..99"):
        priority.check(level)
