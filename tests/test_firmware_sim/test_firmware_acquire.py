"""Acquisition in the firmware, hardware-in-the-loop: ``firmware-sim run --acquire`` as a
separate process on the simulated camera with a model written 20 deg / 15 % / 30 px off
its object; the host sees the model's instance state in telemetry (tracking on the face
once found: no rows while the only instance is searching, as in ``springtrack track``),
triggers a new search with ACQUIRE (``hostctl acquire``), and a firmware without
--acquire refuses it."""
import subprocess
import sys

import numpy as np
import pytest

from hostctl import Device, HostctlError
from springtrack.acquisition.acquire import Pose, model_pose, place
from springtrack.instances import TRACKING
from springtrack.sim.scenes import make_scene
from springtrack.wire import Nack
from support.fwproc import SCENE_S, Firmware, collect_until

BIN_HOSTCTL = [sys.executable, "-m", "hostctl.cli"]


def on_face(snap, tol_px=6.0) -> bool:
    truth = make_scene("face_occlusion").truth(snap.t_us / 1e6)
    d = np.hypot(snap.trackers["x"] - truth[:, 0], snap.trackers["y"] - truth[:, 1])
    return bool(np.mean(d) < tol_px)


@pytest.fixture
def acquiring_fw(tmp_path):
    m = make_scene("face_occlusion").initial_model()
    p = model_pose(m)
    off = tmp_path / "off.toml"
    place(m, Pose(p.tx + 30.0, p.ty, p.angle_deg + 20.0, p.scale * 1.15)).save(off)
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", SCENE_S, "--model", str(off),
                  "--acquire", "--pty")
    yield fw
    fw.close()


def test_firmware_acquires_a_model_placed_off_and_searches_again_on_acquire(acquiring_fw):
    with Device(acquiring_fw.path) as dev:
        snaps = collect_until(dev, lambda s: any(
            (x.trackers["state"] == TRACKING).all() and on_face(x) for x in s), timeout=30)
        assert all(set(x.trackers["state"]) <= {TRACKING} for x in snaps)
        g = dev.acquire()
        snaps = collect_until(dev, lambda s: any(
            x.generation == g and (x.trackers["state"] == TRACKING).all() and on_face(x)
            for x in s), timeout=30)
        mine = [x for x in snaps if x.generation == g]
        # a new search from the events after the command: rows again once it is found,
        # from the first event of the window it was found in
        assert g in dev.applied and mine[0].t_us >= dev.applied[g]
        st = dev.stats()
        assert st.get("instances.face26#1") == "tracking" or st.get("instances", {}).get(
            "face26#1") == "tracking", st
        kc = {k: v for k, v in st.items() if k.startswith("kernel.")} or st.get("kernel", {})
        assert any(k.endswith("acquired") and v >= 2 for k, v in kc.items()), kc


@pytest.mark.hil
def test_acquire_is_refused_by_a_firmware_without_acquisition():
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", SCENE_S, "--pty")
    try:
        with Device(fw.path) as dev:
            with pytest.raises(HostctlError, match="--acquire") as e:
                dev.acquire()
            assert getattr(e.value, "code", Nack.BAD_STATE) == Nack.BAD_STATE
        r = subprocess.run(BIN_HOSTCTL + ["--port", fw.path, "acquire"], capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 6 and "--acquire" in r.stderr
    finally:
        fw.close()


def test_firmware_run_reports_each_instance_state_and_changes():
    """The end-of-run stats line names every instance's state and counts of changes."""
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        "sim:face_occlusion", "--preset", "face26", "--acquire", "--max-speed",
                        "--seconds", "0.3"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    line = r.stdout.strip().splitlines()[-1]
    assert line.startswith("stats: ")
    assert "instances=face26#1:tracking(acquired=1,lost=0,reacquired=0)" in line
