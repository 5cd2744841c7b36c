"""A seconds-long slice of benchmarks/fuzz_decoders.py (the full run is 1,000,000 inputs
per decoder, recorded in docs/formats.md)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_decoders.py"


def test_fuzz_slice_is_clean(capsys):
    spec = importlib.util.spec_from_file_location("fuzz_decoders", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--inputs", "400", "--header-inputs", "300", "--seed", "5"]) == 0
    out = capsys.readouterr().out
    assert "total failures: 0" in out and out.count("| 400 | 0 |") == len(mod.DECODERS)
