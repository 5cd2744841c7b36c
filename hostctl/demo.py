"""``make demo``: the whole chain on the simulated ATIS camera, end to end.

1. ``springtrack simulate`` writes the ground truth (and the initial face model) of the
   ``face_occlusion`` scene;
2. ``firmware-sim run --source sim:face_occlusion --pty`` streams the same scene through
   the simulated camera (a pyusb backend) into the fused decode+track loop, in real time;
3. ``hostctl`` loads the face model over the pty, records the telemetry until the firmware
   says the scene has ended, and shuts the firmware down (``hostctl shutdown``);
4. ``springtrack score`` compares the recording with the ground truth;
5. an overlay GIF and the plots (error, energy, compute load) are written.

Run ``hostctl demo [--seconds S] [--seed N] [--out DIR]`` (``make demo``).  The demo composes
the apps as separate processes: it lives in ``hostctl``, which may start ``firmware-sim``,
while the ``springtrack`` library knows neither.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

SCENE = "face_occlusion"


T0 = time.perf_counter()


def step(n: int, total: int, text: str) -> float:
    print(f"[{n}/{total}] {text}  (+{time.perf_counter() - T0:.1f} s)", flush=True)
    return time.perf_counter()


def run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if r.returncode != 0:
        sys.stderr.write(r.stdout + r.stderr)
        raise SystemExit(f"demo: `{' '.join(map(str, cmd))}` failed with exit code {r.returncode}")
    return r


def tool(name: str) -> list[str]:
    """The console script next to this interpreter (the venv's), else ``python -m``."""
    exe = Path(sys.executable).with_name(name)
    if exe.exists():
        return [str(exe)]
    mod = {"springtrack": "springtrack.cli", "firmware-sim": "firmware_sim.cli",
           "hostctl": "hostctl.cli"}[name]
    return [sys.executable, "-m", mod]


def start_firmware(seconds: float, seed: int, model: Path, out: Path):
    cmd = tool("firmware-sim") + ["run", "--source", f"sim:{SCENE}", "--seed", str(seed),
                                  "--seconds", str(seconds), "--model", str(model),
                                  "--realtime", "--pty", "--wait-start"]
    log = open(out / "firmware.log", "w")
    fw = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True, bufsize=1)
    line = fw.stdout.readline().strip()
    if not line.startswith("pty: "):
        fw.kill()
        raise SystemExit(f"demo: firmware-sim did not announce its pty (got {line!r}); "
                         f"see {out / 'firmware.log'}")
    return fw, line.split(" ", 1)[1]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--seconds", type=float, default=12.0, help="scene length, s (real time; 12)")
    ap.add_argument("--seed", type=int, default=1, help="scene and sensor seed (1)")
    ap.add_argument("--out", default="demo_out", help="output folder (default demo_out/)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="springtrack end-to-end demo on the simulated camera")
    add_arguments(ap)
    return run_demo(ap.parse_args(argv))


def run_demo(args) -> int:
    os.environ.setdefault("MPLBACKEND", "Agg")
    out = Path(args.out).resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    t_start = time.perf_counter()
    total = 6
    st = tool("springtrack")

    step(1, total, f"simulating the '{SCENE}' scene for ground truth ({args.seconds:g} s)")
    run(st + ["simulate", SCENE, "--seconds", str(args.seconds), "--seed", str(args.seed),
              "--out", str(out / "events.npy"), "--truth", str(out / "truth.csv"),
              "--model-out", str(out / "face26.toml")])

    step(2, total, "starting firmware-sim: simulated CCam ATIS (pyusb backend) -> fused "
                   "decode+track loop, host link on a pty")
    fw, pty = start_firmware(args.seconds, args.seed, out / "face26.toml", out)
    shut = False
    fw_t0 = time.perf_counter()
    print(f"      firmware host link on {pty}", flush=True)
    try:
        step(3, total, "hostctl: info, load the face26 model, start, record telemetry")
        hc = tool("hostctl") + ["--port", pty, "--timeout", "1.0"]
        info = run(hc + ["info"])
        print("      " + info.stdout.strip().replace("\n", "\n      "), flush=True)
        run(hc + ["load-model", str(out / "face26.toml")])
        run(hc + ["start"])                    # the camera streams from here on
        # record until the firmware says the scene (streamed in real time) has ended
        rec = run(hc + ["record", str(out / "track.csv"), "--seconds", str(args.seconds + 10),
                        "--until-end"])
        print("      " + rec.stdout.strip(), flush=True)
        run(hc + ["shutdown"])                 # the firmware serves the link until told
        shut = True
    finally:
        if not shut:
            fw.terminate()                     # a failed step: stop it (SIGTERM) as well
        try:
            fw_out, _ = fw.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            fw.kill()
            fw_out, _ = fw.communicate()
    fw_stats = [l for l in (fw_out or "").splitlines() if l.startswith("stats:")]
    (out / "firmware_stats.txt").write_text("\n".join(fw_stats) + "\n")

    step(4, total, "scoring the recording against the ground truth")
    score = run(st + ["score", str(out / "truth.csv"), str(out / "track.csv")]).stdout
    (out / "score.txt").write_text(score)
    err = [l for l in score.splitlines() if l.startswith("mean_error_pct=")]

    step(5, total, "rendering the overlay (GIF) and a snapshot (PNG)")
    run(st + ["render", str(out / "events.npy"), "--model", str(out / "face26.toml"),
              "--track", str(out / "track.csv"), "--truth", str(out / "truth.csv"),
              "--out", str(out / "overlay.gif"), "--every-us", "40000"])
    run(st + ["render", str(out / "events.npy"), "--model", str(out / "face26.toml"),
              "--track", str(out / "track.csv"), "--truth", str(out / "truth.csv"),
              "--out", str(out / "snapshot.png")])

    step(6, total, "plots: error over time, elastic energy, compute load")
    rate = plots(out)

    wall = time.perf_counter() - t_start
    print("\n=== springtrack demo ===")
    print(f"scene            {SCENE}, {args.seconds:g} s, seed {args.seed}")
    print(f"tracking error   {err[-1].split('=')[1] + ' % of face length' if err else 'n/a'} "
          f"(paper, real face: 5.42 %)")
    print(f"firmware         {fw_stats[-1][7:] if fw_stats else 'no stats line'}")
    scene_rate = count_rate(out)
    print(f"event rate       {scene_rate / 1e3:.0f} k events/s of scene time")
    print(f"kernel speed     {rate / 1e6:.1f} M events/s timed per 10 ms bin "
          f"(real-time factor {rate / max(scene_rate, 1):.0f}x)")
    print(f"outputs          {out}/  (overlay.gif, snapshot.png, error.png, energy.png, "
          f"load.png, track.csv, truth.csv, score.txt)")
    print(f"demo wall time   {wall:.1f} s")
    return 0


def count_rate(out: Path) -> float:
    import numpy as np
    ev = np.load(out / "events.npy", mmap_mode="r")
    span = (int(ev["t"][-1]) - int(ev["t"][0])) / 1e6 if len(ev) else 0
    return len(ev) / span if span > 0 else 0.0


def plots(out: Path) -> float:
    """Error, energy and load plots; returns the offline kernel's events/s."""
    import numpy as np
    from springtrack import Tracker
    from springtrack.metrics import read_truth_csv, score_track
    from springtrack.model import load
    from springtrack.render import plot_energies, plot_error, plot_load
    from springtrack.track import read_csv
    from springtrack.tracker import profile
    ev = np.load(out / "events.npy")
    model = load(out / "face26.toml")
    truth = read_truth_csv(out / "truth.csv")
    es = score_track(truth, read_csv(out / "track.csv"))
    plot_error(es.t_us, es.pct, out / "error.png", "Face tracking error, firmware telemetry (Fig. 20)")
    tr = Tracker(model)
    offline = tr.run(ev, sample_us=1000)
    plot_energies(offline, out / "energy.png", "Mean elastic energy (Fig. 21)")
    prof = profile(Tracker(model), ev, bin_us=10_000)
    plot_load(prof["t_us"], prof["events"], prof["proc_us"], out / "load.png",
              title="Compute per 10 ms of events, float64 kernel (Figs. 22-23)")
    return float(prof["events"].sum() / max(prof["proc_us"].sum() / 1e6, 1e-9))


if __name__ == "__main__":
    sys.exit(main())
