"""The firmware image's host link message by message against firmware_sim's
(docs/mcu.md, "Messages"): QEMU runs the image (a separate process), the hostctl API or
the hostctl program steers it over a pty or TCP.

* the firmware's own HEARTBEAT once a second of its clock, with its link counters;
* ENERGIES at most once per wire.ENERGY_PERIOD_US of event time, each the host fixed
  kernel's energies of a spring update, as float32;
* requests the image cannot serve (ACQUIRE without an acquisition search, MODEL_GET
  without a TOML text) are NACKed with firmware_sim's code for a request it cannot serve;
* PARAM_SET by name: the generations, values, refusal codes and telemetry of
  firmware-sim --backend fixed, the kernel's words those of springtrack.fixed.q, and the
  hostctl program's set / get through ``springtrack mcu run --listen``.

QEMU comes from Debian (qemu-system-arm), installed by ``make test``; without it these tests
skip, except in CI (CI=true), where they fail."""

import socket
import subprocess
import zlib

import numpy as np
import pytest

from support.mcu_image import require_qemu  # noqa: E402

require_qemu()

from hostctl import Device  # noqa: E402
from hostctl.device import Nacked  # noqa: E402
from springtrack import model as smodel, params as sparams, wire  # noqa: E402
from springtrack.fixed import q as fixed_q  # noqa: E402
from springtrack.fixed.kernel import FixedKernel  # noqa: E402
from springtrack.mcu.qemu import Qemu  # noqa: E402
from springtrack.process_end import end_child  # noqa: E402
from springtrack.wire import MsgType, Nack  # noqa: E402

from support.fwproc import Firmware, hostctl_cmd  # noqa: E402
from support.mcu_image import (image, run_to_end, same_snapshots, springtrack_cmd,  # noqa: E402
                                write_scene)

pytestmark = pytest.mark.hil
BOARD = "mps2-an386"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("scene")
    ev = write_scene(d)
    return d, ev


def host_energies(model, ev):
    """The host fixed kernel's criterion energies at the start and after each spring
    update, as float32."""
    k = FixedKernel(model, sparams.resolve(model))
    kind = sparams.resolve(model).energy_kind_index
    out, updates = [k.energies()[kind].astype(np.float32)], 0
    for t, x, y, p in zip(*(ev[c].tolist() for c in "txyp")):
        k.step(t, x, y, p)
        u = k.counters()["spring_updates"]
        if u != updates:
            updates = u
            out.append(k.energies()[kind].astype(np.float32))
    return out


def test_heartbeat_and_energies_as_firmware_sim_sends_them(scene):
    d, ev = scene
    model = smodel.load(d / "face.toml")
    with Qemu(image(BOARD).elf, BOARD, d / "face.raw") as q:
        with Device(q.link, timeout=0.5, retries=20) as dev:
            dev.load_model(d / "face.toml")
            dev.start()
            while not dev.stream_ended:
                list(dev.telemetry(seconds=0.05))
            list(dev.telemetry(seconds=1.5))              # a heartbeat at least
            # every ENERGIES frame, however many one read brought
            got = list(dev.energies_log)
            beat = dict(dev.firmware_link)
            st = dev.stats()
    assert set(beat) == set(wire.HEARTBEAT_FIELDS)
    assert beat["uptime_us"] > 0 and beat["rx_frames"] >= 10 and beat["tx_frames"] > 100
    assert beat["rx_errors"] == beat["tx_dropped"] == 0
    assert beat["rx_frames"] <= st["link.rx_frames"]
    # one ENERGIES per 100 ms of event time (0.2 s of events: at t0 and t0 + >= 100 ms)
    assert len(got) == 2, [g[0] for g in got]
    assert got[1][0] - got[0][0] >= wire.ENERGY_PERIOD_US
    ref = host_energies(model, ev)
    want = sparams.resolve(model).energy_kind_index          # the model's, or the default
    for t, kind, values in got:
        assert kind == want and len(values) == len(model.connections)
        assert any(np.array_equal(values.astype(np.float32), r) for r in ref), t
    assert np.any(got[-1][2] > 0)


def test_requests_the_image_cannot_serve_get_firmware_sims_nack(scene):
    """ACQUIRE: BAD_STATE, as firmware-sim without --acquire; MODEL_GET: BAD_STATE too (the
    image keeps words, not TOML); nothing changes and the session goes on."""
    d, _ = scene
    fw = Firmware("--source", f"replay:{d / 'face.raw'}", "--backend", "fixed",
                  "--max-speed", "--pty", "--wait-start")
    try:
        with Device(fw.path, timeout=0.5, retries=20) as dev:
            with pytest.raises(Nacked) as e:
                dev.acquire()
            sim_code = e.value.code
    finally:
        fw.close()
    assert sim_code == Nack.BAD_STATE
    with Qemu(image(BOARD).elf, BOARD, d / "face.raw") as q:
        with Device(q.link, timeout=0.5, retries=20) as dev:
            gen = dev.load_model(d / "face.toml")
            with pytest.raises(Nacked) as e:
                dev.acquire()
            assert e.value.code == sim_code and "acquisition" in e.value.reason
            with pytest.raises(Nacked) as e:
                dev.get_model()
            assert e.value.code == Nack.BAD_STATE and "words" in e.value.reason
            assert dev.stats()["generation"] == gen
            assert dev.ping() < 5.0


# ---- PARAM_SET by name ---------------------------------------------------------------
SETS = [("alpha_position", 0.1), ("p_threshold", 0.05), ("activity_tau_us", 5000.0),
        ("alpha_covariance", 1e-4), ("energy_gain", 0.3), ("spring_period", 40),
        ("spring_period", 30.0), ("energy_kind", "torsional"), ("pull_frame", "image"),
        ("sigma_min_px", 0.75), ("sigma_max_px", 40), ("activity_threshold", 4.0),
        ("energy_scale", 3.0), ("cartesian_frame", "image"), ("energy_kind", "euclidean"),
        ("motion_tau_us", 2000.0), ("polarity_gain", 0.3)]
