"""Firmware loop benchmarks; writes the "Fused decode + track" and "Firmware loop"
sections of docs/benchmarks.md.

Run: .venv/bin/python benchmarks/firmware.py [--seconds S] [--realtime-seconds S] [--realtime-runs N]
     [--busy N] [--rt-priority N] [--only realtime|fused] [--no-write]

1. fused decode+track from in-memory 128 KiB USB buffers (CCam words) for face26 on the
   face_occlusion scene, with telemetry every 1 ms and without, best of 5; beside it the
   kernel alone (``Tracker.run`` on decoded events, ``Tracker.process`` without samples)
   and the decoder alone, to show where time goes; the same per word format (CCam,
   EVT 2.0, EVT 2.1, EVT 3.0: the same events in each camera's words), and on the real
   EVT 2.0 / 3.0 recordings at their native geometry (``--only fused``: this part alone);
2. the simulated camera in real time (face_occlusion) through pyusb -> reader -> fused loop,
   --realtime-runs times in each of four conditions: the machine as found and loaded by
   --busy spinning processes, each with ordinary scheduling and with the loop's threads
   under SCHED_FIFO (``firmware-sim run --rt-priority``): dropped transfers and the
   event-to-telemetry latency as benchmarks/_latency.py defines it (the median run by p99
   is reported, every run's p99 listed);
3. overload: a noise burst at ~10x the measured fused rate for 0.2 s of event time in a
   real-time run: memory stays bounded by the buffer pool, drops are counted, tracking
   recovers after the burst.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # no BLAS threads spinning on the
                                                      # other core while we time one

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import springtrack.io as sio  # noqa: E402
from springtrack.io.ccam import encode  # noqa: E402
from springtrack.model import face26  # noqa: E402
from springtrack.tracker import Tracker, make_backend  # noqa: E402
from firmware_sim import camera as camusb  # noqa: E402
from firmware_sim._fused import Fused  # noqa: E402
from firmware_sim.faults import Faults  # noqa: E402
from firmware_sim.loop import FirmwareLoop  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402
from firmware_sim.simcam import SimBackend, SimCamera  # noqa: E402
from firmware_sim.simcam.words import ENCODERS  # noqa: E402
from firmware_sim.sources import events_source  # noqa: E402

from _latency import median_run, snapshot_latencies_ms, summarize  # noqa: E402
from _load import busy  # noqa: E402
from _report import machine, write_section  # noqa: E402
from firmware_sim import priority  # noqa: E402

TRANSFER = camusb.TRANSFER_BYTES


WORD_FORMATS = ("ccam", "evt2", "evt21", "evt3")
DATA = Path(os.environ.get("SPRINGTRACK_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
REAL = (("evt2_sample.raw", "evt2"), ("evt3_sample.raw", "evt3"))


def words_of(ev, fmt):
    return __import__(f"springtrack.io.{fmt}", fromlist=["encode"]).encode(ev)


def bench_fused(ev, backend="cython", repeats=5, fmt="ccam", words=None, model="face26"):
    """-> events/s of the fused loop on ``fmt`` words (``words``, else ``ev`` encoded) with
    telemetry every 1 ms and without, of the kernel alone (``Tracker.run`` sampling every
    1 ms, ``Tracker.process`` without) and of the decoder alone, best of ``repeats`` runs
    in the thread's CPU time (the machine may be shared); the five alternate run by run.
    Also the number of buffers."""
    words = words_of(ev, fmt) if words is None else words
    bufs = [words[i:i + TRANSFER] for i in range(0, len(words), TRANSFER)]
    tr = Tracker(model)
    geometry = dict(width=tr.model.width, height=tr.model.height)

    def fused(period):
        f = Fused(make_backend(backend, tr.model, tr.params), period, 4096, fmt=fmt,
                  **geometry)
        t0 = time.thread_time()
        for b in bufs:
            f.feed(b)
        dt = time.thread_time() - t0
        assert f.tracked == len(ev), (fmt, f.tracked, len(ev))
        return dt

    def kernel(period):
        t = Tracker(tr.model, backend=backend)
        t0 = time.thread_time()
        t.run(ev, period) if period else t.process(ev)
        return time.thread_time() - t0

    def decoder():
        d = sio.decoder(fmt, **({} if fmt == "ccam" else geometry))
        t0 = time.thread_time()
        for b in bufs:
            d.decode(b)
        return time.thread_time() - t0

    runs = {"fused": lambda: fused(1000), "fused_quiet": lambda: fused(0),
            "kernel": lambda: kernel(1000), "kernel_quiet": lambda: kernel(0),
            "decoder": decoder}
    best = dict.fromkeys(runs, float("inf"))
    for _ in range(repeats):
        for k, run in runs.items():
            best[k] = min(best[k], run())
    return {k: len(ev) / v for k, v in best.items()}, len(bufs)


def bench_formats(ev):
    """Rows (what, format, events, bytes per event, bench_fused's rates): the scene's
    events in each camera's words, then the real recordings' own words."""
    rows = []
    for fmt in WORD_FORMATS:
        w = words_of(ev, fmt)
        r, _ = bench_fused(ev, fmt=fmt, words=w)
        rows.append(("face_occlusion, face26 (304x240)", fmt, len(ev), len(w) / len(ev), r))
        print(f"  {fmt}: " + ", ".join(f"{k} {v / 1e6:.2f}" for k, v in r.items()), flush=True)
    for name, fmt in REAL:
        path = DATA / name
        if not path.is_file():
            print(f"  {name}: not found in {DATA}, skipped")
            continue
        rd = sio.open(path)
        rev = rd.read()
        with open(path, "rb") as fh:
            payload = fh.read()[rd.offset:]
        model = face26(cx=rd.width / 2, cy=rd.height / 2, scale=rd.height / 2,
                       width=rd.width, height=rd.height)
        r, _ = bench_fused(rev, fmt=fmt, words=payload, model=model)
        rows.append((f"{name}, face26 at {rd.width}x{rd.height}", fmt, len(rev),
                     len(payload) / len(rev), r))
        print(f"  {name}: " + ", ".join(f"{k} {v / 1e6:.2f}" for k, v in r.items()), flush=True)
    return rows


def fused_section(ev, seconds) -> tuple[str, float]:
    """The "Fused decode + track" section's body and the fused CCam rate (events/s)."""
    load = os.getloadavg()
    r, nbuf = bench_fused(ev)
    print("ccam: " + ", ".join(f"{k} {v / 1e6:.2f}" for k, v in r.items()), flush=True)
    print("per word format:")
    fmt_rows = bench_formats(ev)
    tr = Tracker("face26")
    tr.process(ev)
    assigned = tr.counters["events_assigned"] / max(tr.counters["events_valid"], 1)
    fx, _ = bench_fused(ev, "fixed")
    print("fixed: " + ", ".join(f"{k} {v / 1e6:.2f}" for k, v in fx.items()), flush=True)
    load1 = os.getloadavg()

    def stream(w, f):
        return f if w.startswith("face_") else f"{f} ({w.split(',')[0]})"
    target30 = ", ".join(f"{stream(w, f)} **{'met' if q['fused'] >= 30e6 else 'not met'}** "
                         f"({q['fused'] / 1e6:.1f})" for w, f, n, b, q in fmt_rows)
    m = 1e6
    body = f"""
Machine: {machine()}; load average {load[0]:.1f} / {load[1]:.1f} (1 / 5 min) when the run
started, {load1[0]:.1f} at its end (a shared machine: compare the figures of one run).
Command: `.venv/bin/python benchmarks/firmware.py --only fused --seconds {seconds:g}` (a
full run of benchmarks/firmware.py writes this section too).

From in-memory 128 KiB USB buffers, face26 on face_occlusion ({len(ev):,} events, {nbuf}
CCam buffers, {assigned:.0%} of them assigned); "telemetry" is a snapshot of every tracker
every 1 ms of event time, "quiet" none.  Best of 5 runs in the thread's CPU time, the
paths alternating run by run, M events/s:

| path | float kernel | fixed-point kernel (`--backend fixed`) |
|---|---:|---:|
| fused CCam decode + kernel (`firmware_sim._fused`), telemetry | {r['fused'] / m:.2f} | {fx['fused'] / m:.2f} |
| fused, quiet | {r['fused_quiet'] / m:.2f} | {fx['fused_quiet'] / m:.2f} |
| kernel alone on decoded events (`Tracker.run(ev, 1000)`) | {r['kernel'] / m:.2f} | {fx['kernel'] / m:.2f} |
| kernel alone, quiet (`Tracker.process`) | {r['kernel_quiet'] / m:.2f} | {fx['kernel_quiet'] / m:.2f} |
| CCam decoder alone (`springtrack.io.ccam`) | {r['decoder'] / m:.1f} | |

Target >= 25 M events/s: **{'met' if r['fused'] >= 25e6 else 'not met'}** ({r['fused'] / 25e6:.0%} of it).
The fused loop's cost beside the kernel alone is the decoding (a few ns per event) and
the telemetry (the difference of the quiet rows: a snapshot of 26 trackers every 1 ms);
the kernel's own per-event cost is the rest.  The "Kernel" section's 29 M events/s on
this scene was measured at c0e9c4e; since then the similarity frame's refits (soft weights,
up to 2 refits per spring update, 4f56eeb..8f401e5) cost the default frame about 4.2 k
instructions per spring update, +75 per event on this scene (callgrind, 300 k events:
365 -> 440 per event in the kernel's loop): `benchmarks/ab.py C0E9C4E_TREE 4C0C89B_TREE
--scene face_occlusion --rounds 15` timed 34.1 against 43.3 ns/event (29.3 against 23.1 M
events/s), and the same with `--param pull_frame=image --param cartesian_frame=image`
36.1 against 33.7 (no difference within the noise).

**Per word format**: the fused loop decodes each camera's words with its decoder's state
machine (`springtrack.io`'s `.pxd`) at the sensor's geometry; the same scene's events in
each format, then the real recordings' own bytes (face26 centred on their sensor), float
kernel:

| stream | words | events | bytes/event | fused M ev/s | fused, quiet | kernel alone | kernel, quiet | decoder alone |
|---|---|---:|---:|---:|---:|---:|---:|---:|
""" + "\n".join(f"| {w} | {f} | {n:,} | {b:.2f} | {q['fused'] / m:.2f} | {q['fused_quiet'] / m:.2f} | "
                f"{q['kernel'] / m:.2f} | {q['kernel_quiet'] / m:.2f} | {q['decoder'] / m:.1f} |"
                for w, f, n, b, q in fmt_rows) + f"""

Decoding's share is counted in instructions in "Fused loop instructions" below (the
differences of these times, a few ns per event, drown in this shared machine's noise).
On the real recordings the kernel has few events per tracker to update (a dot and an
outdoor scene far from most face trackers), hence the higher rates.  Target >= 30 M
events/s per format: {target30}.  USB 2.0 high speed carries about 13 M words/s, so the
tracker keeps up with the link when fused >= 13.
"""
    return body, r["fused"]


def wait_end(cam, eng, timeout):
    t0 = time.monotonic()
    quiet = 0
    while quiet < 3 and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
        done = cam.finished and eng.caught_up()
        quiet = quiet + 1 if done else 0
    eng.stop()


def bench_realtime(seconds, rt_priority=None):
    """One real-time run: (stats, benchmarks/_latency.py's per-snapshot latencies in ms,
    events tracked per second)."""
    # the scene is simulated and encoded as the camera's words beforehand: neither the
    # simulator nor the encoding is real-time work of a camera (a real one's words come
    # from its hardware), and a late device would be charged to the loop's latency
    sys.setswitchinterval(0.0005)
    ev, _ = simulate_all("face_occlusion", seconds, seed=0)
    encode = ENCODERS["ccam"]()
    chunks = [c for c in (encode(ev[i:i + 512]) for i in range(0, len(ev), 512))
              if c is not None]
    cam = SimCamera(iter(chunks), realtime=True)
    be = SimBackend(cam)
    eng = FirmwareLoop(lambda: camusb.Camera.open("ccam_atis", backend=be), "face26",
                       record=True, rt_priority=rt_priority)
    eng.start()
    wait_end(cam, eng, seconds + 30)
    s = eng.stats()
    return s, snapshot_latencies_ms(eng.recorder, cam), s["events_tracked"] / seconds


def realtime_conditions(n_busy, rt_priority):
    """[(label, busy processes, SCHED_FIFO priority or None)], the refused ones noted."""
    scheds = [("ordinary scheduling", None)]
    refused = None
    if rt_priority:
        try:
            scheds.append((f"SCHED_FIFO {rt_priority} (`--rt-priority {rt_priority}`)",
                           priority.check(rt_priority)))
        except OSError as e:
            refused = str(e)
    loads = [("as found", 0)] + ([(f"+ {n_busy} busy processes", n_busy)] if n_busy else [])
    return [(f"{lo}, {sc}", nb, pr) for lo, nb in loads for sc, pr in scheds], refused


def bench_realtime_conditions(args):
    """{label: (runs' Latency list, median run's stats, load average at start, tracked,
    dropped, rate)} over realtime_conditions()."""
    conds, refused = realtime_conditions(args.busy, args.rt_priority)
    if refused:
        print(f"SCHED_FIFO rows skipped: {refused}")
    out = {}
    for label, nb, pr in conds:
        with busy(nb):
            runs = []
            for r in range(args.realtime_runs):
                s, lat, rate = bench_realtime(args.realtime_seconds, pr)
                runs.append((summarize(lat), s))
                print(f"{label}, run {r + 1}: {s['events_tracked']} events ({rate / 1e3:.0f} k ev/s), "
                      f"dropped {s['transfers_dropped']}, latency {runs[-1][0]}; "
                      f"{s['transfers']} transfers, load {os.getloadavg()[0]:.1f}", flush=True)
            load = os.getloadavg()[0]          # the last minute of the condition's runs
        mid = median_run([lt for lt, _ in runs])
        stats = next(st for lt, st in runs if lt is mid)
        out[label] = ([lt for lt, _ in runs], mid, stats, load,
                      sum(st["events_tracked"] for _, st in runs),
                      sum(st["transfers_dropped"] for _, st in runs), rate)
    return out, refused


def rss_mb() -> float:
    """Current resident set size of this process (Linux /proc), MB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def bench_overload(ev, fused_rate):
    sys.setswitchinterval(0.0005)
    import threading
    rss0 = rss_mb()
    peak = [rss0]
    done = threading.Event()

    def sample():
        while not done.wait(0.005):
            peak[0] = max(peak[0], rss_mb())
    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    rate = 10 * fused_rate
    faults = Faults(["burst"], burst_at_us=500_000, burst_us=200_000, burst_rate=rate)
    cam = SimCamera(events_source(ev, 2048), realtime=True, faults=faults)
    be = SimBackend(cam)
    eng = FirmwareLoop(lambda: camusb.Camera.open("ccam_atis", backend=be), "face26",
                       record=True)
    eng.start()
    wait_end(cam, eng, 120)
    s = eng.stats()
    done.set()
    sampler.join()
    ts = np.concatenate([b.samples["t"] for b in eng.recorder.blocks])
    after = ts[ts >= 700_000]
    t_end = int(ev["t"][-1])
    inj = dict(faults.injected, device_overflow_events=cam.counts["device_overflow_events"],
               device_overflow_bytes=cam.counts["device_overflow_bytes"])
    return s, inj, rate, peak[0] - rss0, after, t_end, len(eng.reader.pool)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="scene seconds for (1) and (3)")
    ap.add_argument("--realtime-runs", type=int, default=3,
                    help="real-time runs; the median run by latency p99 is reported")
    ap.add_argument("--realtime-seconds", type=float, default=10.0, help="scene seconds per run")
    ap.add_argument("--busy", type=int, default=2,
                    help="spinning processes that make the 'loaded' real-time condition "
                         "(0: only the machine as found)")
    ap.add_argument("--rt-priority", type=int, default=10,
                    help="SCHED_FIFO priority of the real-time rows that use it (0: none)")
    ap.add_argument("--only", choices=["realtime", "fused"],
                    help="run only this part: realtime prints it (nothing written), fused "
                         "writes the \"Fused decode + track\" section unless --no-write")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    if args.realtime_runs < 1:
        ap.error(f"--realtime-runs must be >= 1 (the report needs a real-time run), "
                 f"got {args.realtime_runs}")
    if args.only == "realtime":
        bench_realtime_conditions(args)
        return
    load = os.getloadavg()
    ev, _ = simulate_all("face_occlusion", args.seconds, seed=0)
    fused_body, fused = fused_section(ev, args.seconds)
    if args.only == "fused":
        print(fused_body)
        if not args.no_write:
            write_section("Fused decode + track", fused_body)
        return
    rt, refused = bench_realtime_conditions(args)
    ov, inj, rate, drss, after, t_end, pool = bench_overload(ev[ev["t"] < 1_500_000], fused)
    print(f"overload: burst {inj['burst_events']} events at {rate / 1e6:.0f} M ev/s, dropped "
          f"{ov['transfers_dropped']} transfers ({ov['bytes_dropped'] / 1e6:.1f} MB), queue hwm "
          f"{ov['queue_hwm']}/{pool}, device overflow {inj['device_overflow_bytes'] / 1e6:.1f} MB, "
          f"max RSS +{drss:.1f} MB, snapshots after the burst "
          f"{len(after)}, last {after[-1] if len(after) else None}")
    if args.no_write:
        return
    write_section("Fused decode + track", fused_body)
    rate_k = next(iter(rt.values()))[6] / 1e3

    tracked = sum(r[4] for r in rt.values())
    drops = sum(r[5] for r in rt.values())
    loaded = {k: r for k, r in rt.items() if "busy" in k}
    target_note = ("; ".join(f"**{'met' if r[1].p99 < 1.0 else 'not met'}** with {k.split(', ', 1)[1]} "
                             f"(p99 {r[1].p99:.3f} ms)" for k, r in loaded.items())
                   or "not measured (--busy 0)")
    refused_note = (f"The SCHED_FIFO rows are missing: {refused}.  " if refused else "")
    body = f"""
Machine: {machine()}; load average {load[0]:.1f} / {load[1]:.1f} (1 / 5 min) when the run
started (a shared machine).
Command: `.venv/bin/python benchmarks/firmware.py --seconds {args.seconds:g} --realtime-seconds {args.realtime_seconds:g} --realtime-runs {args.realtime_runs} --busy {args.busy} --rt-priority {args.rt_priority}`.

**Fused decode + track**: the section of that name (written by this run too).

**Real time**, simulated camera on face_occlusion (simulated beforehand, served at the
event timestamps, {rate_k:.0f} k events/s), {args.realtime_runs} runs of {args.realtime_seconds:g} s of scene per condition
through pyusb -> reader thread -> fused loop; {tracked:,} events tracked, **{drops} dropped
transfers**.  **Event-to-telemetry latency** (benchmarks/_latency.py, the one definition): from
the wall instant a snapshot's sample time occurred on the camera's clock to the instant the
loop put the snapshot into its telemetry queue, every snapshot but the first 5 % of a run;
it includes the camera's share (the simulated USB controller ends a transfer up to 250 us
after its oldest word, as a real one does).  The median run by p99 of each condition, the
other runs' p99 beside it; "busy processes" spin on the CPU at ordinary priority
(benchmarks/_load.py) on top of whatever else runs:

