"""UDP event streams in aestream's layout (springtrack.live.udp): the decoder against
hand-made words, and a sender process on loopback into springtrack track."""
from __future__ import annotations

import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from support.live_senders import free_port
from springtrack import io as stio
from springtrack.events import make
from springtrack.live import udp
from support import REPO

SENDER = str(REPO / "tests" / "support" / "live_senders.py")
TRACK = [sys.executable, "-m", "springtrack.cli", "track"]
MODEL = ["--model", "grid3x3", "--sensor-from", "file", "--no-progress"]


def test_the_words_are_aestreams_layout():
    """x in bits 30-16, polarity bit 15, y in bits 14-0, then the time word; bit 31 set
    when no time word follows (aestream's dvs_to_udp)."""
    ev = make([5, 70_000], [3, 32767], [2, 1], [1, 0])
    words = np.frombuffer(udp.encode(ev), "<u4")
    assert list(words) == [(3 << 16) | 0x8000 | 2, 5, (32767 << 16) | 1, 70_000]
    words = np.frombuffer(udp.encode(ev, timestamps=False), "<u4")
    assert list(words) == [0x8000_0000 | (3 << 16) | 0x8000 | 2, 0x8000_0000 | (32767 << 16) | 1]


def test_decoding_unwraps_the_32_bit_clock_and_counts_what_is_not_an_event():
    dec = udp.Decoder()
    ev = make([(1 << 32) - 10, (1 << 32) - 5], [1, 2], [3, 4], [0, 1])
    out, bad = dec.decode(udp.encode(ev), 0.0)
    assert list(out["t"]) == [(1 << 32) - 10, (1 << 32) - 5] and bad == 0
    nxt = make([(1 << 32) + 7, (1 << 32) + 6], [1, 1], [1, 1], [1, 1])   # wrapped, then back 1
    out, bad = dec.decode(udp.encode(nxt) + b"\x01\x02\x03", 0.0)
    assert list(out["t"]) == [(1 << 32) + 7, (1 << 32) + 6] and bad == 3
    # a timed datagram holding an untimed word: that pair dropped, counted
    words = np.frombuffer(udp.encode(nxt), "<u4").copy()
    words[2] |= 0x8000_0000
    out, bad = dec.decode(words.tobytes(), 0.0)
    assert len(out) == 1 and bad == 8
    # untimed datagrams are stamped with the receiver's clock since the first datagram
    out, bad = dec.decode(udp.encode(nxt, timestamps=False), 0.25)
    assert list(out["t"]) == [250_000, 250_000] and list(out["x"]) == [1, 1]


@pytest.mark.parametrize("url, says", [
    ("udp://127.0.0.1", "give the address to listen on as udp://HOST:PORT"),
    ("udp://127.0.0.1:5000?geometry=640", "option geometry='640': must be WxH"),
    ("udp://127.0.0.1:5000?size=1x1", "unknown option 'size'"),
])
def test_udp_urls_that_cannot_open_say_why(url, says):
    from springtrack import live
    with pytest.raises(ValueError, match=re.escape(says)):
        live.open(url)


def wait_bound(port: int, deadline_s: float = 60.0) -> None:
    """Until a process listens on UDP 127.0.0.1:``port`` (binding it then fails)."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return
        time.sleep(0.05)
    raise AssertionError(f"nothing listened on udp 127.0.0.1:{port}")


def rebased_sample(data_file, tmp_path) -> Path:
    """The AEDAT 4 sample with its times from the start of its second (they fit the
    layout's 32-bit clock), as Event Stream (which keeps the 320 x 240 sensor size)."""
    ev = stio.open(data_file("sample.aedat4")).read()
    ev["t"] -= ev["t"][0] - ev["t"][0] % 1_000_000
    stio.write(tmp_path / "s.es", ev, 320, 240)
    return tmp_path / "s.es"


def run_udp(npy, tmp_path, out: str, *sender_args, query="?geometry=320x240"):
    port = free_port(socket.SOCK_DGRAM)
    rx = subprocess.Popen(TRACK + [f"udp://127.0.0.1:{port}{query}", "--out",
                                   str(tmp_path / out)] + MODEL,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_bound(port)
    subprocess.run([sys.executable, SENDER, "udp", f"127.0.0.1:{port}", str(npy), *sender_args],
                   check=True, capture_output=True, timeout=120)
    out_, err = rx.communicate(timeout=120)
    assert rx.returncode == 0, err
    return out_, err


def test_track_of_a_udp_stream_equals_the_files(data_file, tmp_path):
    npy = rebased_sample(data_file, tmp_path)
    subprocess.run(TRACK + [str(npy), "--out", str(tmp_path / "file.csv")] + MODEL,
                   capture_output=True, check=True)
    out, err = run_udp(npy, tmp_path, "live.csv")
    n = len(stio.open(npy).read())
    assert f"events={n} batches={-(-n // 512)} gaps=0 reconnects=0 bad_bytes=0" in err
    assert "ended: the sender's end marker" in err
    assert (tmp_path / "live.csv").read_bytes() == (tmp_path / "file.csv").read_bytes()


def test_a_udp_stream_that_stops_ends_by_its_timeout_with_its_counts(data_file, tmp_path):
    npy = rebased_sample(data_file, tmp_path)
    subprocess.run(TRACK + [str(npy), "--out", str(tmp_path / "file.csv")] + MODEL,
                   capture_output=True, check=True)
    out, err = run_udp(npy, tmp_path, "cut.csv", "--cut", "20000",
                       query="?geometry=320x240&timeout=1")
    assert "events=20000 batches=40 " in err and "ended: no datagram for 1 s" in err
    cut = (tmp_path / "cut.csv").read_text().splitlines()
    full = (tmp_path / "file.csv").read_text().splitlines()
    assert 1 < len(cut) < len(full) and cut == full[:len(cut)]


def test_firmware_sim_tracks_a_udp_stream_as_springtrack_tracks_the_file(data_file, tmp_path):
    """The layout carries no geometry: firmware-sim takes --geometry; the record equals
    springtrack track's CSV of the same events (times under the camera counter's range:
    no re-basing)."""
    es = rebased_sample(data_file, tmp_path)
    subprocess.run(TRACK + [str(es), "--out", str(tmp_path / "file.csv")] + MODEL,
                   capture_output=True, check=True)
    port = free_port(socket.SOCK_DGRAM)
    fw = subprocess.Popen([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                           f"udp://127.0.0.1:{port}", "--geometry", "320x240", "--model",
                           "grid3x3", "--sensor-from", "source", "--max-speed", "--record",
                           str(tmp_path / "fw.csv"), "--stats-every", "0"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_bound(port)
    subprocess.run([sys.executable, SENDER, "udp", f"127.0.0.1:{port}", str(es)],
                   check=True, capture_output=True, timeout=120)
    out, err = fw.communicate(timeout=120)
    assert fw.returncode == 0, err
    assert "udp 320x240 (from --geometry)" in out + err
    assert (tmp_path / "fw.csv").read_bytes() == (tmp_path / "file.csv").read_bytes()


def test_firmware_sim_asks_for_the_geometry_a_udp_stream_lacks():
    r = subprocess.run([sys.executable, "-m", "firmware_sim.cli", "run", "--source",
                        f"udp://127.0.0.1:{free_port(socket.SOCK_DGRAM)}", "--max-speed"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "give --geometry WxH" in r.stderr, r.stderr
