"""``springtrack experiments [--quick]``: the paper's section IV experiments on the
simulated sensor, as tables and plots in ``docs/experiments.md`` and ``docs/img/``.

Experiments (paper figure -> scene, what is swept):

* Fig. 11b  grid_rot_y, Cartesian: maximum tracking angle vs stiffness alpha;
* Fig. 14   grid_pull, Cartesian, alpha = 0.001: mean error vs s (energy threshold scale);
* Table I / Fig. 15  grid_pull: minimum error over s per alpha, Cartesian vs
  Euclidean+torsional;
* Fig. 16   grid_inplane: the same;
* Figs. 20-21  face_occlusion: error over time, normalised Euclidean / torsional energy;
* Fig. 24   face_occlusion: error and computation time vs spring period;
* Figs. 14-16 in both frames of eq. (22) and the Cartesian springs, and every scene with
  the paper's per-experiment values in both.

Every tracker run is a task on dask.distributed: a ``LocalCluster`` by default, or the
scheduler at ``--scheduler ADDRESS``; the scenes are simulated once and scattered to the
workers.  Progress is printed as tasks complete.

One job per module: ``plan`` (what runs: sweep grids and cases), ``runs`` (running them
on dask), ``results`` (queries on the results), ``figures`` (drawing), ``report`` (the
markdown, section by section); this module is the command.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from .plan import PAPER, Plan
from .report import write_report
from .results import select
from .runs import run_all


def add_arguments(p):
    p.add_argument("--quick", action="store_true",
                   help="shorter scenes and coarser sweeps (a few minutes on 2 cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask scheduler address (tcp://host:8786); default: a LocalCluster")
    p.add_argument("--workers", type=int, default=2,
                   help="LocalCluster worker processes (default 2)")
    p.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    p.add_argument("--docs", default="docs",
                   help="output directory for experiments.md and img/ (default docs)")


def run(args) -> int:
    from dask.distributed import Client, LocalCluster

    plan = Plan.quick(args.seed) if args.quick else Plan(seed=args.seed)
    t0 = time.perf_counter()
    if args.scheduler:
        client, cluster, where = Client(args.scheduler), None, f"dask scheduler {args.scheduler}"
    else:
        cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client, where = Client(cluster), f"a dask LocalCluster of {args.workers} workers"
    print(f"dask: {where}", file=sys.stderr)
    try:
        results = run_all(plan, client)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    out = write_report(results, plan, Path(args.docs), args.quick, time.perf_counter() - t0, where)
    print(f"wrote {out} and {Path(args.docs) / 'img'}/*.png", file=sys.stderr)
    best = min(select(results, exp="fig14"), key=lambda r: r["mean_pct"])
    face = select(results, exp="face", s=PAPER["face_s"]) or select(results, exp="face")
    print(f"grid_pull_best_pct={best['mean_pct']:.4f} (s={best['s']:g}; paper 2.74)")
    print(f"face_pct={np.mean([r['mean_pct'] for r in face]):.4f} (s={face[0]['s']:g}, mean of "
          f"{len(face)} seeds; paper 5.42)")
    return 0
