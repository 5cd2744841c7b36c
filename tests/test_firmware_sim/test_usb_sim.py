"""The pyusb path end to end against the simulated CCam ATIS backend.

Everything goes through ``usb.core.find(..., backend=SimBackend(...))`` and pyusb's own
Device/ctrl_transfer/read code, as it would against libusb and a real camera.
"""
from __future__ import annotations

import array
import errno
import struct

import numpy as np
import pytest
import usb.core
import usb.util

from firmware_sim import camera as camusb
from firmware_sim.simcam import SimBackend, SimCamera
from firmware_sim.sources import events_source
from springtrack.events import make
from springtrack.io.ccam import CCamDecoder


def little_stream(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 200_000, n))
    return make(t, rng.integers(0, 304, n), rng.integers(0, 240, n), rng.integers(0, 2, n))


def sim(events=None, **kw):
    cam = SimCamera(events_source(little_stream() if events is None else events), **kw)
    return cam, SimBackend(cam)


def test_find_enumerates_the_camera_with_its_descriptors():
    cam, be = sim()
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x00F4, backend=be)
    assert dev is not None
    assert (dev.idVendor, dev.idProduct, dev.bNumConfigurations) == (0x04B4, 0x00F4, 1)
    assert usb.core.find(idVendor=0x04B4, idProduct=0x1234, backend=be) is None
    dev.set_configuration()
    intf = dev.get_active_configuration()[(0, 0)]
    ep = usb.util.find_descriptor(intf, bEndpointAddress=0x81)
    assert usb.util.endpoint_type(ep.bmAttributes) == usb.util.ENDPOINT_TYPE_BULK
    assert usb.util.endpoint_direction(ep.bEndpointAddress) == usb.util.ENDPOINT_IN
    assert ep.wMaxPacketSize == 512


def test_serial_request_and_serial_selection():
    a, b = (SimCamera(events_source(little_stream()), serial=s, address=k)
            for s, k in ((0x0101, 4), (0x0A0B, 5)))
    be = SimBackend(a, b)
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x00F4, backend=be)
    dev.set_configuration()
    data = dev.ctrl_transfer(0xC0, 0x55, 0x20, 0, 8)
    assert len(data) == 8 and (data[6] << 8 | data[7]) == 0x0101
    dev2 = camusb.find(serial=0x0A0B, backend=be)
    assert camusb.read_serial(dev2) == 0x0A0B and dev2.address == 5
    with pytest.raises(camusb.CameraError, match="serial 7"):
        camusb.find(serial=7, backend=be)


def test_configure_sends_the_driver_sequence():
    cam, be = sim()
    c = camusb.Camera.open("ccam_atis", backend=be, biases={"on_event_threshold": 60})
    assert c.serial == cam.serial
    r = cam.registers
    assert r[0x00A] == r[0x40A] == 0x40                 # flush biases
    assert r[0x008] == r[0x408] == 0x32C                # mode
    assert r[0x000] == r[0x400] == 0xC81                # started
    assert r[0x01A] == 1 and r[0x41A] == 2              # role
    # both bias requests carry the same (value, tension, address) triples
    assert cam.biases[0x61] == cam.biases[0x62]
    loaded = cam.biases[0x61]
    assert loaded[0x07] == (60, 0x7900)                 # on_event_threshold, changed
    assert loaded[0x08] == (39, 0x7900)                 # off_event_threshold, default
    assert loaded[0x1C] == (3, 0x00)                    # static reset_photodiodes
    assert cam.counts["starts"] == 1


def test_bias_payload_layout_is_big_endian_triples():
    p = camusb.bias_payload({"follower": 1})
    assert len(p) == 12 * (len(camusb.BIASES) + len(camusb.STATIC_BIASES))
    first = struct.unpack(">III", p[:12])
    assert first == (207, 0x5900, 0x02)
    with pytest.raises(ValueError, match="unknown bias 'nope'"):
        camusb.bias_payload({"nope": 1})
    with pytest.raises(ValueError, match="0..255"):
        camusb.bias_payload({"follower": 256})


def test_unknown_control_requests_are_rejected_with_a_pipe_error():
    cam, be = sim()
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x00F4, backend=be)
    dev.set_configuration()
    with pytest.raises(usb.core.USBError) as e:
        dev.ctrl_transfer(0x40, 0x77, 0, 0, b"\0\0\0\0")
    assert e.value.errno == errno.EPIPE
    with pytest.raises(usb.core.USBError) as e:
        dev.ctrl_transfer(0x40, 0x61, 0, 0, b"\0" * 11)     # not a multiple of 12
    assert e.value.errno == errno.EPIPE
    assert cam.counts["rejected"] == 2


def test_bulk_reads_return_the_encoded_stream_after_start_only():
    ev = little_stream()
    cam, be = sim(ev)
    dev = camusb.find(backend=be)
    c = camusb.Camera(dev)
    buf = array.array("B", bytes(camusb.TRANSFER_BYTES))
    assert c.read_into(buf, 5) == 0                     # not started: nothing, a timeout
    c.start()
    got = bytearray()
    while not cam.finished:
        n = c.read_into(buf, 5)
        got += buf[:n].tobytes()
    dec = CCamDecoder()
    out = dec.decode(bytes(got))
    assert np.array_equal(out, ev)
    assert dec.stats.total_anomalies == 0


def test_read_length_must_be_a_multiple_of_the_packet_size():
    cam, be = sim()
    c = camusb.Camera.open("ccam_atis", backend=be)
    with pytest.raises(usb.core.USBError) as e:
        c.dev.read(0x81, array.array("B", bytes(1000)), 10)
    assert e.value.errno == errno.EOVERFLOW
    with pytest.raises(camusb.CameraError, match="multiple of wMaxPacketSize"):
        c.read_into(array.array("B", bytes(1000)))


