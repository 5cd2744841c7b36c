"""Camera word streams with every kind of special word mixed in, for decoder tests."""
from __future__ import annotations

import numpy as np


def ccam_mixed_words(seed, n_events=3000, n_special=60):
    from springtrack.io import ccam
    """A CCam word stream of plain events with special words at random places: exposure
    events, events out of the sensor (y, x), unknown words, repeated time-high words."""
    from springtrack.events import make
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 20_000, n_events))
    ev = make(t, rng.integers(0, 304, n_events), rng.integers(0, 240, n_events),
              rng.integers(0, 2, n_events))
    words = np.frombuffer(ccam.encode(ev), np.uint8).reshape(-1, 4).copy()
    special = []
    for pos in sorted(rng.integers(1, len(words), n_special)):
        kind = rng.integers(0, 5)
        w = words[pos].copy()
        if kind == 0 and w[3] != 0x80:
            w[3] |= 0x20                                  # exposure event
        elif kind == 1 and w[3] != 0x80:
            w[0] = 250                                    # y out of the sensor
        elif kind == 2:
            w = np.array([0, 0, 0, 0xC1], np.uint8)       # unknown type
        elif kind == 3 and w[3] != 0x80:
            w[1], w[2] = 0x40, w[2] | 1                   # x = 320, out of the sensor
        else:
            prev = [q for q in words[:pos] if q[3] == 0x80][-1]
            w = prev.copy()                               # the same time-high again
        special.append((pos, w))
    out = list(words)
    for pos, w in reversed(special):
        out.insert(pos, w)
    return np.array(out, np.uint8).tobytes()


def evt2_mixed_words(seed, n_events=4000, n_special=80):
    """An EVT 2.0 word stream of CD events (t dense enough for runs of 32 between
    TIME_HIGH words) with other words at random places: triggers, 'other' types, unknown
    types, events outside 640 x 480 (alone and in runs of up to 70), repeated TIME_HIGH
    words."""
    from springtrack.events import make
    from springtrack.io import evt2
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 3000, n_events))
    ev = make(t, rng.integers(0, 640, n_events), rng.integers(0, 480, n_events),
              rng.integers(0, 2, n_events))
    words = list(np.frombuffer(evt2.encode(ev), "<u4"))
    for pos in sorted(rng.integers(1, len(words), n_special), reverse=True):
        kind = rng.integers(0, 7)
        if kind == 5:                                      # a run of events outside
            words[pos:pos] = [(1 << 28) | (int(rng.integers(0, 640)) << 11) | 480 + i % 7
                              for i in range(int(rng.integers(2, 70)))]
            continue
        if kind == 0:
            w = 0xA << 28                                  # external trigger
        elif kind == 1:
            w = 0xE << 28                                  # 'other'
        elif kind == 2:
            w = 0x3 << 28                                  # unknown type
        elif kind == 3:
            w = (1 << 28) | (700 << 11) | 10               # x = 700 outside 640
        elif kind == 6:
            w = (0 << 28) | (5 << 11) | 2047               # y = 2047 outside 480
        else:
            w = [q for q in words[:pos] if q >> 28 == 0x8][-1]   # the same TIME_HIGH again
        words.insert(pos, w)
    return np.array(words, "<u4").tobytes()


def evt3_mixed_words(seed, n_words=40_000, width=640, height=480):
    """An EVT 3.0 word stream shaped like a sensor's: rows of EVT_ADDR_X runs and vector
    groups (VECT_BASE_X, then VECT_12 / VECT_8 with random masks), EVT_TIME_LOW words
    (sometimes going back), EVT_TIME_HIGH words (sometimes wrapping or going back), and
    the rare words at random places: events and vectors before their address or base,
    events and vectors reaching outside width x height, triggers, 'other' and unknown
    types, a vector base driven far by vectors without a VECT_BASE_X."""
    rng = np.random.default_rng(seed)
    # after the first time high: events and vectors before any row and base (orphans)
    words, th = [0x8000, 0x2005, 0x2006, 0x4FFF, 0x2007, 0x5003, 0x0003, 0x4001, 0x2008], 0
    while len(words) < n_words:
        r = rng.random()
        if r < 0.35:
            words.append(0x0000 | int(rng.integers(0, height + 8)))        # EVT_ADDR_Y
            for _ in range(int(rng.integers(0, 6))):                        # EVT_ADDR_X
                words.append(0x2000 | int(rng.integers(0, 2)) << 11
                             | int(rng.integers(0, width + 4)))
        elif r < 0.55:                                                      # a vector group
            words.append(0x3000 | int(rng.integers(0, 2)) << 11
                         | int(rng.integers(0, width + 20)))
            for _ in range(int(rng.integers(1, 5))):
                v12 = rng.random() < 0.6
                bits = int(rng.integers(0, 1 << (12 if v12 else 8)))
                bits &= int(rng.integers(0, 1 << (12 if v12 else 8)))       # sparse masks
                words.append((0x4000 if v12 else 0x5000) | bits)
        elif r < 0.62:
            words.append(0x6000 | int(rng.integers(0, 4096)))               # EVT_TIME_LOW
        elif r < 0.635:
            th = (th + int(rng.choice([1, 1, 1, 2, -3, 4000]))) % 4096      # EVT_TIME_HIGH
            words.append(0x8000 | th)
        elif r < 0.645:
            words.append(int(rng.choice([0xA000, 0xE000, 0xF000, 0x7000, 0x1000, 0x9000,
                                         0xC000, 0xD000])) | int(rng.integers(0, 4096)))
        elif r < 0.65:                                                      # base far away
            words.extend([0x4FFF] * int(rng.integers(100, 400)))
        else:
            words.append(0x2000 | int(rng.integers(0, width)))
    return np.array(words, "<u2").tobytes()
