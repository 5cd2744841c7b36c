"""Camera sources by URL (firmware_sim.sources): the registry maps schemes to handler
modules; every simulated source reaches the events through the real pyusb path."""
from __future__ import annotations

import array

import numpy as np
import pytest

from firmware_sim import sources
from firmware_sim import usb as camusb
from firmware_sim.sources import SourceOptions, open_source
from springtrack.events import make
from springtrack.io.ccam import CCamDecoder

# this module is also a handler: "array:N" serves N events of a fixed stream
USAGE = "array:N"
HELP = "the first N events of a test stream"


def stream(n=2000, width=304):
    rng = np.random.default_rng(3)
    return make(np.sort(rng.integers(0, 100_000, n)), rng.integers(0, width, n),
                rng.integers(0, 240, n), rng.integers(0, 2, n))


def open(target, opts, url):
    return sources.simulated(url, sources.events_source(stream()[:int(target)], 256), opts)


def read_all(src) -> np.ndarray:
    """Every event the source's camera sends, through pyusb and the CCam decoder."""
    cam = src.open_camera()
    dec = CCamDecoder()
    buf = array.array("B", bytes(camusb.TRANSFER_BYTES))
    parts = []
    while not src.device.finished:
        parts.append(dec.decode(buf[:cam.read_into(buf, 5)].tobytes()))
    cam.close()
    return np.concatenate(parts)


@pytest.fixture
def array_scheme():
    sources.register("array", __name__)
    yield
    del sources.SCHEMES["array"]


def test_a_registered_scheme_is_served_without_editing_any_caller(array_scheme):
    assert "array:N" in sources.usage() and "array:N: the first N" in sources.describe()
    src = open_source("array:1500", SourceOptions(realtime=False))
    assert src.profile == "ccam_atis" and src.report() == []
    assert np.array_equal(read_all(src), stream()[:1500])


def test_a_failing_source_ends_the_stream_and_says_why():
    """A source that raises mid-stream (an unreadable file, a bug) ends the simulated
    camera's stream like a camera that stops sending; the error is kept for the run's
    end instead of killing the host's reader thread."""
    def events():
        yield stream()[:1000]
        raise OSError("disk gone")
    src = sources.simulated("test:", events(), SourceOptions(realtime=False))
    assert np.array_equal(read_all(src), stream()[:1000])
    assert sources.failure(src) == "OSError: disk gone"


def test_unknown_scheme_names_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown source scheme 'camera'; use sim:SCENE \| "
                                         r"replay:FILE \| usb"):
        open_source("camera:0")


def test_scene_source_brings_its_own_model_and_checks_the_scene():
    src = open_source("sim:face_occlusion", SourceOptions(seconds=0.05, realtime=False))
    assert src.default_model().name and src.device is not None
    with pytest.raises(ValueError, match="unknown scene 'nope'"):
        open_source("sim:nope")


def test_replay_drops_events_outside_the_ccam_sensor_and_reports_them(tmp_path):
    from springtrack import io as stio
    ev = stream(width=320)
    path = tmp_path / "wide.raw"
    stio.write(path, ev, 320, 240, format="evt2")
    src = open_source(f"replay:{path}", SourceOptions(realtime=False))
    keep = ev[ev["x"] < 304]
    assert np.array_equal(read_all(src), keep)
    assert src.report() == [f"replay: {len(ev) - len(keep)} events outside the 304x240 "
                            f"sensor dropped before encoding"]
    with pytest.raises(FileNotFoundError, match="replay file not found"):
        open_source(f"replay:{tmp_path / 'none.raw'}")
    (tmp_path / "junk.raw").write_bytes(b"\x00junk")
    with pytest.raises(ValueError, match="junk.raw"):
        open_source(f"replay:{tmp_path / 'junk.raw'}")


def test_options_that_do_not_apply_are_refused_clearly():
    with pytest.raises(ValueError, match="unknown fault"):
        open_source("sim:face_occlusion", SourceOptions(faults="meteor"))
    with pytest.raises(ValueError, match="--faults needs a simulated source"):
        open_source("usb", SourceOptions(faults="stall"))
    with pytest.raises(ValueError, match="takes no target"):
        open_source("usb:2766")
