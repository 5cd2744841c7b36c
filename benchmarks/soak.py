"""Soak: ``firmware-sim`` for ``--minutes`` (10) under mixed hostile traffic; it must stay
answerable, send nothing non-finite, and stay under a memory ceiling.  The summary
replaces the "Soak" section of docs/benchmarks.md.

    .venv/bin/python benchmarks/soak.py [--minutes 10 | --hours H] [--seed 1] [--memory-mb 512]
                                        [--no-write]

The firmware: ``firmware-sim run --source sim:face_occlusion --seconds 30 --realtime
--listen 127.0.0.1:0 --key-file K --faults timeout,odd,stall,corrupt,disconnect,burst``
(USB faults of firmware_sim/faults.py, re-armed at every replay), in its own process.
``odd`` cuts transfers inside a word; one followed by a shed transfer misaligns the
simulated word stream (docs/firmware.md, "Load shedding"): garbage words, time-high words
hours ahead, whose empty stretches the sampling rule skips (docs/algorithm.md, "Sampling").
Traffic, each in its own thread and connection(s):

* operator (127.0.0.1): START at every end of the scene (a replay), model swaps (face26,
  grid3x3, face26 at stiffness 0.5 which drove the float kernel to NaN before the spring
  bound was enforced, a 1200-character model name, broken TOML), parameter changes (valid, out of range, wrong type), RESET,
  STOP/START; takes the operator role back whenever the storm took it over;
* monitor (127.0.0.1, read-only): telemetry throughout (every snapshot checked), STATS
  every 5 s (answerability), the firmware's resident memory every 5 s;
* slow consumer (127.0.0.1): an authenticated monitor reading 2 KiB every 0.5 s through a
  4 KiB receive buffer, pinging to stay; reconnects every 60 s;
* fuzzer from 127.0.0.2 (another address, like a host on the network): garbage, mutated,
  random and hostile frames (benchmarks/fuzz_link.py) unsigned and signed with a wrong key
  - authentication failures, connections closed, the address locked out; and from
  127.0.0.1 an authenticated monitor sending signed hostile frames;
* reconnect storm from 127.0.0.3: every 10 s a burst of 40 connections, some silent, some
  HELLO only, some closed at once;
* probe (127.0.0.1): every 5 s a new connection, HELLO + STATS (up to 3 tries, 1 s apart).
"""
from __future__ import annotations

import argparse
import json
import random
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _report import machine, write_section  # noqa: E402
from fuzz_link import (MUTATING, hostile_frame, mutate, rand_bytes, random_frame,  # noqa: E402
                       valid_commands)
from hostctl import AuthFailed, Device, HostctlError, Nacked, Role  # noqa: E402
from springtrack import model as _model  # noqa: E402
from springtrack import wire  # noqa: E402
from springtrack.wire import MsgType  # noqa: E402

TITLE = "Soak"
PROGRESS = ("state", "events_tracked", "loop.snapshots", "loop.telemetry_dropped",
            "loop.nonfinite_snapshots", "loop.generation", "loop.last_t_us")
TRAFFIC = ("operator", "monitor", "slow_consumer", "fuzzer", "signed_fuzzer", "storm", "probe")
FAULTS = "timeout,odd,stall,corrupt,disconnect,burst"
SCENE_S = 30


def load_average() -> str:
    try:
        return " ".join(open("/proc/loadavg").read().split()[:3])
    except OSError:
        return "?"


def rss_mb(pid: int) -> float:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def refused(e: HostctlError) -> bool:
    """A refusal by the firmware (its address locked out after failed authentications, or
    the session refused: NACK forbidden), as opposed to a link error."""
    return isinstance(e, AuthFailed) or (isinstance(e, Nacked) and e.code == wire.Nack.FORBIDDEN)


