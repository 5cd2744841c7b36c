"""hostctl CLI verbs and recording, against a link server on a real pty (in-process thread)
driving the real Tracker-backed test engine; filterpy smoothing on a simulated scene."""
import io
import math

import numpy as np
import pytest

import springtrack
from firmware_sim import transport
from springtrack.sim.sensor import simulate_all
from hostctl import Device, cli
from hostctl.monitor import monitor
from hostctl.smooth import Smoother, smooth_track
from springtrack import wire
from springtrack.model import ShapeModel, TrackerSpec
from springtrack.track import read_csv
from support.link import Served
from support.engine import SimEngine


@pytest.fixture
def served():
    eng = SimEngine()
    s = Served(eng)
    yield s
    s.close()
    eng.close()


def run(capsys, *argv):
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_info_set_get_stats(served, capsys):
    p = served.path
    rc, out, _ = run(capsys, "--port", p, "info")
    assert rc == 0 and "model: face26" in out and "protocol_version: 1" in out
    rc, out, _ = run(capsys, "--port", p, "set", "alpha_position=0.05", "spring_period=40")
    assert rc == 0 and "alpha_position=0.05: generation 2" in out and "generation 3" in out
    served.engine.step()
    rc, out, _ = run(capsys, "--port", p, "get", "alpha_position", "spring_period")
    assert rc == 0 and out.splitlines() == ["alpha_position=0.05", "spring_period=40"]
    rc, out, _ = run(capsys, "--port", p, "set", "pull_frame=image")   # a string value
    assert rc == 0 and "pull_frame='image': generation 4" in out
    served.engine.step()
    rc, out, _ = run(capsys, "--port", p, "get", "pull_frame", "cartesian_frame")
    assert rc == 0 and out.splitlines() == ["pull_frame='image'", "cartesian_frame='similarity'"]
    assert not served.engine.tracker.params.pull_similarity
    rc, out, _ = run(capsys, "--port", p, "stats")
    assert rc == 0 and "updates_applied: 2" in out and "host.lost: 0" in out
    rc, out, _ = run(capsys, "--port", p, "ping", "-n", "3")
    assert rc == 0 and "3 pings" in out


def test_cli_ports_lists_serial_ports(capsys):
    from serial.tools import list_ports
    rc, out, err = run(capsys, "ports")
    devices = [p.device for p in list_ports.comports()]
    assert rc == 0
    assert [line.split("\t")[0] for line in out.splitlines()] == devices
    assert devices or "no serial ports found" in err


def test_cli_errors_exit_nonzero_with_reason(served, capsys):
    rc, _, err = run(capsys, "--port", served.path, "set", "alpha_position=7")
    assert rc == 6 and "PARAM_SET refused (out_of_range)" in err and "alpha_position=7" in err
    rc, _, err = run(capsys, "--port", served.path, "set", "alpha_position")
    assert rc == 1 and "expected NAME=VALUE" in err
    rc, _, err = run(capsys, "--port", served.path, "set", "cartesian_frame=rotated")
    assert rc == 6 and "PARAM_SET refused" in err and "cartesian_frame" in err
    rc, _, err = run(capsys, "--port", "/dev/nonexistent-port", "info")
    assert rc == 3 and "/dev/nonexistent-port: cannot open port" in err
    silent = transport.PtyPort()
    try:
        rc, _, err = run(capsys, "--port", silent.path, "--timeout", "0.1", "--retries", "0", "info")
        assert rc == 4 and f"{silent.path}: no answer to HELLO after 1 tries of 0.1 s" in err
    finally:
        silent.close()
    rc, _, err = run(capsys, "info")
    assert rc == 1 and "no port given" in err


def test_cli_load_model_preset_and_invalid_file(served, capsys, tmp_path):
    rc, out, _ = run(capsys, "--port", served.path, "load-model", "grid3x3")
    assert rc == 0 and "committed as generation 2" in out
    served.engine.step()
    assert served.engine.model.name == "grid3x3"
    bad = tmp_path / "bad.toml"
    bad.write_text(springtrack.model.grid3x3().to_toml().replace('a = "r0c0"', 'a = "zz"', 1))
    rc, _, err = run(capsys, "--port", served.path, "load-model", str(bad))
    assert rc == 6 and "invalid_model" in err and "unknown tracker id 'zz'" in err
    served.engine.step()
    assert served.engine.model.name == "grid3x3"


