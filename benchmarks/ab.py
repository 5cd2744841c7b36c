"""A/B kernel timing: the same events through two builds of springtrack, interleaved.

Run: .venv/bin/python benchmarks/ab.py OLD_TREE NEW_TREE [--preset face26] [--backend cython]
     [--events 2000000] [--rounds 5]

Each tree is a source checkout with its extensions built in place (for example a
`git worktree add /tmp/base HEAD~3` built with `python setup.py build_ext --inplace`).
Every round runs each tree once, in its own process, best of 3 in the thread's CPU time, so
both trees see the same machine state: this VM's speed drifts by tens of percent within
minutes, so runs minutes apart are not comparable, interleaved runs are.  Prints best and
median ns/event per tree.  For changes of a few percent, count instructions instead
(valgrind --tool=callgrind; see docs/benchmarks.md, "Kernel instruction counts").
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

RUN = r'''
import sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
import springtrack
ev = np.load(sys.argv[2])
best = float("inf")
for _ in range(3):
    tr = springtrack.Tracker(sys.argv[3], backend=sys.argv[4])
    c0 = time.thread_time()
    tr.process(ev)
    best = min(best, time.thread_time() - c0)
print(best / len(ev) * 1e9)
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs=2, help="two source trees with built extensions")
    ap.add_argument("--preset", default="face26")
    ap.add_argument("--backend", default="cython")
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import numpy as np
    import springtrack
    from springtrack.synthetic import blob_stream
    from kernel import SCENES
    noise, motion = SCENES[args.preset]
    ev, _ = blob_stream(springtrack.load_model(args.preset), args.events, rate_hz=300_000,
                        noise=noise, seed=1, **motion)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    times = {t: [] for t in args.trees}
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "events.npy")
        np.save(path, ev)
        for r in range(args.rounds):
            for tree in args.trees:
                out = subprocess.run([sys.executable, "-c", RUN, tree, path, args.preset,
                                      args.backend], capture_output=True, text=True, env=env)
                if out.returncode != 0:
                    sys.exit(f"{tree}: {out.stderr.strip().splitlines()[-1]}")
                times[tree].append(float(out.stdout))
            print(f"round {r + 1}/{args.rounds}", file=sys.stderr)
    for tree, v in times.items():
        print(f"{tree}: {args.preset} {args.backend}, {len(ev):,} events: "
              f"best {min(v):.1f} ns/event, median {statistics.median(v):.1f}")


if __name__ == "__main__":
    main()
