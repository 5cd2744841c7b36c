"""Fuzz the streaming decoders and the file-format detection (tests/support/decoder_fuzz.py) with
--inputs random and mutated inputs per decoder (default 1,000,000) and --header-inputs
mutated file headers; prints one line per decoder, optionally records them in
docs/formats.md (section "Fuzzing").

    .venv/bin/python benchmarks/fuzz_decoders.py [--inputs 1000000] [--write-docs]
"""
from __future__ import annotations

import argparse
import faulthandler
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from support.decoder_fuzz import DECODERS, fuzz_decoder, fuzz_headers, seeds  # noqa: E402

from _report import replace_section  # noqa: E402

DOC = REPO / "docs" / "formats.md"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--inputs", type=int, default=1_000_000, help="inputs per decoder")
    ap.add_argument("--header-inputs", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", help="comma-separated decoder names")
    ap.add_argument("--write-docs", action="store_true",
                    help="record the result in docs/formats.md (section 'Fuzzing')")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    base = seeds(rng)
    names = args.only.split(",") if args.only else list(DECODERS)
    lines, total_fail = [], 0
    for name in names:
        f, first, secs = fuzz_decoder(name, DECODERS[name], base[name], args.inputs, rng)
        total_fail += f
        line = (f"| {name} | {args.inputs:,} | {f} | {secs:.0f} s |"
                + (f" {first}" if first else ""))
        print(line, flush=True)
        lines.append(line)
    hf, hfirst = fuzz_headers(args.header_inputs, rng)
    total_fail += hf
    hline = f"| open() on mutated headers | {args.header_inputs:,} | {hf} | |" + (
        f" {hfirst}" if hfirst else "")
    print(hline)
    lines.append(hline)
    if args.write_docs:
        body = (f"`.venv/bin/python benchmarks/fuzz_decoders.py --inputs {args.inputs} "
                f"--seed {args.seed} --write-docs` (half random byte strings, half "
                "mutated windows of valid streams; 0-3 split points each; every 50th also "
                "compared with a whole decode):\n\n"
                "| decoder | inputs | failures | time |\n|---|---|---|---|\n"
                + "\n".join(lines) + "\n\nNo crash: the run finished (a segfault would "
                "have aborted it).\n")
        replace_section(DOC, "Fuzzing", body, "# Event file formats\n")
    print(f"total failures: {total_fail}")
    return 1 if total_fail else 0


if __name__ == "__main__":
    faulthandler.enable()      # a segfault prints where it happened
    sys.exit(main())
