"""Memory bounded by the input, not by its time span: hostile inputs whose event time runs
over hours or days (a long gap, counter wraps, overflow bytes) tracked by `springtrack
track` and by the firmware's replay path, each in a subprocess whose peak resident memory
is measured (tests/support/peak_rss.py, with a data limit so that a regression fails fast).  Empty
stretches are sampled for sampling.HOLD periods and at their end (springtrack/sampling.py), and the rows are
written as they are taken."""
import subprocess
import sys

import numpy as np
import pytest

from springtrack import sampling
from springtrack.events import make
from springtrack.io import es
from springtrack.io.writers import encode_file
from springtrack.track import read_csv
from support import REPO

HERE = REPO / "tests" / "support"
CEILING_MIB = 200          # peak resident memory allowed (an idle interpreter: ~35 MiB)
LIMIT_MIB = 1500           # data the subprocess may allocate at all
P = 1000                   # the default --sample-us
ES_DVS_OVERFLOW = 0xFF     # Event Stream DVS: t += 127 us (springtrack/io/es.pyx EsDvsBytes)


def peak_rss(tool, *argv):
    """Run the command line; return (its status, peak RSS MiB, stdout)."""
    r = subprocess.run([sys.executable, str(HERE / "peak_rss.py"), str(LIMIT_MIB), tool, *argv],
                       capture_output=True, text=True, timeout=600)
    peak = float(r.stderr.rsplit("peak_rss_mib", 1)[1])
    return r.returncode, peak, r.stdout + r.stderr


def blocks(n_blocks, per_block, gap_us, width=304, height=240, seed=0):
    """``n_blocks`` bursts of ``per_block`` events 1 us apart, ``gap_us`` between bursts."""
    rng = np.random.default_rng(seed)
    t = (np.arange(n_blocks)[:, None] * (gap_us + per_block) + np.arange(per_block)).ravel()
    n = len(t)
    return make(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))


def expected_rows(ev, k_trackers):
    """Rows of the track: the samples the rule takes (springtrack.reference's loop)."""
    from springtrack.reference import ReferenceTracker
    from springtrack.model import load_model
    ref = ReferenceTracker(load_model("grid3x3"))
    return len(ref.run(ev, P)) * k_trackers


def track(tmp_path, src, *extra):
    out = tmp_path / "out.csv"
    rc, peak, log = peak_rss("springtrack", "track", str(src), "--model", "grid3x3", "--out",
                             str(out), "--no-progress", *extra)
    assert rc == 0, log
    return peak, out


def test_a_47_byte_csv_with_a_10_10_us_gap(tmp_path):
    src = tmp_path / "gap.csv"
    src.write_text("t,x,y,p\n0,10,10,1\n5,12,10,1\n10000000000,11,10,0\n")
    assert src.stat().st_size <= 48
    peak, out = track(tmp_path, src)
    assert peak < CEILING_MIB
    tr = read_csv(out)                    # the empty stretch: HOLD periods, then its end
    assert list(tr.t_us) == list(range(0, sampling.HOLD * P + 1, P)) + [10 ** 10]
    assert len(tr.t_us) <= sampling.PER_EVENT * 3


@pytest.mark.slow
@pytest.mark.parametrize("fmt,gap_us", [("evt2", (1 << 34) + 12_345),     # a 28-bit wrap
                                        ("evt3", (1 << 24) + 12_345)])    # a 12-bit wrap
def test_raw_files_with_repeated_wraps(tmp_path, fmt, gap_us):
    """1.6 MB RAW files: bursts of events between 1000 gaps of one counter wrap each (4.8 h
    for EVT 2.0's TIME_HIGH, 16.8 s for EVT 3.0's): hours of event time, a few MB of input."""
    ev = blocks(1000, 400 if fmt == "evt2" else 270, gap_us)
    src = tmp_path / f"wraps.{fmt}.raw"
    src.write_bytes(encode_file(ev, 304, 240, fmt))
    assert 1.5e6 < src.stat().st_size < 1.8e6
    peak, out = track(tmp_path, src)
    assert peak < CEILING_MIB
    assert sum(1 for _ in open(out)) - 1 == expected_rows(ev, 9)


