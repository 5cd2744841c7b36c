"""Hand-computed decoder cases for every format: layouts, wraps, anomalies, carry."""
from __future__ import annotations

import struct

import numpy as np
import pytest

import springtrack.io as sio
from support.words import ccam_mixed_words, evt2_mixed_words, evt3_mixed_words


def u32(*words):
    return struct.pack(f"<{len(words)}I", *words)


def u16(*words):
    return struct.pack(f"<{len(words)}H", *words)


def rows(ev):
    return [tuple(int(v) for v in e) for e in ev]


# ---- EVT 2.0 ----------------------------------------------------------------------------

def evt2_cd(p, tlow, x, y):
    return (p << 28) | (tlow << 22) | (x << 11) | y


def test_evt2_words():
    dec = sio.decoder("evt2")
    data = u32(0x8000_0010, evt2_cd(1, 5, 100, 200), evt2_cd(0, 63, 2047, 0),
               0xA000_0001, 0xE000_0000, 0xF000_0000, 0x3000_0000)
    ev = dec.decode(data)
    assert rows(ev) == [(16 * 64 + 5, 100, 200, 1), (16 * 64 + 63, 2047, 0, 0)]
    s = dec.stats
    assert s.words == 7 and s.events == 2
    assert s.info == {"time_high_words": 1, "triggers": 1, "other_words": 2}
    assert s.anomalies["unknown_type"] == 1


def test_evt2_wrap_and_backwards():
    dec = sio.decoder("evt2")
    top = (1 << 28) - 1
    ev = dec.decode(u32(0x8000_0000 | top, evt2_cd(1, 1, 0, 0),
                        0x8000_0002, evt2_cd(1, 2, 0, 0),          # wrap: +2**28
                        0x8000_0001, evt2_cd(1, 3, 0, 0)))         # back by 1: rebased
    # rebased one time-high unit past the last one (timebase.pxd)
    assert list(ev["t"]) == [top * 64 + 1, ((1 << 28) + 2) * 64 + 2, ((1 << 28) + 3) * 64 + 3]
    assert dec.stats.info["time_wraps"] == 1
    assert dec.stats.anomalies["time_backwards"] == 1


def test_evt2_geometry_and_carry():
    dec = sio.decoder("evt2", width=100, height=50)
    data = u32(0x8000_0001, evt2_cd(1, 0, 99, 49), evt2_cd(1, 0, 100, 0), evt2_cd(0, 0, 0, 50))
    out = [dec.decode(data[i:i + 3]) for i in range(0, len(data), 3)]
    assert rows(np.concatenate(out)) == [(64, 99, 49, 1)]
    assert dec.stats.anomalies["out_of_geometry"] == 2
    assert dec.decode(b"\x01\x02") .size == 0 and dec.pending_bytes == 2
    assert dec.finish() == 2 and dec.stats.anomalies["truncated"] == 1
    assert dec.pending_bytes == 0


def test_evt2_before_time_high_counted():
    dec = sio.decoder("evt2")
    ev = dec.decode(u32(evt2_cd(1, 7, 1, 1)))
    assert rows(ev) == [(7, 1, 1, 1)] and dec.stats.info["before_time_high"] == 1


# ---- EVT 3.0 ----------------------------------------------------------------------------

def test_evt3_vectors_and_addresses():
    dec = sio.decoder("evt3")
    data = u16(0x8001,                 # TIME_HIGH 1
               0x6002,                 # TIME_LOW 2   -> t = 4098
               0x0007,                 # ADDR_Y 7
               0x2000 | 1 << 11 | 5,   # ADDR_X p=1 x=5
               0x3000 | 1 << 11 | 10,  # VECT_BASE_X p=1 x=10
               0x4000 | 0b1000_0000_0101,   # VECT_12: x 10, 12, 21
               0x5000 | 0b1000_0001,        # VECT_8:  x 22, 29
               0x2000 | 0 << 11 | 3,   # ADDR_X p=0 x=3
               0xA000, 0xE000, 0xF000, 0x7000, 0x9000)
    ev = dec.decode(data)
    assert rows(ev) == [(4098, 5, 7, 1), (4098, 10, 7, 1), (4098, 12, 7, 1), (4098, 21, 7, 1),
                        (4098, 22, 7, 1), (4098, 29, 7, 1), (4098, 3, 7, 0)]
    assert dec.stats.info["triggers"] == 1 and dec.stats.info["other_words"] == 3
    assert dec.stats.anomalies["unknown_type"] == 1