class Soak:
    def __init__(self, args):
        self.args = args
        self.tmp = Path(tempfile.mkdtemp(prefix="soak-"))
        self.key = bytes(random.Random(args.seed).getrandbits(8) for _ in range(32)).hex().encode()
        (self.tmp / "link.key").write_bytes(self.key)
        exe = ROOT / ".venv" / "bin" / "firmware-sim"
        cmd = [str(exe) if exe.exists() else sys.executable, *([] if exe.exists() else
               ["-m", "firmware_sim.cli"]), "run", "--source", "sim:face_occlusion",
               "--seconds", str(SCENE_S), "--realtime", "--listen", "127.0.0.1:0",
               "--key-file", str(self.tmp / "link.key"), "--faults", FAULTS,
               "--seed", str(args.seed), "--stats-every", "0"]
        self.cmd = " ".join(cmd[1:] if exe.exists() else cmd)
        self.err = open(self.tmp / "firmware.err", "w")
        self.fw = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self.err, text=True,
                                   cwd=ROOT)
        line = self.fw.stdout.readline()
        if not line.startswith("listen: socket://"):
            raise SystemExit(f"firmware did not announce its listener: {line!r}")
        self.url = line.split()[1]
        self.addr = self.url.removeprefix("socket://").rsplit(":", 1)
        self.addr = (self.addr[0], int(self.addr[1]))
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.c = Counter()                 # what the soak did and saw
        self.problems: list[str] = []
        self.rss: list[float] = []         # the firmware's resident MB, every 5 s
        self.t0 = time.monotonic()
        self.rss_by_minute: dict[int, float] = {}   # minute -> highest resident MB in it
        self.last_stats: dict = {}

    def count(self, key: str, n: int = 1) -> None:
        with self.lock:
            self.c[key] += n

    def problem(self, text: str) -> None:
        with self.lock:
            if len(self.problems) < 50:
                self.problems.append(f"{time.strftime('%H:%M:%S')} {text}")

    def device(self, role=Role.OPERATOR, name="soak", **kw) -> Device:
        """A session, retried while the address is locked out or the sessions are busy."""
        for attempt in range(60):
            try:
                return Device(self.url, key=self.key, role=role, name=name, **kw)
            except HostctlError:
                self.count(f"{name}.connect_retries")
                if self.stop.wait(1.0):
                    raise
        raise HostctlError(f"{name}: could not connect for 60 s")

    def run_thread(self, name, fn):
        def body():
            while not self.stop.is_set():
                try:
                    fn()
                except HostctlError as e:      # reconnect: a takeover, a closed session
                    self.count(f"{name}.reconnects")
                    if not refused(e):
                        self.count(f"{name}.link_errors")
                    self.stop.wait(0.5)
                except Exception as e:          # noqa: BLE001 - a soak bug, not a firmware one
                    self.problem(f"{name}: {type(e).__name__}: {e}")
                    self.stop.wait(1.0)
        t = threading.Thread(target=body, name=name, daemon=True)
        t.start()
        return t

    # ---- traffic ------------------------------------------------------------------
    def operator(self):
        rng = random.Random(self.args.seed + 1)
        face, grid = _model.face26(), _model.grid3x3()
        # face26 at stiffness 0.5 (it drove the float kernel to NaN before the spring bound:
        # refused now), a name INFO cannot carry, a TOML syntax error: as text, since a
        # ShapeModel refuses to hold the first two
        nan = re.sub(r"stiffness = [0-9.e-]+", "stiffness = 0.5", face.to_toml())
        long = grid.to_toml().replace(f'name = "{grid.name}"', 'name = "' + "n" * 1200 + '"')
        # a 120 KB dotted key (tomllib's cost is quadratic in its depth: refused before it
        # parses) and hostile types (a number for the trackers, a list for a spring's end)
        deep = ".".join(["a"] * 60_000) + " = 1\n"
        types = grid.to_toml().replace('a = "r0c0"', "a = [1]", 1) + "trackers = 5\n"
        models = [("face26", face), ("grid3x3", grid), ("nan", nan), ("long_name", long),
                  ("broken", "[[trackers]]\nid = 1\n[[["), ("deep_key", deep),
                  ("hostile_types", types)]
        params = [("energy_gain", lambda: rng.uniform(0.01, 0.2)),
                  ("alpha_position", lambda: rng.uniform(0.01, 0.2)),
                  ("alpha_position", lambda: 3.0), ("sigma_max_px", lambda: 1e12),
                  ("energy_scale", lambda: "big"), ("nope", lambda: 1)]
        with self.device(name="operator") as dev:
            dev.start()
            while not self.stop.is_set():
                if dev.role != Role.OPERATOR:        # taken over by the storm: take it back
                    self.count("operator.taken_over")
                    return
                list(dev.telemetry(seconds=rng.uniform(0.5, 2.0)))
                if dev.stream_ended:
                    self.count("operator.replays")
                    dev.start()
                    continue
                k = rng.randrange(10)
                model_name = None
                try:
                    if k < 3:
                        model_name, m = rng.choice(models)
                        dev.load_model(m)
                        self.count(f"operator.model_accepted.{model_name}")
                    elif k < 8:
                        name, value = rng.choice(params)
                        dev.set(name, value())
                        self.count("operator.param.acked")
                    elif k == 8:
                        dev.reset()
                        self.count("operator.reset")
                    else:
                        dev.stop()
                        dev.start()
                        self.count("operator.stop_start")
                except Nacked as e:
                    self.count(f"operator.nack.{wire.Nack(e.code).name.lower()}")
                    if model_name is not None:
                        self.count(f"operator.model_refused.{model_name}")

    def monitor(self):
        with self.device(role=Role.MONITOR, name="monitor") as dev:
            next_stats = 0.0
            last_t = None
            seen = 0
            while not self.stop.is_set():
                for e in list(dev.errors)[seen:]:
                    self.count(f"monitor.error.{e.name(wire.Fault)}")
                seen = len(dev.errors)
                for s in dev.telemetry(seconds=0.5):
                    self.count("monitor.snapshots")
                    tr = s.trackers
                    if not (np.isfinite(tr["x"]).all() and np.isfinite(tr["y"]).all()
                            and (tr["x"] < 2048).all() and (tr["y"] < 2048).all()):
                        self.count("monitor.bad_snapshots")
                    if last_t is not None and s.t_us <= last_t:
                        self.count("monitor.time_not_increasing")
                    last_t = s.t_us
                if time.monotonic() >= next_stats:
                    next_stats = time.monotonic() + 5.0
                    try:
                        st = dev.stats()
                    except HostctlError:
                        self.count("monitor.stats_unanswered")
                        raise
                    self.count("monitor.stats_answered")
                    with self.lock:
                        self.last_stats = st
                        self.rss.append(rss_mb(self.fw.pid))
                        minute = int((time.monotonic() - self.t0) // 60)
                        self.rss_by_minute[minute] = max(self.rss[-1],
                                                         self.rss_by_minute.get(minute, 0.0))

    def slow_consumer(self):
        with self.device(role=Role.MONITOR, name="slow") as dev:
            sock = dev.port._socket
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            end = time.monotonic() + 60
            while not self.stop.is_set() and time.monotonic() < end:
                dev._keepalive()
                try:
                    sock.settimeout(0.5)
                    data = sock.recv(2048)
                except socket.timeout:
                    data = b"x"
                if not data:
                    raise HostctlError("slow consumer: closed by the firmware")
                self.count("slow.bytes", len(data))
                self.stop.wait(0.5)
        self.count("slow.sessions")

    def fuzzer(self):
        rng = random.Random(self.args.seed + 2)
        pool = valid_commands()
        wrong = wire.Signer(b"w" * 32, b"12345678")
        try:
            sock = socket.create_connection(self.addr, timeout=2, source_address=("127.0.0.2", 0))
        except OSError:
            self.count("fuzz.connect_refused")
            self.stop.wait(0.5)
            return
        self.count("fuzz.connections")
        try:
            sock.sendall(wire.encode_frame(MsgType.HELLO, 1, wire.encode_hello("fuzz")))
            for i in range(rng.randrange(20, 400)):
                k = rng.randrange(5)
                seq = rng.randrange(65536)
                frame = (rand_bytes(rng, rng.randrange(1, 80)) + b"\x00" if k == 0 else
                         mutate(rng, rng.choice(pool)) if k == 1 else
                         random_frame(rng, seq) if k == 2 else
                         hostile_frame(rng, seq) if k == 3 else
                         wire.encode_frame(MsgType.STATS, seq, signer=wrong))
                sock.sendall(frame)
                self.count("fuzz.frames")
                if i % 50 == 0:
                    sock.settimeout(0.01)
                    try:
                        if sock.recv(65536) == b"":
                            self.count("fuzz.closed_by_firmware")
                            return
                    except socket.timeout:
                        pass
        except OSError:
            self.count("fuzz.closed_by_firmware")
        finally:
            sock.close()
        self.stop.wait(0.2)

    def signed_fuzzer(self):
        """An authenticated monitor sending signed hostile frames of every type."""
        rng = random.Random(self.args.seed + 3)
        with self.device(role=Role.MONITOR, name="signed_fuzz") as dev:
            for _ in range(200):
                if self.stop.is_set():
                    return
                seq = rng.randrange(65536)
                try:
                    body = wire.decode_body(wire.cobs_decode(hostile_frame(rng, seq)[:-1]))
                except wire.WireError:
                    body = None
                if body is None or rng.random() < 0.5:
                    mtype = rng.choice(list(MsgType))
                    payload = rand_bytes(rng, rng.randrange(40))
                else:
                    mtype, payload = body.type, body.payload
                if mtype in MUTATING:          # never a valid START/STOP/RESET/SHUTDOWN
                    payload = payload or b"\x01"
                dev._write(wire.encode_frame(mtype, seq, payload, signer=dev.signer))
                self.count("signed_fuzz.frames")
                dev.poll(0.02)
            dev.ping()
            self.count("signed_fuzz.sessions")

    def storm(self):
        rng = random.Random(self.args.seed + 4)
        socks = []
        for i in range(40):
            try:
                s = socket.create_connection(self.addr, timeout=2, source_address=("127.0.0.3", 0))
            except OSError:
                self.count("storm.refused")
                continue
            self.count("storm.connections")
            k = rng.randrange(3)
            if k == 1:
                s.sendall(wire.encode_frame(MsgType.HELLO, i, wire.encode_hello(
                    "storm", role=rng.choice([Role.OPERATOR, Role.MONITOR]))))
            if k == 2:
                s.close()
            else:
                socks.append(s)
        self.stop.wait(10.0)
        for s in socks:
            s.close()

    def probe(self):
        if self.stop.wait(5.0):
            return
        for attempt in range(3):
            try:
                with Device(self.url, key=self.key, role=Role.MONITOR, name="probe",
                            timeout=0.5, retries=3) as dev:
                    dev.stats()
                self.count("probe.answered")
                if attempt:
                    self.count("probe.answered_after_retry")
                return
            except HostctlError:
                self.stop.wait(1.0)
        self.count("probe.unanswered")
        self.problem("probe: no answer in 3 tries")

    # ---- run -----------------------------------------------------------------------------
    def run(self) -> dict:
        t0 = self.t0 = time.monotonic()
        load0 = load_average()
        threads = [self.run_thread(n, getattr(self, n)) for n in self.args.traffic.split(",")]
        end = t0 + self.args.minutes * 60
        next_print = t0 + self.args.progress_s
        while time.monotonic() < end and self.fw.poll() is None:
            time.sleep(1.0)
            if time.monotonic() >= next_print:
                next_print += self.args.progress_s
                st = {k: self.last_stats.get(k) for k in PROGRESS}
                print(f"{(time.monotonic() - t0) / 60:.1f} min, rss {self.rss[-1:]} MB, "
                      f"firmware {st}: {dict(self.c)}", file=sys.stderr, flush=True)
        alive = self.fw.poll() is None
        self.stop.set()
        for t in threads:
            t.join(15)
        final = {}
        if alive:
            with Device(self.url, key=self.key, timeout=1.0) as dev:
                final = dev.stats()
                dev.shutdown()
            (self.tmp / "final_stats.json").write_text(json.dumps(final, indent=1, default=str))
            self.fw.wait(30)
        else:
            self.problem(f"the firmware exited during the soak (status {self.fw.returncode})")
        self.err.close()
        err = (self.tmp / "firmware.err").read_text()
        return dict(wall=time.monotonic() - t0, load0=load0, load1=load_average(),
                    alive=alive, exit=self.fw.returncode, final=final, err=err,
                    shutdown=[l for l in err.splitlines() if l.startswith("shutdown:")])


def report(soak: Soak, r: dict, ceiling: float) -> tuple[str, bool]:
    c, st = soak.c, r["final"]
    rss_max = max(soak.rss or [0.0])
    ok_finite = (c["monitor.bad_snapshots"] == 0 and st.get("link.telemetry_errors", 1) == 0)
    ok_answer = (r["alive"] and c["monitor.stats_unanswered"] == 0
                 and c["probe.unanswered"] == 0 and c["monitor.stats_answered"] > 0)
    ok_mem = rss_max <= ceiling
    shown, zero, unexplained = counters(st)
    for k in unexplained:
        soak.problem(f"STATS counter `{k}` = {st[k]} is not explained (soak.py COUNTERS)")
    for k in (k for k in MUST_BE_ZERO if st.get(k)):
        soak.problem(f"STATS counter `{k}` = {st[k]}: must be 0")
    for name in ("nan", "long_name", "broken", "deep_key", "hostile_types"):
        if c[f"operator.model_accepted.{name}"]:
            soak.problem(f"the hostile model `{name}` was accepted")
    if c["monitor.time_not_increasing"]:
        soak.problem(f"{c['monitor.time_not_increasing']} snapshots did not advance in time")
    for k in (k for k in c if explain(TRAFFIC_MEANING, k) is None):
        soak.problem(f"soak count `{k}` is not explained (benchmarks/soak.py TRAFFIC_MEANING)")
    ok = ok_finite and ok_answer and ok_mem and r["exit"] == 0 and not soak.problems
    g = st.get
    lines = [
        f"Machine: {machine()}.  Command: `.venv/bin/python benchmarks/soak.py "
        + (f"--hours {soak.args.hours:g}" if soak.args.hours is not None
           else f"--minutes {soak.args.minutes:g}")
        + f" --seed {soak.args.seed} --memory-mb {ceiling:g}"
        f"{'' if soak.args.traffic == ','.join(TRAFFIC) else ' --traffic ' + soak.args.traffic}` "
        f"({time.strftime('%Y-%m-%d')}), {r['wall'] / 60:.1f} min wall; firmware `{soak.cmd}`. "
        f"Load average at start {r['load0']}, at end {r['load1']} (a shared 2-core machine: "
        f"other work ran meanwhile).", "",
        f"**Result: {'PASS' if ok else 'FAIL'}** - answerable: "
        f"{'yes' if ok_answer else 'NO'} ({c['monitor.stats_answered']} STATS of the monitor "
        f"answered, {c['monitor.stats_unanswered']} not; {c['probe.answered']} probes answered "
        f"({c['probe.answered_after_retry']} after a retry), {c['probe.unanswered']} not); "
        f"finite: {'yes' if ok_finite else 'NO'} ({c['monitor.snapshots']} snapshots checked by "
        f"the monitor, {c['monitor.bad_snapshots']} bad; "
        f"{g('loop.nonfinite_snapshots', '?')} non-finite snapshots dropped in the firmware, "
        f"{g('link.telemetry_errors', '?')} encode failures); memory: "
        f"{'yes' if ok_mem else 'NO'} (resident {min(soak.rss or [0]):.0f} .. {rss_max:.0f} MB, "
        f"ceiling {ceiling:g} MB; the highest of each minute: "
        f"{', '.join(f'{v:.0f}' for _, v in sorted(soak.rss_by_minute.items()))} MB); "
        f"exit status after SHUTDOWN {r['exit']} "
        f"({'; '.join(r['shutdown']) or 'no shutdown line'}).", "",
        "What the soak did (its own counts):", "",
        "| traffic | count | meaning |", "|---|---:|---|",
        *(f"| {k} | {v} | {explain(TRAFFIC_MEANING, k)} |" for k, v in sorted(c.items())), "",
        f"The firmware's counters at the end (STATS after {r['wall'] / 60:.1f} min): every one "
        f"that is not zero, and those that must be zero; `last_error`: "
        f"{str(g('last_error', '')).replace('|', '/') or 'none'}.", "",
        "| counter | value | meaning |", "|---|---:|---|",
        *(f"| `{k}` | {g(k)} | {explain(COUNTERS, k)} |" for k in shown), "",
        f"Zero: {', '.join(f'`{k}`' for k in zero)}.", "",
    ]
    if soak.problems:
        lines += ["Problems:", "", *(f"* {p}" for p in soak.problems), ""]
    return "\n".join(lines), ok


def explain(table: dict, key: str) -> str | None:
    """The meaning of ``key``: its own entry, else that of a listed suffix (``.reconnects``
    for every traffic thread), else that of its longest listed prefix (``operator.nack.``
    covers every NACK code)."""
    if key in table:
        return table[key]
    suffix = next((x for x in table if x.startswith(".") and key.endswith(x)), None)
    if suffix is not None:
        return table[suffix]
    prefixes = [p for p in table if p.endswith(".") or p.endswith("_")]
    best = max((p for p in prefixes if key.startswith(p)), key=len, default=None)
    return None if best is None else f"{table[best]}: {key[len(best):]}"


def counters(st: dict) -> tuple[list, list, list]:
    """The firmware's STATS split into counters shown (not zero, or must be zero), zero
    ones, and counters nothing explains (a soak failure: every counter must be explained)."""
    shown, zero, unexplained = [], [], []
    for k, v in st.items():
        if k in FIGURES or k.startswith("session.") or k.startswith("proc_us_per_10ms."):
            continue
        if explain(COUNTERS, k) is None:
            unexplained.append(k)
        elif v or k in MUST_BE_ZERO:
            shown.append(k)
        else:
            zero.append(k)
    return shown, zero, unexplained


# values of STATS that are not counters (described in docs/firmware.md, "Statistics")
FIGURES = {"state", "last_error", "queue_depth", "event_rate", "decode.format",
           "decode.width", "decode.height", "decode.pending_bytes", "geometry_drops.fraction",
           "loop.proc_ns", "loop.generation", "loop.last_t_us", "kernel.backend",
           "link.sessions", "link.operator"}
MUST_BE_ZERO = ("loop.updates_failed", "loop.processing_errors", "supervisor.faults",
                "supervisor.threads_stopped", "link.handler_errors", "link.telemetry_errors",
                "link.session_faults")

TRAFFIC_MEANING = {
    "fuzz.connections": "connections of the fuzzer (127.0.0.2, wrong key)",
    "fuzz.connect_refused": "fuzzer connections refused by the operating system",
    "fuzz.frames": "garbage, mutated, random, hostile and wrongly signed frames it sent",
    "fuzz.closed_by_firmware": "fuzzer connections the firmware closed (8 failed "
                               "authentications, pending timeout, address locked out)",
    "signed_fuzz.frames": "signed hostile frames of an authenticated monitor",
    "signed_fuzz.sessions": "its sessions that still answered a ping after 200 of them",
    "storm.connections": "reconnect-storm connections (127.0.0.3; silent, HELLO only, closed)",
    "storm.refused": "storm connections refused by the operating system",
    "slow.bytes": "bytes the slow consumer read",
    "slow.sessions": "its 60 s sessions that ended normally",
    "monitor.snapshots": "snapshots the monitor checked (finite, on the sensor, time increasing)",
    "monitor.bad_snapshots": "snapshots with a non-finite or off-sensor value (must be 0)",
    "monitor.time_not_increasing": "snapshots whose time did not increase (must be 0)",
    "monitor.stats_answered": "STATS the monitor asked every 5 s and got",
    "monitor.stats_unanswered": "STATS without an answer (must be 0)",
    "monitor.error.": "ERROR frames the monitor received (its last 200 kept), by code",
    "probe.answered": "new connections (every 5 s) whose HELLO + STATS were answered",
    "probe.answered_after_retry": "of those, answered only on the 2nd or 3rd try",
    "probe.unanswered": "probes never answered (must be 0)",
    "operator.model_accepted.": "models the operator uploaded and the firmware accepted, by model",
    "operator.nack.": "operator commands NACKed (hostile on purpose), by code",
    "operator.model_refused.": "models the operator uploaded and the firmware refused, by model",
    "operator.param.acked": "parameter changes ACKed",
    "operator.reset": "RESETs",
    "operator.stop_start": "STOP then START",
    "operator.replays": "STARTs after NOTICE stream_ended (the scene replayed)",
    "operator.taken_over": "times another session took the operator role (then taken back)",
    ".connect_retries": "connection attempts retried (address locked out, sessions busy)",
    ".reconnects": "sessions of this traffic that ended (a takeover, closed by the "
                   "firmware) and were opened again",
    ".link_errors": "of those, ended by a link error (no answer, closed) rather than a "
                    "refusal",
}

COUNTERS = {
    "transfers": "USB transfers read",
    "bytes": "bytes read from the camera",
    "transfers_dropped": "USB transfers shed because the pool was full (the burst fault)",
    "bytes_dropped": "their bytes",
    "events_decoded": "events decoded over every replay",
    "events_tracked": "events the kernel tracked over every replay",
    "queue_hwm": "most transfers ever waiting for the loop (bounded by the pool, --buffers)",
    "usb.timeouts": "bulk reads that timed out (injected every 7th read, and idle reads)",
    "usb.stalls": "endpoint stalls cleared (one per replay)",
    "usb.disconnects": "simulated unplugs (one per replay)",
    "usb.reconnects": "reconnections after them",
    "usb.open_failures": "attempts to reopen the camera while it was unplugged",
    "usb.short_transfers": "transfers shorter than the buffer (the odd fault, the scene's "
                           "quiet stretches)",
    "usb.odd_transfers": "transfers cut inside a word (the odd fault)",
    "usb.commands": "vendor control requests (biases)",
    "usb.command_errors": "vendor control requests that failed",
    "usb.coalesced": "short transfers merged into the buffer before them",
    "decode.words": "words decoded",
    "decode.time_high_words": "time-high words",
    "decode.time_wraps": "time-counter wraps (none in a 30 s scene but from misread words)",
    "decode.exposure_events": "exposure-measurement words (this camera sends none: misread "
                              "words)",
    "decode.gaps": "gaps marked (shed transfers, reconnects, replays): a new time base",
    "decode.triggers": "trigger events",
    "decode.other_words": "other word types",
    "decode.time_low_backwards": "time-low words going back within a time-high",
    "decode.outside_roi": "events outside the region of interest",
    "geometry_drops.events": "events outside the sensor, dropped (the corrupt fault)",
    "geometry_drops.in_words": "of those, decoded from words",
    "geometry_drops.before_encoding": "of those, dropped by the simulated sensor",
    "anomalies.unknown_type": "words of an undefined type (the corrupt fault; misread words), "
                              "counted and skipped",
    "anomalies.out_of_geometry": "corrupt words outside the sensor, counted and skipped",
    "anomalies.time_backwards": "time going back (each replay restarts the clock; corrupt "
                                "time words), rebased",
    "anomalies.orphan": "events before any time base",
    "anomalies.before_time_high": "events before the first time-high word",
    "anomalies.skipped_after_gap": "events discarded while waiting for a time base after a gap",
    "anomalies.tracker_back_in_time": "events older than the tracker's last, refused",
    "anomalies.tracker_outside_sensor": "events outside the model's sensor, refused",
    "anomalies.replay_file": "anomalies of the decoder that read a replayed file (none here: "
                             "a simulated scene)",
    "loop.pieces": "pieces of transfers handed to the kernel",
    "loop.snapshots": "telemetry snapshots taken (1 kHz of event time; a jump in time is "
                      "sampled for HOLD periods and at its end)",
    "loop.updates_applied": "model, parameter and reset updates put in effect",
    "loop.updates_rejected": "updates refused with a NACK (bad models, parameters)",
    "loop.updates_failed": "accepted updates the kernel refused when applied (must be 0)",
    "loop.kernel_swaps": "models swapped in (double buffer)",
    "loop.processing_errors": "transfers whose processing raised (must be 0)",
    "loop.bytes_abandoned": "bytes of a transfer abandoned by a STOP in its middle",
    "loop.nonfinite_snapshots": "snapshots of a non-finite state, dropped (none expected: "
                                "validation refuses such models, the state guard resets)",
    "loop.nonfinite_resets": "trackers reset to the model because of them (once per generation)",
    "loop.watchdog_stalls": "stalls the watchdog saw (transfers waiting, nothing processed)",
    "loop.samples_skipped": "sample times of empty stretches not written (at most 5 samples per "
                            "event; the misaligned streams' time-high words hours ahead)",
    "loop.telemetry_dropped": "snapshots the engine's queue dropped (hosts behind)",
    "kernel.events_valid": "events the kernel accepted",
    "kernel.events_assigned": "events assigned to a tracker (eq. 3's update)",
    "kernel.skipped_back_in_time": "events older than the kernel's clock (replay restarts, "
                                   "corrupt time words), skipped",
    "kernel.skipped_outside_sensor": "events outside the model's sensor, skipped",
    "kernel.spring_updates": "spring updates (eqs. 7-20)",
    "kernel.state_resets": "tracker states reset by the kernels' state guard (a mean outside "
                           "the position box after a spring update)",
    "kernel.index_updates": "updates of the spatial index",
    "supervisor.faults": "unexpected exceptions caught in firmware threads (must be 0)",
    "supervisor.faults_": "of those, in the thread",
    "supervisor.restarts": "threads restarted after them",
    "supervisor.threads_stopped": "threads stopped after failing too often (must be 0)",
    "supervisor.reported_": "ERROR frames sent, by code",
    "link.rx_frames": "frames received from every host",
    "link.rx_lost": "frames missing by sequence number (gaps of at most 256: more is a jump)",
    "link.rx_seq_jumps": "sequence numbers that jumped ahead by more than 256 (the fuzzers' "
                         "random sequence numbers), not counted as lost",
    "link.uploads_validated": "model uploads validated off the link's thread",
    "link.uploads_over_budget": "uploads whose validation overran its time budget, refused "
                                "busy (must be 0 for legal uploads)",
    "link.uploads_busy": "uploads refused busy while another was being validated",
    "link.rx_retries": "repeated frames answered from the reply cache",
    "link.rx_bytes": "bytes received",
    "link.rx_crc_errors": "frames with a bad CRC dropped",
    "link.rx_cobs_errors": "frames with bad COBS dropped",
    "link.rx_malformed": "frames too short or inconsistent, dropped",
    "link.rx_oversize": "frames over the size limit, dropped",
    "link.version_refused": "frames of another protocol version, NACKed",
    "link.acks": "ACKs sent",
    "link.nacks": "NACKs sent (every refused command)",
    "link.handler_errors": "exceptions inside command handlers, NACKed internal (must be 0)",
    "link.forbidden": "operator commands from monitors, NACKed forbidden",
    "link.tx_frames": "frames sent",
    "link.tx_bytes": "bytes sent",
    "link.tx_dropped": "frames not sent to a host that did not read (the slow consumer)",
    "link.telemetry_sent": "TELEMETRY frames sent (over every session)",
    "link.telemetry_stale": "snapshots queued while no session had a role, discarded",
    "link.tx_stale_bytes": "bytes queued for a previous host, discarded at a new HELLO",
    "link.energies_sent": "ENERGIES frames sent (10 Hz of event time)",
    "link.sessions_opened": "TCP connections accepted into a session slot",
    "link.sessions_closed": "connections closed (every reason)",
    "link.sessions_refused": "connections refused: every session slot held by authenticated hosts",
    "link.sessions_evicted": "sessions closed to let an operator in",
    "link.pending_timeouts": "connections closed or evicted without an authenticated HELLO",
    "link.idle_timeouts": "sessions closed after 30 s without a frame",
    "link.operator_takeovers": "HELLOs as operator that took the role from another session",
    "link.auth_unsigned": "unsigned frames dropped on the keyed link (lifetime)",
    "link.auth_bad_tag": "frames with a wrong signature dropped (lifetime)",
    "link.auth_replay": "replayed frames dropped (lifetime)",
    "link.auth_disconnects": "connections closed after 8 failed authentications",
    "link.auth_lockouts": "connections from a locked-out address, admitted on probation (closed "
                          "at their first failed authentication)",
    "link.telemetry_errors": "snapshots that could not be encoded (must be 0)",
    "link.session_faults": "sessions closed because their handling raised (must be 0)",
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--hours", type=float, default=None, help="the soak's length in hours "
                                                              "(instead of --minutes)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--memory-mb", type=float, default=512.0,
                    help="resident memory ceiling of the firmware process (MB)")
    ap.add_argument("--traffic", default=",".join(TRAFFIC),
                    help=f"comma-separated subset of {','.join(TRAFFIC)} (default: all)")
    ap.add_argument("--progress-s", type=float, default=60.0,
                    help="a progress line on stderr every S seconds (60)")
    ap.add_argument("--no-write", action="store_true", help="print, do not update the docs")
    args = ap.parse_args(argv)
    if args.hours is not None:
        args.minutes = args.hours * 60
    soak = Soak(args)
    try:
        r = soak.run()
    finally:
        if soak.fw.poll() is None:
            soak.fw.terminate()
            soak.fw.wait(10)
    text, ok = report(soak, r, args.memory_mb)
    print(text)
    print(f"firmware stderr: {soak.tmp / 'firmware.err'}", file=sys.stderr)
    if not args.no_write:
        write_section(TITLE, text)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
