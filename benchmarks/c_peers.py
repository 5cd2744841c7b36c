"""Tracker against hand-written C: the kernels through ``Tracker.process`` beside two C peers.

Writes the "Tracker against hand-written C" section of docs/benchmarks.md, in one run on the
face scene and the paper's scenes:

* contenders: the float kernel (``Tracker.process``, the default parameters, the similarity
  frame of eq. 22 included, one mean for both polarities as the peers: polarity_gain = 0,
  the paper's eq. 3, asked for explicitly), the fixed-point kernel (``backend="fixed"``),
  and the peers of benchmarks/ctrackers (``plain``: plain C, the spring passes vectorised by the compiler;
  ``simd``: AVX-512 intrinsics, AVX2 where the processor has no AVX-512), all on the same
  numpy structured array of packed records (t int64, x/y int16, p uint8: 13 bytes, as
  expelliarmus, tonic and numpy files hold events);
* first each peer is checked against the float kernel on each stream (the state every 1 ms
  of its first --check events, the counters at the end); then the contenders alternate
  within each of --repeat rounds, a new tracker per run, the thread's CPU time of the
  ``process`` call (best and median);
* where the time goes: ``perf stat`` where the machine has hardware counters; else
  instructions, simulated cache misses and branch mispredictions per event counted by
  callgrind (benchmarks/_counts.py) on the first --count events of two streams, the peers
  in their AVX2 builds (valgrind has no AVX-512).

    .venv/bin/python benchmarks/c_peers.py [--events 3000000] [--sim-seconds 10]
        [--repeat 7] [--check 300000] [--count 200000] [--no-write]
"""
from __future__ import annotations

import argparse
import datetime
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
from _counts import callgrind_status, counted, mark, perf_status  # noqa: E402
from _ctrackers import PACKED, CTracker, agreement, compile_command  # noqa: E402
from _report import cpu_info, machine, write_section  # noqa: E402
from _streams import SCENES  # noqa: E402
from support.fixed_bound import SIM_SCENES, sim_stream  # noqa: E402

import springtrack  # noqa: E402
from springtrack.sim.synthetic import blob_stream  # noqa: E402

# the SIMD peer needs AVX2 at least
PEERS = ("plain", "simd") if "avx2" in cpu_info()[2] else ("plain",)
FLOAT, FIXED = "float kernel (Tracker.process)", "fixed kernel (Tracker.process)"
COUNT_STREAMS = ("face26 (blob_stream)", "face_occlusion")


def packed(ev) -> np.ndarray:
    out = np.empty(len(ev), PACKED)
    for f in ("t", "x", "y", "p"):
        out[f] = ev[f]
    return out


# the peers' step: eq. (3), one mean for both polarities (no half offsets, eq. M6b)
PAPER_STEP = {"polarity_gain": 0.0}


def streams(n_events: int, sim_seconds: float):
    """(label, model, params, packed events): the face (face26 on the Kernel section's
    blob_stream, the default parameters) and the paper's scenes on the simulator (their
    models, springs and energy scale as the paper's experiments set them)."""
    noise, motion = SCENES["face26"]
    model = springtrack.load_model("face26")
    ev, _ = blob_stream(model, n_events, rate_hz=300_000, noise=noise, seed=1, **motion)
    yield "face26 (blob_stream)", model, dict(PAPER_STEP), packed(ev)
    for name in SIM_SCENES:
        model, ev, _, params = sim_stream(name, sim_seconds)
        yield name, model, {**(params or {}), **PAPER_STEP}, packed(ev)


def makers(model, params) -> dict:
    """{contender: a function making a new tracker with ``process(events)``}."""
    base = springtrack.Tracker(model, params)
    out = {FLOAT: lambda: springtrack.Tracker(base.model, base.params),
           FIXED: lambda: springtrack.Tracker(base.model, base.params, backend="fixed")}
    for kind in PEERS:
        out[f"C peer: {kind}"] = lambda kind=kind: CTracker(kind, base.model, base.params)
    return out


