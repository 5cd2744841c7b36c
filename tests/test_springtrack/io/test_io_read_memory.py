"""Reader.read allocates by the events a file holds, not by the most its length could hold
(springtrack/io/reader.py: sized by the first READ_SAMPLE bytes' events per byte, doubled
if the rest is denser): measured with tracemalloc, which sees numpy's buffers."""
from __future__ import annotations

import tracemalloc

import numpy as np

import springtrack.io as sio
from springtrack.events import make
from springtrack.io import evt2

TIME_HIGH_0 = (0x8 << 28).to_bytes(4, "little")      # an EVT 2.0 TIME_HIGH word, value 0


def traced_peak(fn):
    tracemalloc.start()
    try:
        out = fn()
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def few_events_file(path, n_filler_words: int, where: str) -> np.ndarray:
    """An EVT 2.0 file of 20,000 events and ``n_filler_words`` valid TIME_HIGH words
    (no event in them) before or after the events."""
    rng = np.random.default_rng(2)
    ev = make(np.sort(rng.integers(0, 1_000_000, 20_000)), rng.integers(0, 304, 20_000),
              rng.integers(0, 240, 20_000), rng.integers(0, 2, 20_000))
    header = b"% evt 2.0\n% geometry 304x240\n% end\n"
    filler = TIME_HIGH_0 * n_filler_words
    words = evt2.encode(ev)
    path.write_bytes(header + (filler + words if where == "before" else words + filler))
    return ev


def test_a_file_of_few_events_among_many_words_allocates_by_its_events(tmp_path):
    path = tmp_path / "sparse.raw"
    ev = few_events_file(path, 1 << 22, "before")              # 16 MiB of TIME_HIGH words
    got, peak = traced_peak(lambda: sio.open(path).read())
    np.testing.assert_array_equal(got[["t", "x", "y", "p"]], ev[["t", "x", "y", "p"]])
    size = path.stat().st_size
    # the most 16 MiB of EVT 2.0 words could hold is 4 M events (64 MiB): read allocated
    # that, 4 times the file, whatever the file held; now the events (0.3 MiB), the
    # first sample's decode (1 MiB) and the buffers
    assert peak < size / 4, (peak, size)


def test_a_dense_file_is_read_in_one_right_sized_array(tmp_path):
    path = tmp_path / "dense.raw"
    ev = few_events_file(path, 0, "after")
    got, peak = traced_peak(lambda: sio.open(path).read())
    assert len(got) == len(ev)
    # the events (16 bytes each), the first sample's decode and the read buffer
    assert peak < 1.2 * got.nbytes + (3 << 20), (peak, got.nbytes)


def test_a_rest_denser_than_the_sample_grows_the_array(tmp_path):
    path = tmp_path / "late.raw"
    ev = few_events_file(path, 1 << 18, "before")              # 1 MiB of words, then events
    got = sio.open(path).read()
    np.testing.assert_array_equal(got[["t", "x", "y", "p"]], ev[["t", "x", "y", "p"]])
