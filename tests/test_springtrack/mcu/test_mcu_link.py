"""The firmware image's host link message by message against firmware_sim's
(docs/mcu.md, "Messages"): QEMU runs the image (a separate process), the hostctl API or
the hostctl program steers it over a pty or TCP.

* the firmware's own HEARTBEAT once a second of its clock, with its link counters;
* ENERGIES at most once per wire.ENERGY_PERIOD_US of event time, each the host fixed
  kernel's energies of a spring update, as float32;
* requests the image cannot serve (ACQUIRE without an acquisition search, MODEL_GET
  without a TOML text) are NACKed with firmware_sim's code for a request it cannot serve.

QEMU comes from Debian (qemu-system-arm), installed by ``make test``; without it these tests
skip, except in CI (CI=true), where they fail."""

import numpy as np
import pytest

from support.mcu_image import require_qemu  # noqa: E402

require_qemu()

from hostctl import Device  # noqa: E402
from hostctl.device import Nacked  # noqa: E402
from springtrack import model as smodel, params as sparams, wire  # noqa: E402
from springtrack.fixed.kernel import FixedKernel  # noqa: E402
from springtrack.mcu.qemu import Qemu  # noqa: E402
from springtrack.wire import Nack  # noqa: E402

from support.fwproc import Firmware  # noqa: E402
from support.mcu_image import image, write_scene  # noqa: E402

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
    for t, x, y in zip(ev["t"].tolist(), ev["x"].tolist(), ev["y"].tolist()):
        k.step(t, x, y)
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
            got = []
            while not dev.stream_ended:
                before = dev.counts["energies"]
                list(dev.telemetry(seconds=0.05))
                if dev.counts["energies"] != before:
                    got.append(dev.energies)
            list(dev.telemetry(seconds=1.5))              # a heartbeat at least
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
    for t, kind, values in got:
        assert kind == 0 and len(values) == len(model.connections)
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