def test_cli_record_csv_matches_the_offline_tracker(served, capsys, tmp_path):
    served.engine.speed = 1.0                           # 1 kHz telemetry, as specified
    served.engine.run()
    rc, _, _ = run(capsys, "--port", served.path, "start")
    assert rc == 0
    out = tmp_path / "rec.csv"
    rc, text, _ = run(capsys, "--port", served.path, "record", str(out), "--seconds", "0.4",
                      "--smooth")
    assert rc == 0 and "lost device queue 0, device send queue 0, link 0, CRC errors 0, host 0" in text
    rec = read_csv(out)
    assert rec.ids == springtrack.model.face26().ids and len(rec) > 100
    assert np.all(np.diff(rec.t_us) == 1000)
    # the same events through springtrack's own tracker, sampled at the same times
    ev = served.engine.events
    tr = springtrack.Tracker("face26")
    offline = tr.run(ev[ev["t"] < rec.t_us[-1]], sample_us=1000)
    idx = np.searchsorted(offline.t_us, rec.t_us)
    ok = idx < len(offline)
    assert ok.sum() > 100
    assert np.max(np.abs(offline.x[idx[ok]] - rec.x[ok])) <= 1 / 32 + 1e-9
    assert np.max(np.abs(offline.y[idx[ok]] - rec.y[ok])) <= 1 / 32 + 1e-9
    assert np.array_equal(offline.active[idx[ok]], rec.active[ok])
    side = (tmp_path / "rec.smooth.csv").read_text().splitlines()
    assert side[0] == "t_us,tracker,x_s,y_s,vx,vy" and len(side) > 26


def test_record_npz_and_monitor_view(served, tmp_path):
    served.engine.speed = 1.0                           # 1 kHz telemetry, as specified
    served.engine.run()
    with Device(served.path) as dev:
        dev.start()
        buf = io.StringIO()
        monitor(dev, seconds=0.5, smooth=True, rate=20, out=buf)
        frames = buf.getvalue().split("\x1b[H\x1b[2J")[1:]
        assert len(frames) >= 2                          # redraw rate: benchmarks/link.py
        last = frames[-1]
        assert "model face26" in last and "lost frames " in last and "link errors 0" in last
        assert "outline18" in last and "mouth" in last and "vx" in last
        from hostctl.record import save
        summary = save(tmp_path / "r.npz", dev.telemetry(seconds=0.3), dev.info, smooth={})
    z = np.load(tmp_path / "r.npz")
    assert z["x"].shape == (summary["snapshots"], 26) and list(z["ids"][:1]) == ["brow_l"]
    assert z["vx"].shape[1] == 26 and np.all(np.diff(z["t_us"]) == 1000)


def test_host_parser_survives_random_frames(served):
    """The host side of the fuzzing: 3000 well-formed frames (valid COBS and CRC) of every
    type with random payloads go through Device's dispatcher; only counters change."""
    import random
    rng = random.Random(11)
    with Device(served.path) as dev:
        info = dict(dev.info)
        for i in range(3000):
            mtype = rng.choice(list(wire.MsgType) + [0, 0x7E, 0xFF])
            n = rng.choice((0, 1, 2, 4, 7, 8, 15, 23, 28, rng.randrange(300)))
            payload = bytes(rng.randrange(256) for _ in range(n))
            for f in wire.FrameReader().feed(wire.encode_frame(mtype, i, payload,
                                                               version=rng.choice((1, 1, 1, 2)))):
                dev._dispatch(f)
        assert dev.info == info
        assert dev.reader.counts["malformed"] > 0 and dev.counts["foreign_version"] > 0
        dev.replies.clear()
        assert dev.set(alpha_position=0.3) == 2         # still a working session


# ---- filterpy smoothing --------------------------------------------------------------
def test_smoother_constant_velocity_hand_case():
    rng = np.random.default_rng(3)
    t = np.arange(0, 2_000_000, 1000)
    x = 10 + 30.0 * t * 1e-6 + rng.normal(0, 0.5, len(t))
    y = 50 - 12.0 * t * 1e-6 + rng.normal(0, 0.5, len(t))
    sm = smooth_track(t, x[:, None], y[:, None], rate_hz=100)
    assert len(sm["t_us"]) == 200 and np.all(np.diff(sm["t_us"]) == 10_000)
    assert abs(sm["vx"][-1, 0] - 30.0) < 1.5 and abs(sm["vy"][-1, 0] + 12.0) < 1.5
    assert abs(sm["x_s"][-1, 0] - (10 + 30.0 * t[-1] * 1e-6)) < 0.5


