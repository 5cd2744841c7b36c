"""``springtrack info``: the facts it prints for a file we built by hand."""
from __future__ import annotations

import json

import numpy as np

import springtrack.io as sio
from springtrack.cli import main
from springtrack.commands.info import summarize
from springtrack.events import make


def test_info_facts(tmp_path):
    # 100 events in [0, 10 ms) and 300 in [20 ms, 30 ms): peak 300 per 10 ms = 30 kev/s
    t = np.concatenate([np.linspace(0, 9_999, 100), np.linspace(20_000, 29_999, 300)])
    ev = make(t.astype(np.int64), np.arange(400) % 304, np.arange(400) % 240, np.arange(400) % 2)
    path = tmp_path / "a.raw"
    sio.write(path, ev, 304, 240)
    f = summarize(path, chunk=64)
    assert (f["format"], f["width"], f["height"], f["events"]) == ("evt2", 304, 240, 400)
    assert (f["t_first_us"], f["t_last_us"], f["span_us"]) == (0, 29_999, 29_999)
    assert f["peak_rate_ev_s"] == 300 / 0.01 and f["peak_bin_start_us"] == 20_000
    assert abs(f["mean_rate_ev_s"] - 400 / 0.029999) < 1e-6
    assert f["on_events"] == 200
    assert f["header"]["geometry_source"] == "format"
    assert sum(f["anomalies"].values()) == 0


def test_info_cli_reports_anomalies(tmp_path, capsys):
    words = np.array([0x8000_0001, 0x1000_0801, 0x3000_0000, 0x8000_0000], dtype="<u4")
    path = tmp_path / "b.raw"
    path.write_bytes(b"% evt 2.0\n% geometry 10x10\n" + words.tobytes() + b"\x01\x02")
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "format    evt2" in out and "geometry  10x10" in out
    assert "events    1 (1 ON)" in out
    assert "unknown_type 1" in out and "time_backwards 1" in out and "truncated 1" in out
    assert main(["info", "--json", str(path)]) == 0
    facts = json.loads(capsys.readouterr().out)
    assert facts["anomalies"]["truncated"] == 1 and facts["words"] == 4


def test_info_cli_errors(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing.raw")]) == 2
    (tmp_path / "g.bin").write_bytes(b"\x00\x01garbage")
    assert main(["info", str(tmp_path / "g.bin")]) == 2
    assert "unknown format" in capsys.readouterr().err


def test_info_real_file(data_file, capsys):
    assert main(["info", str(data_file("evt2_sample.raw"))]) == 0
    out = capsys.readouterr().out
    assert "events    539,481" in out and "1,317,888 .. 1,367,888 us" in out


def test_info_aedat4_shows_streams_and_both_times(data_file, capsys):
    assert main(["info", str(data_file("sample.aedat4"))]) == 0
    out = capsys.readouterr().out
    assert "format    aedat4" in out and "geometry  320x240 (from info node)" in out
    assert "2 imu (IMUS" in out and "118 packets" in out
    assert "1,605,537,493,718,345 .. 1,605,537,494,308,262 us" in out
    assert "2020-11-16 14:38:13.718345 UTC .. 2020-11-16 14:38:14.308262 UTC" in out
    assert "= 0 .. 589,917 us from the first event" in out
    assert "imu_packets 59" in out and "anomalies none" in out


def test_info_evt21_shows_word_order(tmp_path, capsys):
    ev = make(np.arange(100), np.arange(100) % 320, np.arange(100) % 320, np.arange(100) % 2)
    path = tmp_path / "g.raw"
    sio.write(path, ev, 320, 320, format="evt21-legacy")
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "format    evt21" in out and "geometry  320x320" in out
    assert "endianness: legacy" in out and "events    100 (50 ON)" in out
    assert "Unix-epoch" not in out


def test_info_peak_rate_is_never_below_the_mean_on_a_short_recording(data_file):
    """evt3_sample.raw spans 8.8 ms, less than one 10 ms bin: the peak is the mean, not
    the count of a bin the recording only partly covers."""
    f = summarize(data_file("evt3_sample.raw"))
    assert f["span_us"] < 10_000
    assert f["peak_rate_ev_s"] >= f["mean_rate_ev_s"] * (1 - 1e-12)
    g = summarize(data_file("evt2_sample.raw"))      # 50 ms: whole bins from the first event
    assert g["peak_rate_ev_s"] >= g["mean_rate_ev_s"]
    assert (g["peak_bin_start_us"] - g["t_first_us"]) % 10_000 == 0


def test_info_says_a_file_of_mostly_corrupt_words_is_doubtful(tmp_path, capsys, data_file):
    """Random bytes behind an EVT 3.0 header: described, and called doubtful with the way
    out (the commands that use events refuse it); a real recording is not."""
    path = tmp_path / "g.raw"
    path.write_bytes(b"% evt 3.0\n% geometry 304x240\n% end\n"
                     + bytes(np.random.default_rng(3).integers(0, 256, 1 << 17, np.uint8)))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "doubtful  over 10% of the words are corrupt: not a file of format evt3" in out
    assert main(["info", "--json", str(path)]) == 0
    assert json.loads(capsys.readouterr().out)["undecodable"] is True
    assert main(["info", str(data_file("evt3_sample.raw"))]) == 0
    assert "doubtful" not in capsys.readouterr().out
