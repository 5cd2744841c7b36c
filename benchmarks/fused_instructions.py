"""Instructions per event of the fused decode + track loop in each camera word format,
counted by callgrind (deterministic, unlike times on a shared machine): the same events of
the face_occlusion scene in CCam, EVT 2.0, EVT 2.1 and EVT 3.0 words, face26 tracking, only
``Fused.feed`` counted.  The kernel's work is the same in every format, so the differences
between the rows are the decoders'.  Writes the "Fused loop instructions" section of
docs/benchmarks.md.

Run: .venv/bin/python benchmarks/fused_instructions.py [--events N] [--no-write]
(needs valgrind; about 15 s per format at the default 400,000 events)
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _report import machine, write_section  # noqa: E402

FORMATS = ("ccam", "evt2", "evt21", "evt3")
FEED = "__pyx_pw_12firmware_sim_6_fused_5Fused_9feed"     # Fused.feed's Cython wrapper
CHILD = """
import sys
from springtrack.tracker import Tracker, make_backend
from firmware_sim._fused import Fused
fmt, path = sys.argv[1], sys.argv[2]
w = open(path, "rb").read()
tr = Tracker("face26")
f = Fused(make_backend("cython", tr.model, tr.params), 1000, 4096, fmt=fmt, width=304,
          height=240)
for i in range(0, len(w), 131072):
    f.feed(w[i:i + 131072])
print("tracked", f.tracked)
"""


def count(fmt: str, path: Path) -> tuple[int, int]:
    """(instructions inside Fused.feed, events tracked) of one format's words."""
    r = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
                        "--collect-atstart=no", f"--toggle-collect={FEED}", sys.executable,
                        "-c", CHILD, fmt, str(path)], capture_output=True, text=True,
                       cwd=ROOT, check=True)
    ir = int(re.search(r"Collected : (\d+)", r.stderr).group(1))
    return ir, int(re.search(r"tracked (\d+)", r.stdout).group(1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=400_000, help="events of the scene (count)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    if shutil.which("valgrind") is None:
        sys.exit("fused_instructions: valgrind not found (apt-get install valgrind)")
    from springtrack.sim.sensor import simulate_all
    ev, _ = simulate_all("face_occlusion", 5.0, seed=0)
    ev = ev[:args.events]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in FORMATS:
            enc = __import__(f"springtrack.io.{fmt}", fromlist=["encode"]).encode
            path = Path(tmp) / f"face.{fmt}"
            words = enc(ev)
            path.write_bytes(bytes(words))
            ir, n = count(fmt, path)
            rows.append((fmt, n, len(words) / len(ev), ir / n))
            print(f"{fmt}: {ir / n:.1f} instructions per event ({n} events)", flush=True)
    base = rows[0][3]
    cmd = f".venv/bin/python benchmarks/fused_instructions.py --events {args.events}"
    body = (f"\nMachine: {machine()} (callgrind's count does not depend on the load).  "
            f"Command: `{cmd}`.\n\nface26 on the first {rows[0][1]:,} events of "
            f"face_occlusion, each format's words fed in 128 KiB buffers; instructions "
            f"executed inside `Fused.feed` (decoding, tracking, 1 ms snapshots) per event:\n\n"
            "| words | bytes/event | instructions / event | more than CCam |\n|---|---:|---:|---:|\n"
            + "\n".join(f"| {f} | {b:.2f} | {i:.1f} | {i - base:+.1f} |" for f, n, b, i in rows)
            + "\n\nThe kernel's work is the same in every row, so the last column is what a "
              "format's decoding costs beyond the CCam's (whose own block decoder, "
              "`ccam_decode_plain`, is about 8 instructions per event in a callgrind profile)."
              "\n")
    print(body)
    if not args.no_write:
        write_section("Fused loop instructions", body)


if __name__ == "__main__":
    main()