def test_a_dat_file_with_a_wrap(tmp_path):
    """DAT timestamps are 32 bits: bursts at 0, 2^31 + 10^6 us (36 min later) and, after the
    counter wrapped, at 500 us again, i.e. 2^32 + 500 us."""
    from springtrack.io import dat
    parts = [blocks(1, 1000, 0, seed=k) for k in range(3)]
    parts[1]["t"] += (1 << 31) + 10 ** 6
    parts[2]["t"] += 500
    src = tmp_path / "wrap.dat"
    src.write_bytes(encode_file(parts[0], 304, 240, "dat") + dat.encode(parts[1])
                    + dat.encode(parts[2]))
    peak, out = track(tmp_path, src)
    assert peak < CEILING_MIB
    parts[2]["t"] += 1 << 32
    assert sum(1 for _ in open(out)) - 1 == expected_rows(np.concatenate(parts), 9)


def test_an_event_stream_file_with_8_mb_of_overflow_bytes(tmp_path):
    """Each DVS overflow byte adds 127 us: 8 MiB of them put 18 minutes between two events."""
    first, last = blocks(1, 500, 0), blocks(1, 500, 0, seed=1)
    src = tmp_path / "overflow.es"
    src.write_bytes(es.header("dvs", 304, 240) + es.encode(first, "dvs")
                    + bytes([ES_DVS_OVERFLOW]) * (8 << 20) + es.encode(last, "dvs"))
    peak, out = track(tmp_path, src)
    assert peak < CEILING_MIB
    rows = read_csv(out)
    assert rows.t_us[-1] - rows.t_us[0] > (8 << 20) * 127 * 0.99


def test_the_firmware_replay_path(tmp_path):
    """`firmware-sim run --source replay:` of the gap CSV: the simulated camera, the fused
    loop and the recorder, as fast as the loop takes it; its record equals `springtrack
    track`'s."""
    src = tmp_path / "gap.csv"
    src.write_text("t,x,y,p\n0,10,10,1\n5,12,10,1\n10000000000,11,10,0\n")
    rec = tmp_path / "fw.csv"
    rc, peak, log = peak_rss("firmware-sim", "run", "--source", f"replay:{src}", "--preset",
                             "grid3x3", "--sensor-from", "model", "--max-speed", "--record",
                             str(rec), "--stats-every", "0")
    assert rc == 0, log
    assert peak < CEILING_MIB
    _, out = track(tmp_path, src)
    assert rec.read_bytes() == out.read_bytes()


def test_render_memory_does_not_grow_with_the_frames(tmp_path):
    """``render`` streams its frames to the writer (GIF: springtrack.render.GifStream), so
    200 frames take no more memory than 20 (imageio's GIF writer kept every frame, about
    1 MB each here, until it closed); the GIF holds every frame."""
    from PIL import Image
    src = tmp_path / "ev.npy"
    np.save(src, blocks(200, 200, 10_000))             # 2 s of events
    peaks = {}
    for n in (20, 200):
        out = tmp_path / f"r{n}.gif"
        rc, peaks[n], log = peak_rss("springtrack", "render", str(src), "--model", "grid3x3",
                                     "--out", str(out), "--every-us", str(2_000_000 // n),
                                     "--window-us", "10000")
        assert rc == 0, log
        written = int(log.split(": ")[-1].split(" frame")[0])       # "wrote OUT: N frame(s)"
        assert Image.open(out).n_frames == written >= n
    assert peaks[200] - peaks[20] < 25, peaks
    assert peaks[200] < CEILING_MIB


def test_render_without_a_model_streams_the_events(tmp_path):
    """Without a model ``render`` counts the events per pixel chunk by chunk as it reads
    them: 4 M events (64 MB as records) take no more memory than 200 k."""
    rng = np.random.default_rng(2)
    peaks = {}
    for n in (200_000, 4_000_000):
        ev = make(np.arange(n) * 5, rng.integers(0, 640, n), rng.integers(0, 480, n),
                  rng.integers(0, 2, n))
        src = tmp_path / f"e{n}.raw"
        src.write_bytes(encode_file(ev, 640, 480, "evt3"))
        del ev
        rc, peaks[n], log = peak_rss("springtrack", "render", str(src),
                                     "--out", str(tmp_path / f"e{n}.png"))
        assert rc == 0 and f"{n:,} events on the 640x480 sensor" in log, log
    assert peaks[4_000_000] - peaks[200_000] < 25, peaks
