"""A/B kernel timing: the same events through two builds of springtrack, interleaved.

Run: .venv/bin/python benchmarks/ab.py OLD_TREE NEW_TREE [--preset face26] [--backend cython]
     [--scene face_occlusion] [--events 2000000] [--rounds 5] [--paired [--pairs 30]]
     [--param NAME=VALUE ...]

Each tree is a source checkout with its extensions built in place (for example a
`git worktree add /tmp/base HEAD~3` built with `python setup.py build_ext --inplace`).
Every round runs each tree once, in its own process, best of 3 in the thread's CPU time, so
both trees see the same machine state: this VM's speed drifts by tens of percent within
minutes, so runs minutes apart are not comparable, interleaved runs are.  Prints best and
median ns/event per tree.  --param sets a tracker parameter for both trees, --param-new for
NEW_TREE only (what a parameter costs: a tree without the option against one with it).

--paired is finer: one process imports OLD_TREE's springtrack and loads NEW_TREE's kernel
extension beside it, then times the two kernels on the same events alternately (pairs of
runs a fraction of a second apart, the order swapped every pair) and reports the median of
the per-pair time ratios NEW/OLD with its quartiles.  Two copies of one build measure
1.00 +- 0.03 (quartiles) this way on this VM, where the process mode's best times differ
by up to 8 %.  It needs the trees to differ only inside the kernel extension (the modules
it cimports, _stepper and _samples, come from OLD_TREE).  For changes of a few percent,
count instructions too (valgrind --tool=callgrind; see docs/benchmarks.md, "Kernel
instruction counts").
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _params import parse_params  # noqa: E402

RUN = r'''
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
import springtrack
ev = np.load(sys.argv[2])
params = json.loads(sys.argv[5])
best = float("inf")
for _ in range(3):
    tr = springtrack.Tracker(sys.argv[3], params or None, backend=sys.argv[4])
    c0 = time.thread_time()
    tr.process(ev)
    best = min(best, time.thread_time() - c0)
print(best / len(ev) * 1e9)
'''

PAIRED = r'''
import glob, importlib.util, json, statistics, sys, time
import numpy as np
old, new, path, preset, module, cls, pairs, events, pa, pb = sys.argv[1:11]
sys.path.insert(0, old)
import springtrack
ka = importlib.import_module("springtrack." + module)
so = glob.glob(f"{new}/springtrack/{module}.cpython*.so")
if not so:
    sys.exit(f"{new}: no built springtrack/{module} extension")
spec = importlib.util.spec_from_file_location("springtrack." + module, so[0])
kb = importlib.util.module_from_spec(spec)
spec.loader.exec_module(kb)
ev = np.ascontiguousarray(np.load(path)[:int(events)])
model = springtrack.load_model(preset)
params = {ka: springtrack.Tracker(model, json.loads(pa) or None).params,
          kb: springtrack.Tracker(model, json.loads(pb) or None).params}
ta, tb = [], []
for r in range(int(pairs)):
    order = ((ka, ta), (kb, tb)) if r % 2 == 0 else ((kb, tb), (ka, ta))
    for mod, out in order:
        k = getattr(mod, cls)(model, params[mod])
        c0 = time.thread_time()
        k.run(ev, 0, 0, 0)
        out.append((time.thread_time() - c0) / len(ev) * 1e9)
ratios = sorted(b / a for a, b in zip(ta, tb))
q = lambda v, f: v[int(f * (len(v) - 1))]
print(f"{statistics.median(ta):.2f} {statistics.median(tb):.2f} {min(ta):.2f} {min(tb):.2f} "
      f"{statistics.median(ratios):.4f} {q(ratios, 0.25):.4f} {q(ratios, 0.75):.4f}")
'''

KERNEL_CLASSES = {"cython": ("_kernel", "Kernel"), "fixed": ("_fixed", "FixedKernel")}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs=2, help="two source trees with built extensions")
    ap.add_argument("--preset", default="face26")
    ap.add_argument("--scene", default=None,
                    help="a firmware_sim scene (e.g. face_occlusion, 5 s) instead of the "
                         "preset's blob_stream of benchmarks/kernel.py")
    ap.add_argument("--backend", default="cython")
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--paired", action="store_true",
                    help="one process, the two kernels alternately (see above)")
    ap.add_argument("--pairs", type=int, default=30, help="pairs of runs with --paired")
    ap.add_argument("--pair-events", type=int, default=500_000,
                    help="events per run with --paired (the first of --events)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="a tracker parameter for both trees (repeatable)")
    ap.add_argument("--param-new", action="append", default=[], metavar="NAME=VALUE",
                    help="a tracker parameter for NEW_TREE only (repeatable)")
    args = ap.parse_args()
    both = parse_params(args.param)
    params = [both, {**both, **parse_params(args.param_new)}]      # OLD_TREE, NEW_TREE
    if args.paired and args.backend not in KERNEL_CLASSES:
        ap.error(f"--paired supports --backend {' or '.join(KERNEL_CLASSES)}")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import numpy as np
    import springtrack
    from springtrack.sim.synthetic import blob_stream
    from _streams import SCENES
    if args.scene:
        from springtrack.sim.sensor import simulate_all
        ev, _ = simulate_all(args.scene, 5.0, seed=0)
        ev = ev[:args.events]
    else:
        noise, motion = SCENES[args.preset]
        ev, _ = blob_stream(springtrack.load_model(args.preset), args.events, rate_hz=300_000,
                            noise=noise, seed=1, **motion)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    times = {t: [] for t in args.trees}
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "events.npy")
        np.save(path, ev)
        if args.paired:
            paired(args, path, env, params)
            return
        for r in range(args.rounds):
            for tree, prm in zip(args.trees, params):
                out = subprocess.run([sys.executable, "-c", RUN, tree, path, args.preset,
                                      args.backend, json.dumps(prm)],
                                     capture_output=True, text=True, env=env)
                if out.returncode != 0:
                    sys.exit(f"{tree}: {out.stderr.strip().splitlines()[-1]}")
                times[tree].append(float(out.stdout))
            print(f"round {r + 1}/{args.rounds}", file=sys.stderr)
    for tree, v in times.items():
        print(f"{tree}: {args.preset} {args.backend}, {len(ev):,} events: "
              f"best {min(v):.1f} ns/event, median {statistics.median(v):.1f}")


def paired(args, path, env, params):
    module, cls = KERNEL_CLASSES[args.backend]
    out = subprocess.run([sys.executable, "-c", PAIRED, *args.trees, path, args.preset, module,
                          cls, str(args.pairs), str(args.pair_events),
                          *(json.dumps(p) for p in params)],
                         capture_output=True, text=True, env=env)
    if out.returncode != 0:
        sys.exit(f"paired run failed: {(out.stderr.strip().splitlines() or ['?'])[-1]}")
    ma, mb, ba, bb, r, q1, q3 = (float(v) for v in out.stdout.split())
    n = min(args.pair_events, args.events)
    print(f"{args.preset} {args.backend}, {args.pairs} pairs of {n:,} events, thread CPU time:")
    print(f"  {args.trees[0]}: median {ma:.1f} ns/event, best {ba:.1f}")
    print(f"  {args.trees[1]}: median {mb:.1f} ns/event, best {bb:.1f}")
    print(f"  new/old time per pair: median {r:.3f} (quartiles {q1:.3f} - {q3:.3f})")


if __name__ == "__main__":
    main()