def test_evt3_orphans_dropped_and_counted():
    dec = sio.decoder("evt3")
    ev = dec.decode(u16(0x2005, 0x0003, 0x4FFF, 0x2006))   # x before y; vector before base
    assert rows(ev) == [(0, 6, 3, 0)]
    assert dec.stats.anomalies["orphan"] == 2


def test_evt3_wrap_vs_backwards():
    dec = sio.decoder("evt3")
    ev = dec.decode(u16(0x0001, 0x8FFF, 0x6010, 0x2000,      # t = 4095*4096 + 16
                        0x8000, 0x6001, 0x2001,              # wrap: 2**24 + 1
                        0x8000 | 3000, 0x2002,               # forward
                        0x8000 | 1000, 0x6002, 0x2003))      # back by 2000: rebased
    t = list(ev["t"])
    assert t[0] == 4095 * 4096 + 16 and t[1] == (1 << 24) + 1
    assert t[2] == (1 << 24) + 3000 * 4096 + 1
    assert t[3] == (1 << 24) + 3001 * 4096 + 2                # rebased to 3000 + 1
    assert dec.stats.info["time_wraps"] == 1 and dec.stats.anomalies["time_backwards"] == 1


def test_evt3_vector_split_across_calls():
    data = u16(0x0002, 0x3000 | 100, 0x4FFF, 0x50FF)
    whole = sio.decoder("evt3").decode(data)
    dec = sio.decoder("evt3")
    parts = [dec.decode(data[i:i + 1]) for i in range(len(data))]
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    assert list(whole["x"]) == list(range(100, 120))


# ---- CCam ATIS --------------------------------------------------------------------------

def test_ccam_word_layout():
    dec = sio.decoder("ccam", keep_exposure=True)
    # time-high 1 -> offset 2048 us; event: b0=39 (y=200), b1=0x2C, b2=0x03 (x bit 8,
    # t bit 0), b3=0x15 (t bits 10..7 = 5, p=1)  ->  x=300, t=2048 + (5<<7 | 1)
    ev = dec.decode(bytes([1, 0, 0, 0x80, 39, 0x2C, 0x03, 0x15,
                           0, 7, 0, 0x20]))                 # exposure event at y=239, x=7
    assert rows(ev) == [(2048 + 641, 300, 200, 1)]
    assert rows(dec.take_exposure()) == [(2048, 7, 239, 0)]
    assert dec.stats.info == {"time_high_words": 1, "exposure_events": 1}


def test_ccam_wrap_backwards_garbage():
    dec = sio.decoder("ccam")
    ev = dec.decode(bytes([0xFF, 0xFF, 0xFF, 0x80, 0, 0, 0, 0,     # th = 2**24 - 1
                           1, 0, 0, 0x80, 0, 1, 0, 0,              # wrap -> 2**24 + 1
                           0, 0, 0, 0x80, 0, 2, 0, 0,              # back by 1: rebased
                           240, 0, 0, 0, 0, 0x30, 1, 0,            # y out, x = 304 out
                           0, 0, 0, 0xC1]))                        # bits 7..6: unknown
    assert list(ev["t"]) == [((1 << 24) - 1) * 2048, ((1 << 24) + 1) * 2048,
                             ((1 << 24) + 2) * 2048]
    a = dec.stats.anomalies
    assert (a["time_backwards"], a["out_of_geometry"], a["unknown_type"]) == (1, 2, 1)
    assert dec.stats.info["time_wraps"] == 1


def test_ccam_geometry_is_fixed():
    with pytest.raises(ValueError, match="304x240"):
        sio.decoder("ccam", width=640, height=480)


# ---- Event Stream -----------------------------------------------------------------------

def test_es_dvs_bytes():
    dec = sio.decoder("es", event_type="dvs", width=320, height=240)
    ev = dec.decode(bytes([0xFF, 0x05, 3, 0, 4, 0,      # t = 127 + 2, p = 1
                           0xFE,                          # reset byte
                           0x00, 0x40, 1, 0xEF, 0]))      # x = 320: out of geometry
    assert rows(ev) == [(129, 3, 4, 1)]
    assert dec.stats.info == {"overflow_bytes": 1, "reset_bytes": 1}
    assert dec.stats.anomalies["out_of_geometry"] == 1


