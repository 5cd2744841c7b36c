"""Camera sources by URL (firmware_sim.sources): the registry maps schemes to handler
modules; every simulated source reaches the events through the real pyusb path."""
from __future__ import annotations

import array
import builtins

import numpy as np
import pytest

from firmware_sim import sources
from firmware_sim import camera as camusb
from firmware_sim.sources import SourceOptions, open_source
from springtrack import io as stio
from springtrack.events import make

# this module is also a handler: "array:N" serves N events of a fixed stream
USAGE = "array:N"
HELP = "the first N events of a test stream"


def stream(n=2000, width=304):
    rng = np.random.default_rng(3)
    return make(np.sort(rng.integers(0, 100_000, n)), rng.integers(0, width, n),
                rng.integers(0, 240, n), rng.integers(0, 2, n))


def open(target, opts, url):
    return sources.simulated(url, sources.events_source(stream()[:int(target)], 256), opts)


def read_bytes(src) -> bytes:
    """Every byte the source's camera sends, through pyusb."""
    cam = src.open_camera()
    buf = array.array("B", bytes(camusb.TRANSFER_BYTES))
    parts = []
    while not src.device.finished:
        parts.append(buf[:cam.read_into(buf, 5)].tobytes())
    cam.close()
    return b"".join(parts)


def read_all(src) -> np.ndarray:
    """Every event the source's camera sends, decoded as its profile says."""
    p = src.profile
    opts = {"legacy": p.legacy} if p.fmt == "evt21" else {}
    return stio.decoder(p.fmt, **opts).decode(read_bytes(src))


@pytest.fixture
def array_scheme():
    sources.register("array", __name__)
    yield
    del sources.SCHEMES["array"]


def test_a_registered_scheme_is_served_without_editing_any_caller(array_scheme):
    assert "array:N" in sources.usage() and "array:N: the first N" in sources.describe()
    src = open_source("array:1500", SourceOptions(realtime=False))
    assert src.profile.name == "ccam_atis" and src.report() == []
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


@pytest.mark.parametrize("fmt,legacy", [("evt2", False), ("evt21", False), ("evt21", True),
                                        ("evt3", False)])
def test_replay_serves_a_raw_file_s_words_as_they_are_at_its_geometry(tmp_path, fmt, legacy):
    ev = stream(width=640)
    path = tmp_path / "wide.raw"
    stio.write(path, ev, 640, 480, format=fmt + ("-legacy" if legacy else ""))
    src = open_source(f"replay:{path}", SourceOptions(realtime=False))
    p = src.profile
    assert (p.fmt, p.width, p.height, p.legacy) == (fmt, 640, 480, legacy)
    r = stio.open(path)
    with builtins.open(path, "rb") as f:
        payload = f.read()[r.offset:]
    assert read_bytes(src) == payload                  # the recorded words, unchanged
    assert "words as recorded, 640x480" in src.notes[0] and src.report() == []


def test_replay_with_a_smaller_profile_drops_events_and_says_so_everywhere(tmp_path):
    ev = stream(width=320)
    path = tmp_path / "wide.raw"
    stio.write(path, ev, 320, 240, format="evt2")
    src = open_source(f"replay:{path}", SourceOptions(realtime=False, profile="ccam_atis"))
    assert src.profile.name == "ccam_atis"
    assert "does not fit the 304x240 sensor of --profile ccam_atis" in src.notes[1]
    keep = ev[ev["x"] < 304]
    assert np.array_equal(read_all(src), keep)
    dropped = len(ev) - len(keep)
    assert src.counters() == {"outside_sensor": dropped, "events_in": len(ev), "t_offset_us": 0,
                              "file_anomalies": 0}
    assert src.report() == [f"replay: warning: {dropped} of {len(ev)} events "
                            f"({dropped / len(ev):.1%}) lay outside the 304x240 sensor and "
                            f"were dropped before encoding"]


def test_replay_re_encodes_other_formats_for_an_evk_of_their_geometry(tmp_path):
    ev = stream(width=320)
    path = tmp_path / "rec.es"
    stio.write(path, ev, 320, 240)
    src = open_source(f"replay:{path}", SourceOptions(realtime=False))
    assert (src.profile.fmt, src.profile.width, src.profile.height) == ("evt2", 320, 240)
    assert np.array_equal(read_all(src), ev)
    src = open_source(f"replay:{path}", SourceOptions(realtime=False, profile="evt3"))
    assert np.array_equal(read_all(src), ev)


def test_replay_re_bases_a_recording_stamped_in_epoch_microseconds(tmp_path):
    ev = stream()
    ev["t"] += 1_605_537_493_718_345
    path = tmp_path / "epoch.npy"
    np.save(path, ev)
    src = open_source(f"replay:{path}", SourceOptions(realtime=False, profile="evt3"))
    got = read_all(src)
    assert np.array_equal(got["t"], ev["t"] - ev["t"][0])
    assert f"re-based by -{ev['t'][0]} us" in src.report()[0]


def test_replay_checks_its_file(tmp_path):
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
