"""The long run of the coverage-guided fuzz targets (tests/support/fuzz_targets.py, under
atheris: tests/support/atheris_run.py): each target for --seconds in its own process, its
corpus kept in --corpus/TARGET between runs; prints one line per target (inputs run,
coverage, corpus, findings) and keeps each finding's input in --corpus/findings/.

    .venv/bin/python benchmarks/fuzz_atheris.py [--seconds 60] [--only decoder-evt3,model-toml]

Needs the fuzz extra: pip install 'springtrack[fuzz]'.  Results: docs/formats.md, "Fuzzing".
"""
from __future__ import annotations

import argparse
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from support.fuzz_targets import TARGETS  # noqa: E402

RUNNER = REPO / "tests" / "support" / "atheris_run.py"
DONE = re.compile(r"#(\d+)\s+DONE\s+cov: (\d+) ft: (\d+) corp: (\d+)/")


def run_target(name: str, seconds: int, corpus: Path) -> str:
    out = corpus / name
    findings = corpus / "findings"
    out.mkdir(parents=True, exist_ok=True)
    findings.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, str(RUNNER), name, f"-max_total_time={seconds}",
                        "-timeout=10", "-rss_limit_mb=2048", f"-artifact_prefix={findings}/{name}-",
                        "-print_final_stats=1", str(out)],
                       capture_output=True, text=True, timeout=seconds + 300)
    wall = time.perf_counter() - t0
    m = DONE.search(r.stderr)
    runs, cov, ft, corp = m.groups() if m else ("?",) * 4
    verdict = "nothing found" if r.returncode == 0 else \
        f"FOUND (exit {r.returncode}): " + " | ".join(r.stderr.strip().splitlines()[-6:])
    return (f"{name:22s} {runs:>9s} inputs in {wall:5.0f} s, cov {cov} ft {ft}, "
            f"corpus {corp}: {verdict}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=int, default=60, help="seconds per target")
    ap.add_argument("--only", help="comma-separated target names (default: all)")
    ap.add_argument("--corpus", type=Path, default=Path("/tmp/springtrack-fuzz"),
                    help="directory of the corpora kept between runs, and of the findings")
    args = ap.parse_args(argv)
    names = args.only.split(",") if args.only else list(TARGETS)
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, python "
          f"{platform.python_version()}, {args.seconds} s per target", flush=True)
    bad = 0
    for name in names:
        line = run_target(name, args.seconds, args.corpus)
        bad += "FOUND" in line
        print(line, flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