def test_es_atis_bytes():
    dec = sio.decoder("es", event_type="atis", width=304, height=240, keep_exposure=True)
    ev = dec.decode(bytes([0xFE,                          # overflow x2: t += 126
                           (5 << 2) | 0b10, 1, 1, 2, 0,   # t = 131, p = 1: x 257, y 2
                           0xFC,                          # reset
                           (1 << 2) | 0b01, 0, 0, 0, 0])) # exposure at t = 132
    assert rows(ev) == [(131, 257, 2, 1)]
    assert rows(dec.take_exposure()) == [(132, 0, 0, 0)]
    assert dec.stats.info == {"overflow_bytes": 1, "reset_bytes": 1, "exposure_events": 1}


def test_es_partial_event_pending():
    dec = sio.decoder("es", event_type="dvs")
    assert dec.decode(bytes([0x01, 2, 0])).size == 0
    assert dec.pending_bytes == 3
    assert rows(dec.decode(bytes([3, 0]))) == [(0, 2, 3, 1)]
    dec.decode(bytes([0x01]))
    assert dec.finish() == 1 and dec.stats.anomalies["truncated"] == 1


# ---- DAT --------------------------------------------------------------------------------

def test_dat_records_and_wrap():
    dec = sio.decoder("dat", width=640, height=480)
    rec = lambda t, x, y, p: struct.pack("<II", t, x | y << 14 | p << 28)
    ev = dec.decode(rec(0xFFFF_FFF0, 639, 479, 1) + rec(5, 1, 2, 0)      # wrap
                    + rec(3, 1, 2, 0)                                     # back by 2
                    + rec(4, 1, 3, 1)                                     # goes on from there
                    + rec(6, 640, 0, 0) + rec(7, 0, 0, 3))                # x out; p=3
    assert rows(ev) == [(0xFFFF_FFF0, 639, 479, 1), ((1 << 32) + 5, 1, 2, 0),
                        ((1 << 32) + 6, 1, 2, 0), ((1 << 32) + 7, 1, 3, 1)]
    a = dec.stats.anomalies
    assert (a["time_backwards"], a["out_of_geometry"], a["unknown_type"]) == (1, 1, 1)


# ---- the time base, one policy for every format ------------------------------------------

def policy_counts(raws, bits):
    """The documented rule (docs/formats.md#time-base), written out independently: a drop
    of more than half the range is a wrap, a smaller one is rebased one unit past the last
    count.  Returns the counts and the numbers of wraps and backward jumps."""
    counts, epoch, last, wraps, back = [], 0, None, 0, 0
    for r in raws:
        if last is not None and r < last:
            if last - r > 1 << (bits - 1):
                epoch, wraps = epoch + (1 << bits), wraps + 1
            else:
                epoch, back = epoch + last - r + 1, back + 1
        last = r
        counts.append(epoch + r)
    return counts, wraps, back


def time_base_stream(fmt, raws):
    """One time-base counter value then one event (x 1, y 2, p 1; low time bits 5) per
    value, in ``fmt``'s words; returns (bytes, bits, shift) of the format's counter."""
    if fmt == "ccam":
        w = b"".join(bytes([r & 0xFF, (r >> 8) & 0xFF, r >> 16, 0x80])
                     + bytes([239 - 2, 1, 5 << 1, 1 << 4]) for r in raws)
        return w, 24, 11
    if fmt == "evt2":
        return u32(*[w for r in raws for w in (0x8000_0000 | r, evt2_cd(1, 5, 1, 2))]), 28, 6
    if fmt == "evt3":
        return u16(0x0002, 0x6005, *[w for r in raws for w in (0x8000 | r, 0x2801)]), 12, 12
    rec = b"".join(struct.pack("<II", r, 1 | 2 << 14 | 1 << 28) for r in raws)
    return rec, 32, 0