REFUSED = [("nope", 1.0), ("alpha_position", "x"), ("spring_period", 1.5),
           ("spring_period", True), ("alpha_position", 5.0), ("alpha_position", float("nan")),
           ("activity_tau_us", float("inf")), ("energy_kind", "foo"), ("energy_kind", 3),
           ("sigma_min_px", 50.0), ("alpha_covariance", 0.9), ("motion_tau_us", 0.5),
           ("spring_period", 2 ** 62), ("spring_period", 2 ** 62 + 1), ("pull_frame", 1.0)]
MALFORMED = [b"", b"\x05abc", b"\x01ax\x00", b"\x01ab\x02", b"\x01af" + bytes(9),
             b"\x02\xff\xfef" + bytes(8)]


def words_crc(params, nc):
    return zlib.crc32(fixed_q.params_words(params, nc).tobytes())


def steer(dev, nc=None):
    """SETS, then REFUSED and MALFORMED through PARAM_SET by name: the ACKed generations,
    the refusal codes, PARAM_GET after each, and (the image) the kernel's words' CRC-32."""
    out = dict(gens=[], codes=[], values=[], crcs=[])
    for name, value in SETS:
        out["gens"].append(dev._command(MsgType.PARAM_SET, wire.encode_param_set(name, value)))
        out["values"].append(dev.get())
        if nc is not None:
            out["crcs"].append(dev.stats()["params_crc32"])
    for payload in [wire.encode_param_set(n, v) for n, v in REFUSED] + MALFORMED:
        with pytest.raises(Nacked) as e:
            dev._command(MsgType.PARAM_SET, payload)
        out["codes"].append(e.value.code)
    dev.reset()                                          # keeps the parameters set
    out["values"].append(dev.get())
    if nc is not None:
        out["crcs"].append(dev.stats()["params_crc32"])
    return out


def test_param_set_by_name_as_firmware_sim(scene):
    """Every parameter set by name in the image and in firmware-sim --backend fixed: the
    same generations, values and refusal codes (unknown name, wrong type, out of range,
    the set's own limits, malformed payloads), the refused ones changing nothing; the
    image's kernel words are springtrack.fixed.q.params_words' after each change; the
    telemetry of the changed parameters (the motion model on: velocities too) is the same,
    snapshot for snapshot."""
    d, _ = scene
    model = smodel.load(d / "face.toml")
    nc = len(model.connections)
    fw = Firmware("--source", f"replay:{d / 'face.raw'}", "--backend", "fixed",
                  "--max-speed", "--pty", "--wait-start", "--model", str(d / "face.toml"))
    try:
        with Device(fw.path, timeout=0.5, retries=20) as dev:
            dev.load_model(d / "face.toml")
            sim = steer(dev)
            sim["snaps"] = run_to_end(dev)
    finally:
        fw.close()
    with Qemu(image(BOARD).elf, BOARD, d / "face.raw") as q:
        with Device(q.link, timeout=0.5, retries=20) as dev:
            dev.load_model(d / "face.toml")
            mcu = steer(dev, nc)
            mcu["snaps"] = run_to_end(dev)
    assert [g - sim["gens"][0] for g in sim["gens"]] == [g - mcu["gens"][0] for g in mcu["gens"]]
    assert mcu["codes"] == sim["codes"], list(zip(REFUSED + MALFORMED, mcu["codes"], sim["codes"]))
    tracking = [{k: v for k, v in d.items() if k in sparams.SPECS} for d in sim["values"]]
    assert mcu["values"] == tracking                     # firmware-sim adds camera biases
    for values, crc in zip(mcu["values"], mcu["crcs"]):
        assert crc == words_crc(sparams.Params(**values), nc), values
    assert mcu["crcs"][-1] == mcu["crcs"][-2]            # the refusals changed nothing
    same_snapshots(mcu["snaps"], sim["snaps"])
    assert any(np.any(x.trackers["vx"] != 0) for x in mcu["snaps"])   # the velocity block


def test_hostctl_set_and_get_through_mcu_run_listen(scene, tmp_path):
    """The hostctl program, unchanged, against `springtrack mcu run --listen`: set several
    parameters at once (PARAM_SET by name), get them back; a refused one changes nothing
    and exits with the NACK."""
    d, _ = scene
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(springtrack_cmd("mcu", "run", str(image(BOARD).elf), "--board", BOARD,
                                            "--events", str(d / "face.raw"), "--listen",
                                            f"127.0.0.1:{port}"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith("listen: socket://"), (line, proc.poll())
        link = line.split()[1]

        def hostctl(*args):
            return subprocess.run(hostctl_cmd("--port", link, "--retries", "20", *args),
                                  capture_output=True, text=True, timeout=120)
        assert hostctl("load-model", str(d / "face.toml")).returncode == 0
        r = hostctl("set", "spring_period=40", "energy_kind=torsional", "p_threshold=0.05")
        assert r.returncode == 0, r.stderr
        r = hostctl("set", "alpha_position=0.3", "sigma_min_px=80")
        assert r.returncode != 0 and "out_of_range" in (r.stdout + r.stderr).lower(), r
        r = hostctl("get", "spring_period", "energy_kind", "p_threshold", "alpha_position")
        assert r.returncode == 0, r.stderr
        assert r.stdout.split() == ["spring_period=40", "energy_kind='torsional'",
                                    "p_threshold=0.05", "alpha_position=0.2"]
    finally:
        end_child(proc)
        proc.stdout.close()
        proc.stderr.close()