def test_timeouts_are_finite_and_raise_usbtimeouterror():
    cam, be = sim(little_stream(10))
    c = camusb.Camera.open("ccam_atis", backend=be)
    buf = array.array("B", bytes(4096))
    while not cam.finished:
        c.read_into(buf, 5)
    with pytest.raises(usb.core.USBTimeoutError) as e:
        c.dev.read(0x81, buf, 5)
    assert e.value.errno == errno.ETIMEDOUT


def test_realtime_mode_releases_events_at_their_timestamps():
    import time
    t = np.arange(0, 100_000, 100)                      # 1000 events over 0.1 s
    ev = make(t, t % 300, (t // 300) % 240, t % 2)
    cam, be = sim(ev, realtime=True)
    c = camusb.Camera.open("ccam_atis", backend=be)
    buf = array.array("B", bytes(camusb.TRANSFER_BYTES))
    dec = CCamDecoder()
    lag = []
    while not cam.finished:
        n = c.read_into(buf, 20)
        got = dec.decode(buf[:n].tobytes())
        if len(got):
            now = time.monotonic()
            # never early; each event's wall time is when its timestamp came due
            assert cam.wall_of(int(got["t"][-1])) <= now + 1e-4
            lag.append(now - cam.wall_of(int(got["t"][-1])))
    assert np.median(lag) < 0.01


def test_evt_profiles_are_read_only_and_decoded_by_the_fused_loop():
    from firmware_sim._fused import WORD_FORMATS
    for name in ("evt2", "evt21", "evt3"):
        p = camusb.PROFILES[name]
        assert not p.configure and p.fmt == name and p.fmt in WORD_FORMATS
        # and by springtrack.io's streaming decoder, at the profile's geometry, for a kernel
        # the fused loop cannot call (the microcontroller build, docs/mcu.md)
        d = camusb.make_decoder(p)
        assert (d.format, d.width, d.height) == (name, p.width, p.height)
    assert camusb.PROFILES["ccam_atis"].fmt in WORD_FORMATS
    assert camusb.make_decoder(camusb.PROFILES["ccam_atis"]).format == "ccam"
    odd = camusb.DeviceProfile("odd", 1, 2, "evt9", 64, 64, False)
    with pytest.raises(camusb.CameraError, match="no streaming decoder"):
        camusb.make_decoder(odd)


@pytest.mark.parametrize("fmt,legacy", [("evt2", False), ("evt21", False), ("evt21", True),
                                        ("evt3", False)])
def test_evt_profile_streams_chunk_by_chunk_through_the_same_pyusb_path(fmt, legacy):
    """A simulated Prophesee-style EVK: the scene's chunks continue one stream (each
    encoded from the previous one's time base), 512-byte packets on bulk IN 0x81."""
    import dataclasses
    import springtrack.io as sio
    prof = dataclasses.replace(camusb.PROFILES[fmt], legacy=legacy)
    rng = np.random.default_rng(1)
    n = 5000
    ev = make(np.sort(rng.integers(0, 30_000_000, n)), rng.integers(0, prof.width, n),
              rng.integers(0, prof.height, n), rng.integers(0, 2, n))
    cam = SimCamera(events_source(ev, 300), fmt=fmt, legacy=legacy)
    be = SimBackend(cam, pid=prof.pid)
    c = camusb.Camera.open(prof, backend=be)
    assert cam.counts["control_out"] == 0               # no CCam register control
    dec = sio.decoder(fmt, **({"legacy": legacy} if fmt == "evt21" else {}))
    buf = array.array("B", bytes(camusb.TRANSFER_BYTES))
    parts = []
    while not cam.finished:
        parts.append(dec.decode(buf[:c.read_into(buf, 5)].tobytes()))
    assert np.array_equal(np.concatenate(parts), ev)
    assert not any(dec.stats.anomalies.values())


def test_an_evk_refuses_faults_that_write_ccam_words():
    from firmware_sim.faults import Faults
    with pytest.raises(ValueError, match="burst inject CCam words"):
        SimCamera([little_stream()], fmt="evt3", faults=Faults(["corrupt", "burst"]))
    SimCamera([little_stream()], fmt="evt3", faults=Faults(["corrupt"]))   # in its words


def test_a_restart_resumes_the_stream_at_a_word_after_a_full_transfer_ended_mid_word():
    """A full transfer that follows the cut tail of an `odd` transfer ends mid-word; the
    host drops that half word at a stop, so the next start must not send the other half."""
    from firmware_sim.faults import Faults
    cam = SimCamera(events_source(little_stream(20_000), 2048), faults=Faults(["odd"]))
    be = SimBackend(cam)
    c = camusb.Camera.open("ccam_atis", backend=be)
    buf = array.array("B", bytes(16384))
    for _ in range(200):                   # until the head chunk stands inside a word
        c.read_into(buf, 5)
        head = cam.fifo[0] if cam.fifo else None
        if head is not None and head.pos % 4 and head.marks_t[0] >= 0:
            break
    else:
        pytest.fail("no transfer ended mid-word")
    c.close()
    c = camusb.Camera.open("ccam_atis", backend=be)
    got = bytearray()
    while not cam.finished:
        got += buf[:c.read_into(buf, 5)].tobytes()
    dec = CCamDecoder()
    assert len(dec.decode(bytes(got))) > 0
    assert dec.stats.total_anomalies == 0 and len(got) % 4 == 0
    assert 0 < cam.counts["restart_dropped_bytes"] < 4