@pytest.mark.parametrize("fmt", ["ccam", "evt2", "evt3", "dat"])
def test_every_decoder_keeps_the_one_time_base_policy(fmt):
    """Wraps, backward jumps (small and by almost half the range) and forward jumps of the
    time counter give the same counts in every format: the one time-base helper."""
    bits = {"ccam": 24, "evt2": 28, "evt3": 12, "dat": 32}[fmt]
    top, half = (1 << bits) - 1, 1 << (bits - 1)
    # wraps: top -> 1, top -> 2, half + 3 -> 1; backward jumps: 4 -> 2, 3 -> 0, half -> 1
    # and half + 2 -> 2 (a drop of exactly half the range is not a wrap)
    raws = [top - 2, top, 1, 4, 2, 3, 3, 0, half, 1, top, 2, half + 2, 2, half + 3, 1]
    data, bits, shift = time_base_stream(fmt, raws)
    counts, wraps, back = policy_counts(raws, bits)
    dec = sio.decoder(fmt)
    ev = dec.decode(data)
    low = 0 if fmt == "dat" else 5
    assert list(ev["t"]) == [(c << shift) | low for c in counts]
    assert np.all(np.diff(ev["t"]) >= 0)                  # time never goes back
    assert (wraps, back) == (3, 4)
    assert dec.stats.info["time_wraps"] == wraps
    assert dec.stats.anomalies["time_backwards"] == back


def test_unknown_decoder_name():
    with pytest.raises(ValueError, match="known: ccam, evt2, evt3, es, dat"):
        sio.decoder("evt4")


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_ccam_block_path_equals_word_by_word(seed):
    """The decoder takes runs of plain event words 32 at a time (io/ccam_block.h) and any
    block with another word word by word: the same events, exposure events and counters
    as decoding one word per call (never a block), special words at every kind of place."""
    data = ccam_mixed_words(seed)
    whole = sio.decoder("ccam", keep_exposure=True)
    single = sio.decoder("ccam", keep_exposure=True)
    a = whole.decode(data)
    b = np.concatenate([single.decode(data[i:i + 4]) for i in range(0, len(data), 4)])
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(whole.take_exposure(), single.take_exposure())
    assert whole.stats.anomalies == single.stats.anomalies
    assert whole.stats.info == single.stats.info
    assert len(a) > 2500 and sum(whole.stats.anomalies.values()) > 10


def decoded_whole_and_by_word(fmt, data, **opts):
    """``data`` decoded in one call (block paths) and one word per call (never a block):
    asserts the same events and counters; returns the events and the counters."""
    whole = sio.decoder(fmt, **opts)
    single = sio.decoder(fmt, **opts)
    a = whole.decode(data)
    ws = whole.word_size
    b = np.concatenate([single.decode(data[i:i + ws]) for i in range(0, len(data), ws)])
    np.testing.assert_array_equal(a, b)
    assert whole.stats == single.stats
    return a, whole.stats


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_evt2_block_path_equals_word_by_word(seed):
    """The EVT 2.0 decoder takes runs of plain CD words 32 at a time (io/evt2_block.h) and
    any block with another word word by word: the same events and counters as decoding
    one word per call (never a block)."""
    a, stats = decoded_whole_and_by_word("evt2", evt2_mixed_words(seed), width=640, height=480)
    assert len(a) > 3900 and sum(stats.anomalies.values()) > 10


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_evt3_block_path_equals_word_by_word(seed):
    """The EVT 3.0 decoder takes plain event words 16 at a time (io/evt3_block.h) and any
    other word word by word: the same events and counters as decoding one word per call
    (never a block), with every kind of word at every kind of place."""
    a, s = decoded_whole_and_by_word("evt3", evt3_mixed_words(seed), width=640, height=480)
    assert len(a) > 30_000 and s.anomalies["orphan"] > 0 and s.anomalies["out_of_geometry"] > 0
    assert s.info["time_low_backwards"] > 100 and s.anomalies["unknown_type"] > 10


@pytest.mark.slow
def test_evt3_block_path_on_the_recording(data_file):
    """The real EVT 3.0 recording decoded whole (blocks) and one word per call (never a
    block): the same events and counters."""
    path = data_file("evt3_sample.raw")
    data = path.read_bytes()[sio.open(path).offset:]
    a, _ = decoded_whole_and_by_word("evt3", data, width=1280, height=720)
    assert len(a) == 219_596