def test_smoother_rejects_bad_input():
    with pytest.raises(ValueError, match="positive"):
        Smoother(3, rate_hz=0)
    s = Smoother(3)
    with pytest.raises(ValueError, match="2 trackers, expected 3"):
        s.update(0, [1, 2], [1, 2])


def test_smoothed_velocity_within_10_percent_of_the_scene():
    """moving_blob (40 px/s) -> simulated sensor -> real Tracker -> telemetry encoding ->
    Kalman filter: the velocity estimate is within 10 % of the true part velocity once
    the filter has converged (the tracker locks onto the blob's leading or trailing edge,
    ~6 px from its centre, and may switch edge early on: a 12 px jump)."""
    speed = 40.0
    ev, truth = simulate_all("moving_blob", 3.0, seed=2, speed=speed)
    m = ShapeModel("blob", 304, 240, [TrackerSpec("blob", 60.0, 120.0, (16.0, 0.0, 16.0))], [])
    track = springtrack.Tracker(m).run(ev, sample_us=1000)
    xs, ys = [], []
    for k in range(len(track)):
        tr = np.zeros(1, wire.TRACK_DTYPE)
        for f in ("x", "y", "sxx", "sxy", "syy", "activity"):
            tr[f] = getattr(track, f)[k]
        payload = wire.encode_telemetry(track.t_us[k], 1, 0.0, wire.quantise_trackers(tr))
        _, _, _, dec = wire.decode_telemetry(payload)
        xs.append(dec["x"])
        ys.append(dec["y"])
    sm = smooth_track(track.t_us, np.array(xs), np.array(ys))
    late = sm["t_us"] > 1_500_000
    vx, vy = sm["vx"][late, 0], sm["vy"][late, 0]
    assert np.all(np.abs(vx - speed) <= 0.1 * speed), (vx.min(), vx.max())
    assert np.all(np.abs(vy) <= 0.1 * speed)
    assert math.isclose(np.mean(vx), speed, rel_tol=0.05)


def test_cli_set_is_all_or_nothing(served, capsys):
    """``set A=ok B=bad`` once exited 6 with A already changed on the device."""
    p = served.path
    rc, before, _ = run(capsys, "--port", p, "get", "alpha_position")
    assert rc == 0 and "0.05" not in before
    rc, _, err = run(capsys, "--port", p, "set", "alpha_position=0.05", "sigma_max_px=1e12")
    assert rc == 6 and "out_of_range" in err and "nothing changed (alpha_position set back)" in err
    served.engine.step()
    assert run(capsys, "--port", p, "get", "alpha_position")[1] == before
    rc, _, err = run(capsys, "--port", p, "set", "alpha_position=0.05", "nope=1")
    assert rc == 6 and "unknown" in err                  # refused before anything is set
    served.engine.step()
    assert run(capsys, "--port", p, "get", "alpha_position")[1] == before


def test_record_summary_splits_drops_by_place_and_warns():
    from hostctl import drops
    before = dict(device_queue=10, device_link=3)
    after = dict(device_queue=466, device_link=5)
    host0, host1 = dict(lost=3, crc_errors=0, host=0), dict(lost=8, crc_errors=1, host=2)
    d = drops.span(before, after, host0, host1)
    assert (d["device_queue"], d["device_link"], d["link"], d["crc_errors"], d["host"]) == \
        (456, 2, 3, 1, 2)
    text, warn = drops.summary(d, 339)
    assert warn and "device queue 456" in text and "link 3" in text and "host 2" in text
    assert "57.7% of the span's snapshots missing" in text
    text, warn = drops.summary(drops.span(None, after, host0, host0), 10)
    assert warn and "unknown" in text
    text, warn = drops.summary(drops.span(before, before, host0, host0), 10)
    assert not warn and text == "lost device queue 0, device send queue 0, link 0, CRC errors 0, host 0"
