"""What sampling costs on the API path: ``Tracker.run(events, sample_us)`` with a sample
every 100 µs, every 1 ms and none, for one face (face_occlusion, 5 s) and eight faces
(benchmarks/instances.py ``faces(8)``, 2 s, 208 trackers), on the float (``cython``) and
integer (``fixed``) kernels; writes the "Sampling cost" section of docs/benchmarks.md.

Run: .venv/bin/python benchmarks/sampling.py [--rounds R] [--baseline TREE [--baseline-label L]]
     [--no-write]

Each round runs every case once in a fresh process per tree (``--baseline``: a source
checkout with its extensions built in place, e.g. main's, timed in the same rounds,
alternating with this checkout), each case twice there; the figure is the best run over
the rounds in the process's CPU time (memory the process touches first costs page faults:
the second run of a case reuses the first's).  ns per row = the CPU time beyond the
unsampled run's, per tracker and sample taken.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))
from _report import machine, write_section  # noqa: E402

NOTE = ("Where a sampled run's time goes beyond the kernel's: each sample row (72 bytes "
        "per tracker, `TRACK_DTYPE`) is written once, by the kernel, into the buffer "
        "`Tracker.run` sized ahead for the run, the Track's fields views of it; the first "
        "touch of that memory (page faults, the pages zeroed by the OS) is a large share of "
        "the ns per row, the rest the snapshot itself (the mean predicted to the sample "
        "time, eq. M1, the activity decayed, eq. 6: 50-80 instructions per tracker in the "
        "float kernel, an integer decay per tracker in the fixed one) and, per sample, the "
        "mean energies and the event loop stopping at the sample time.  The ns per row at "
        "1 ms is a difference of a few ms, within this machine's noise.")
PERIODS = (100, 1000, 0)             # µs; 0: no samples
BACKENDS = ("cython", "fixed")

RUN = r'''
import json, pickle, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
import springtrack
ev = np.load(sys.argv[2])
with open(sys.argv[3], "rb") as f:
    models = pickle.load(f)
out = {}
for backend in sys.argv[4].split(","):
    for q in map(int, sys.argv[5].split(",")):
        for _ in range(2):
            tr = springtrack.Tracker(models, backend=backend)
            c0 = time.process_time()
            if q:
                got = tr.run(ev, q)
                rows = len(got) * len(tr.ids)
            else:
                tr.process(ev)
                rows = 0
            dt = time.process_time() - c0
            key = f"{backend} {q}"
            out[key] = [min(dt, out.get(key, [dt])[0]), rows]
print(json.dumps(out))
'''


def scenes(tmp: Path) -> list:
    """[(label, events file, models file, events)] of the two scenes."""
    from springtrack.sim.scenes import make_scene
    from springtrack.sim.sensor import simulate_all
    from instances import faces
    out = []
    for label, scene, seconds in (("1 face (face_occlusion, 5 s, 26 trackers)",
                                   make_scene("face_occlusion"), 5.0),
                                  ("8 faces (instances.py faces(8), 2 s, 208 trackers)",
                                   faces(8), 2.0)):
        ev, _ = simulate_all(scene, seconds)
        models = scene.initial_models() if hasattr(scene, "initial_models") else scene.initial_model()
        k = len(out)
        np_path, m_path = tmp / f"ev{k}.npy", tmp / f"models{k}.pkl"
        import numpy as np
        np.save(np_path, ev)
        with open(m_path, "wb") as f:
            pickle.dump(models, f)
        out.append((label, np_path, m_path, len(ev)))
    return out


def one_round(tree: Path, ev_path: Path, m_path: Path) -> dict:
    res = subprocess.run([sys.executable, "-c", RUN, str(tree), str(ev_path), str(m_path),
                          ",".join(BACKENDS), ",".join(map(str, PERIODS))],
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--baseline", type=Path, help="a built checkout timed beside this one")
    ap.add_argument("--baseline-label", default="baseline",
                    help="what the baseline is, for the table (e.g. its commit)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    trees = {"this": ROOT} | ({"baseline": args.baseline.resolve()} if args.baseline else {})
    load0 = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, ev_path, m_path, n in scenes(Path(tmp)):
            best = {name: {} for name in trees}
            for r in range(args.rounds):
                order = list(trees) if r % 2 == 0 else list(trees)[::-1]
                for name in order:
                    for key, (dt, cnt) in one_round(trees[name], ev_path, m_path).items():
                        old = best[name].get(key)
                        best[name][key] = [min(dt, old[0]) if old else dt, cnt]
            for backend in BACKENDS:
                for q in PERIODS:
                    cells = []
                    for name in trees:
                        dt, cnt = best[name][f"{backend} {q}"]
                        base = best[name][f"{backend} 0"][0]
                        per = f", {(dt - base) / cnt * 1e9:.0f} ns/row" if cnt else ""
                        cells.append(f"{n / dt / 1e6:.2f}{per}")
                    rows.append(f"| {label} | {backend} | {q or 'none'} | "
                                + " | ".join(cells) + " |")
                    print(rows[-1], flush=True)
    load1 = os.getloadavg()
    cols = " | ".join(f"{'this checkout' if t == 'this' else args.baseline_label} M ev/s (CPU)"
                      for t in trees)
    head = [f"| scene | kernel | sample_us | {cols} |",
            "|---|---|---:|" + "---:|" * len(trees)]
    cmd = (".venv/bin/python benchmarks/sampling.py --rounds "
           f"{args.rounds}" + (f" --baseline BASELINE --baseline-label '{args.baseline_label}'"
                                if args.baseline else ""))
    body = (f"Machine: {machine()}; load average {load0[0]:.1f} at the start, "
            f"{load1[0]:.1f} at the end (a shared machine).  Command: `{cmd}`.\n\n"
            "`Tracker.run(events, sample_us)` (`process` where none), best of "
            f"{args.rounds} rounds (each a fresh process per tree, each case run twice "
            "there), CPU time; ns/row is the time beyond the unsampled run per tracker "
            "and sample.\n\n" + "\n".join(head + rows) + "\n\n" + NOTE)
    print(body)
    if not args.no_write:
        write_section("Sampling cost (Tracker.run)", body)


if __name__ == "__main__":
    main()