def timed(model, params, events, repeat):
    """{contender: [thread CPU seconds per run]}, the contenders alternating each round."""
    make = makers(model, params)
    times = {k: [] for k in make}
    names = list(make)
    for r in range(repeat):
        for name in (names if r % 2 == 0 else names[::-1]):
            tr = make[name]()
            c0 = time.thread_time()
            tr.process(events)
            times[name].append(time.thread_time() - c0)
    return times


def count_child(path: str) -> None:
    """Under callgrind (counted): each contender on the pickled streams, one mark each."""
    with open(path, "rb") as f:
        jobs = pickle.load(f)
    for label, model, params, events in jobs:
        base = springtrack.Tracker(model, params)
        for name, make in makers(model, params).items():
            if name.startswith("C peer: "):      # valgrind has no AVX-512: the AVX2 builds
                tr = CTracker(name.split(": ")[1] + "-avx2", base.model, base.params)
            else:
                tr = make()
            with mark(f"{label}|{name}"):
                tr.process(events)


def where_time_goes(jobs) -> tuple[str | None, dict]:
    """(why not, None) or (None, {(label, contender): counts per event})."""
    why = callgrind_status()
    if why:
        return why, {}
    base = springtrack.Tracker("face26")
    for kind in PEERS:
        CTracker(f"{kind}-avx2", base.model, base.params)        # built outside valgrind
    with tempfile.NamedTemporaryFile(suffix=".pkl", delete=False) as f:
        pickle.dump(jobs, f)
    try:
        raw = counted([sys.executable, __file__, "--count-child", f.name])
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as e:
        return f"callgrind failed: {e}", {}
    finally:
        os.unlink(f.name)
    n = {label: len(ev) for label, _, _, ev in jobs}
    out = {}
    for key, c in raw.items():
        label, name = key.split("|", 1)
        out[label, name] = {k: v / n[label] for k, v in c.items()}
    return None, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=3_000_000,
                    help="events of the face's blob_stream (default 3,000,000)")
    ap.add_argument("--sim-seconds", type=float, default=10.0,
                    help="seconds of each paper scene simulated (default 10 s)")
    ap.add_argument("--repeat", type=int, default=7, help="timed rounds (default 7)")
    ap.add_argument("--check", type=int, default=300_000,
                    help="events per stream the peers are checked on (default 300,000)")
    ap.add_argument("--count", type=int, default=200_000,
                    help="events per stream counted under callgrind (default 200,000; 0: none)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--count-child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.count_child:
        return count_child(args.count_child)
    load0 = os.getloadavg()
    t_start = time.perf_counter()
    checks, rows, jobs = [], [], []
    for label, model, params, ev in streams(args.events, args.sim_seconds):
        for kind in PEERS:
            a = agreement(kind, model, params, ev[:args.check])
            checks.append((label, kind, a))
            print(f"{label} {kind}: {a}", flush=True)
        times = timed(model, params, ev, args.repeat)
        rate = {k: (len(ev) / min(v), len(ev) / float(np.median(v))) for k, v in times.items()}
        for k, (best, med) in rate.items():
            rows.append((label, k, len(ev), best, med, rate))
            print(f"{label:22s} {k:32s} {best / 1e6:7.2f} M ev/s best, {med / 1e6:7.2f} median",
                  flush=True)
        if label in COUNT_STREAMS and args.count:
            jobs.append((label, model, params, ev[:args.count]))
    load1 = os.getloadavg()
    perf_why = perf_status()
    cg_why, counts = where_time_goes(jobs) if jobs else ("not asked (--count 0)", {})
    print(f"perf: {perf_why or 'available'}; callgrind: {cg_why or 'counted'}", flush=True)
    for key, c in counts.items():
        print(key, {k: round(c[k], 2) for k in ("Ir", "D1mr", "DLmr", "Bcm")}, flush=True)
    if args.no_write:
        return
    write_section("Tracker against hand-written C",
                  report(args, checks, rows, counts, perf_why, cg_why, load0, load1,
                         time.perf_counter() - t_start))


def reading(counts) -> str:
    """One sentence per counted stream: the float kernel's counts beside the plain peer's."""
    out = []
    for label in COUNT_STREAMS:
        f, p = counts.get((label, FLOAT)), counts.get((label, "C peer: plain"))
        if not (f and p):
            continue
        out.append(f"{label}: the float kernel runs {f['Ir'] / p['Ir']:.2f}x the plain peer's "
                   f"instructions, with {(f['D1mr'] + f['D1mw']) / max(p['D1mr'] + p['D1mw'], 1e-9):.1f}x "
                   f"its L1 data misses and {(f['Bcm'] + f['Bim']) / max(p['Bcm'] + p['Bim'], 1e-9):.2f}x "
                   f"its branch mispredictions.")
    return ("\n" + "  ".join(out) + "\n") if out else ""


def report(args, checks, rows, counts, perf_why, cg_why, load0, load1, seconds) -> str:
    def ratio(rate, k, peer, i):
        return rate[k][i] / rate[peer][i] if peer in rate else float("nan")

    check_rows = "\n".join(
        f"| {lab} | {kind} | {a['samples']:,} | {a['position_px']:.1e} | "
        f"{a['covariance_rel']:.1e} | {a['activity_rel']:.1e} | "
        f"{'yes' if a['counters_equal'] else 'NO'} |" for lab, kind, a in checks)
    table = "\n".join(
        f"| {lab} | {k} | {n:,} | {b / 1e6:.2f} | {m / 1e6:.2f} | "
        f"{ratio(r, k, 'C peer: simd', 0):.2f} / {ratio(r, k, 'C peer: simd', 1):.2f} | "
        f"{ratio(r, k, 'C peer: plain', 0):.2f} / {ratio(r, k, 'C peer: plain', 1):.2f} |"
        for lab, k, n, b, m, r in rows)
    fl = {lab: r for lab, k, n, b, m, r in rows if k == FLOAT}
    worst = {peer: min(min(ratio(r, FLOAT, peer, 0), ratio(r, FLOAT, peer, 1))
                       for r in fl.values()) for peer in ("C peer: simd", "C peer: plain")}
    face = fl["face26 (blob_stream)"]

    def verdict(v):
        return "not run" if np.isnan(v) else "met" if v >= 1.0 else "not met"

    cc = " ".join(compile_command("simd", Path("simd.so")))
    cc = cc.replace(str(HERE) + "/", "benchmarks/")
    base = springtrack.Tracker("face26")
    isa = CTracker("simd", base.model, base.params).isa if "simd" in PEERS else "not built"
    if counts:
        count_rows = "\n".join(
            f"| {lab} | {name} | {c['Ir']:.0f} | {c['D1mr'] + c['D1mw']:.2f} | "
            f"{c['DLmr'] + c['DLmw']:.3f} | {c['Bcm'] + c['Bim']:.2f} |"
            for (lab, name), c in counts.items())
        where = f"""{perf_why or '`perf stat` is available but not used here'}.  Instead: callgrind
(`benchmarks/_counts.py`: valgrind's instruction counts, its simulated caches and branch
predictor) around the `process` call of each contender, on the first {args.count:,} events of
each stream; valgrind has no AVX-512, so the kernels run their AVX2 clones and the peers their
AVX2 builds (`-march=x86-64-v3`).  Per event:

| stream | contender | instructions | L1 data misses | last-level misses | branch mispredictions |
|---|---|---:|---:|---:|---:|
{count_rows}
{reading(counts)}"""
    else:
        where = (f"{perf_why or '`perf stat` is available but not used here'}; callgrind: "
                 f"{cg_why}.  Where the time goes is not measured in this run.")
    return f"""
Command: `.venv/bin/python benchmarks/c_peers.py --events {args.events} --sim-seconds {args.sim_seconds:g} --repeat {args.repeat}`
({datetime.date.today().isoformat()}, {seconds / 60:.0f} min)
Machine: {machine()}; load average {load0[0]:.1f} / {load0[1]:.1f} (1 / 5 min) at the start,
{load1[0]:.1f} / {load1[1]:.1f} at the end: a shared machine (2 cores, other jobs running), so
a row's rate varies between runs by tens of percent; the contenders alternate within each
round, so the ratios of one run are what to compare.

The peers (benchmarks/ctrackers/): the float64 kernel's algorithm written in C from
`springtrack/reference.py` (eq. 2 per event with its gate and probability from one d^2,
eqs. 3-6, the springs of eqs. 10-20 and the energy criteria of eqs. 13, 21-22 every
spring_period valid events, the similarity frame of eq. 22 fitted at each update as the
default parameters have it), independently of the kernel: structure of arrays, a spatial
index of 8 x 8 px cells (a 64-bit mask of the trackers whose grown gate box covers each
cell, a tracker re-indexed only when its gate box leaves the grown one), branch-free
exp, atan2 and sincos of their own (~1 ulp).  Built by the benchmark: `{cc}` (`plain.c`
likewise); called through ctypes on the same packed array.  `plain`: eq. (2) over the
cell's candidates in a scalar loop; the spring passes as plain loops that gcc vectorises at
`-march=native`.  `simd` ({isa}): eq. (2) over all trackers, eight (AVX2: four) a block,
the cell's candidate mask as the lanes' write mask, no branch per tracker; a winner's lane
written back as a whole block (a scalar store into a block stalls the next event's block
load); the spring passes with AVX2 intrinsics (gathers, Cephes' atan2 and sincos).  The
block scan is slower than `plain`'s loop over the 1-5 candidates the index leaves: every
event's block loads wait for the previous event's store into the same block, so events no
longer overlap in the core (a variant with `plain`'s scan and the vector springs ran at
0.94x `plain` on face_occlusion).  The faster of the two is the yardstick.

Each peer tracks like the float kernel (first {args.check:,} events of each stream, the state
after all events before every 1 ms, the largest difference over all samples and trackers;
`tests/test_c_peers.py` checks them against `reference.py` to 1e-9 px):

| stream | peer | samples | position px | covariance rel. | activity rel. | counters equal |
|---|---|---:|---:|---:|---:|---|
{check_rows}

Speed: a new tracker per run, the thread's CPU time of `process(events)` on the whole
array, best and median of {args.repeat} rounds; ratios = the row's rate / the peer's
(> 1: the row is faster), best / median:

| stream | contender | events | M events/s (best) | M events/s (median) | ratio to C simd | ratio to C plain |
|---|---|---:|---:|---:|---:|---:|
{table}

Targets (float kernel through `Tracker.process`, default frame): >= 1.0x the SIMD peer on the
face: **{verdict(min(ratio(face, FLOAT, 'C peer: simd', 0), ratio(face, FLOAT, 'C peer: simd', 1)))}**
({ratio(face, FLOAT, 'C peer: simd', 0):.2f} best, {ratio(face, FLOAT, 'C peer: simd', 1):.2f} median;
goal 1.3x), on every stream: **{verdict(worst['C peer: simd'])}** (lowest {worst['C peer: simd']:.2f}).
Against the faster peer here, `plain`: face **{verdict(min(ratio(face, FLOAT, 'C peer: plain', 0), ratio(face, FLOAT, 'C peer: plain', 1)))}**
({ratio(face, FLOAT, 'C peer: plain', 0):.2f} best, {ratio(face, FLOAT, 'C peer: plain', 1):.2f} median),
every stream **{verdict(worst['C peer: plain'])}** (lowest {worst['C peer: plain']:.2f}).

**Where the time goes.**  {where}
"""


if __name__ == "__main__":
    main()
