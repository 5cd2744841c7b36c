"""A seconds-long slice of the decoder fuzzing of tests/support/decoder_fuzz.py (the full run,
benchmarks/fuzz_decoders.py, is 1,000,000 inputs per decoder, recorded in docs/formats.md)."""
from __future__ import annotations

import numpy as np

from support.decoder_fuzz import DECODERS, fuzz_decoder, fuzz_headers, seeds


def test_fuzz_slice_is_clean():
    """400 inputs per decoder and 300 mutated headers, drawn as the full run draws them."""
    rng = np.random.default_rng(5)
    base = seeds(rng)
    bad = {}
    for name, opts in DECODERS.items():
        failures, first, _ = fuzz_decoder(name, opts, base[name], 400, rng)
        if failures:
            bad[name] = f"{failures} failures, first: {first}"
    failures, first = fuzz_headers(300, rng)
    if failures:
        bad["open() on mutated headers"] = f"{failures} failures, first: {first}"
    assert not bad, bad
