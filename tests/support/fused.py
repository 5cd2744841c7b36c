"""Helpers of the fused loop's tests: run a Fused over pieces, compare with the offline tracker."""
from __future__ import annotations

import numpy as np
from springtrack.track import TRACK_FIELDS


def collect(f, pieces):
    outs = [o for o in (f.feed(p) for p in pieces) if o is not None]
    return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}


def assert_same(ref, got):
    assert np.array_equal(ref.t_us, got["t"])
    for k in TRACK_FIELDS:
        assert np.array_equal(getattr(ref, k), got["trackers"][k]), k
    assert np.array_equal(ref.energy, got["energy"])