| condition | load average (1 min) at its end | p50 ms | p99 ms | max ms | every run's p99 ms |
|---|---:|---:|---:|---:|---|
""" + "\n".join(f"| {label} | {r[3]:.1f} | {r[1].p50:.3f} | {r[1].p99:.3f} | {r[1].max:.3f} | "
                f"{', '.join(f'{x.p99:.3f}' for x in r[0])} |" for label, r in rt.items()) + f"""

{refused_note}Target p99 < 1 ms under load: {target_note}.  The maximum is set by
rare stalls of several ms in which the whole process pauses (this is a shared 2-core VM);
the reader, the simulated camera and the loop are Python threads of one process, so the
figures are of this simulation on this machine, not of a microcontroller.

**Overload**: a noise burst of {inj['burst_events']:,} events at {rate / 1e6:.0f} M
events/s (10x the fused rate above) for 0.2 s of event time, in a real-time run.  The
reader outruns the loop until the simulated camera's own 16 MiB FIFO overflows too
({inj['device_overflow_bytes'] / 1e6:.1f} MB lost on the device side, as a real sensor
would); the loop dropped {ov['transfers_dropped']} transfers
({ov['bytes_dropped'] / 1e6:.1f} MB) and counted them, queue
high-water mark {ov['queue_hwm']} of a fixed pool of {pool} x 128 KiB buffers (the loop's
only per-transfer memory; telemetry is a bounded queue too); the process's resident memory
peaked {drss:.1f} MB above its level before the run (sampled every 5 ms), which includes the
pool and the simulated camera generating the burst in the same process
(its 20 ms look-ahead of ~{rate * 0.02 * 4 / 1e6:.0f} MB of words plus numpy temporaries),
not the loop.  Tracking resumed after the burst ({len(after)}
snapshots after t = 0.7 s, the last at {after[-1] if len(after) else 'none'} us of a
stream ending at {t_end} us).
"""
    write_section("Firmware loop", body)


if __name__ == "__main__":
    main()
