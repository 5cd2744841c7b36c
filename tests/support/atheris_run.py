"""One fuzz target of tests/support/fuzz_targets.py under atheris, in this process (its loop
ends the process):

    python tests/support/atheris_run.py TARGET [libFuzzer options ...] [CORPUS_DIR ...]

e.g. ``-max_total_time=3`` (seconds), ``-runs=N``, ``-timeout=5`` (seconds an input may
take: longer is a finding), ``-artifact_prefix=DIR/`` (where a finding's input is written).
The target's seeds are written into a fresh corpus directory given first.  The springtrack
modules a target reaches are instrumented for coverage (Python code; the Cython decoders
are fuzzed by mutation from their seeds).  Exit status 0: nothing found; otherwise
libFuzzer's, with the input and the Python traceback on standard error."""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

if __name__ == "__main__" and os.environ.get("SPRINGTRACK_FUZZ_CHILD") != "1":
    # Linux carries a process's peak RSS (getrusage's ru_maxrss, what -rss_limit_mb reads)
    # across exec from the process it was forked from: started by a large pytest, the
    # fuzzer would see pytest's size and stop at once.  A child of this small process
    # counts its own memory only.
    child = subprocess.run([sys.executable, *sys.argv],
                           env=dict(os.environ, SPRINGTRACK_FUZZ_CHILD="1"))
    sys.exit(child.returncode if child.returncode >= 0 else 128 - child.returncode)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))     # tests/: `support`

import atheris  # noqa: E402

with atheris.instrument_imports(include=["springtrack", "support"]):
    from support.fuzz_targets import TARGETS  # noqa: E402


def main(argv: list[str]) -> None:
    if len(argv) < 2 or argv[1] not in TARGETS:
        sys.exit(f"usage: {argv[0]} TARGET [libFuzzer options] [CORPUS_DIR ...]; targets: "
                 f"{', '.join(TARGETS)}")
    target = TARGETS[argv[1]]
    seeds = Path(tempfile.mkdtemp(prefix=f"fuzz-{target.name}-"))
    for k, data in enumerate(target.seeds()):
        (seeds / f"seed{k}").write_bytes(data)

    def one_input(data: bytes) -> None:
        try:
            target.run(data)
        except target.allowed:
            pass

    # libFuzzer reads the corpus directories among its arguments: the seeds first
    atheris.Setup([argv[0], *argv[2:], str(seeds)], one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main(sys.argv)
