"""A small, real, deterministic firmware engine for the link tests (the production engine is
firmware_sim/loop.py)."""
from __future__ import annotations

import threading
import time
from collections import deque
import numpy as np
import springtrack
from firmware_sim.engine import Snapshot, UpdateRejected
from firmware_sim.supervise import Supervisor
from springtrack.sim.sensor import simulate_all
from springtrack import model as _model
from springtrack import params as _params
from springtrack import wire
from springtrack.limits import MAX_CONNECTIONS, MAX_TRACKERS
from springtrack.wire import Nack

CHUNK_US = 1000
_EVENTS = {}


def scene_events(seconds: float = 2.0):
    if seconds not in _EVENTS:
        _EVENTS[seconds] = simulate_all("face_occlusion", seconds, seed=1)
    return _EVENTS[seconds]


class SimEngine:
    def __init__(self, seconds: float = 2.0, speed: float = 1.0):
        self.events, self.truth = scene_events(seconds)
        self.speed = speed
        self.lock = threading.Lock()
        self.model = _model.face26()
        self.tracker = springtrack.Tracker(self.model)
        self.generation = 1
        self.pending_params: dict = {}
        self.pending_model = None
        self.running = False
        self.t_us = 0
        self.pos = 0
        self.telemetry: deque = deque(maxlen=4096)
        self.applied: deque = deque()
        self.counters = dict(events_tracked=0, snapshots=0, updates_applied=0, loops=0,
                             telemetry_dropped=0)
        self.supervisor = Supervisor()
        self._stop = threading.Event()
        self._thread = None

    # ---- Engine interface ------------------------------------------------------------
    def info(self) -> dict:
        with self.lock:
            return dict(firmware="test-sim-engine 1", width=self.model.width,
                        height=self.model.height, max_trackers=MAX_TRACKERS,
                        max_connections=MAX_CONNECTIONS, model=self.model.name,
                        model_hash=self.model.digest(), trackers=self.model.ids,
                        running=self.running, generation=self.generation)

    def load_model(self, toml_text: str) -> int:
        try:
            m = _model.loads(toml_text, "uploaded model")
        except _model.ModelError as e:
            raise UpdateRejected(Nack.INVALID_MODEL, str(e)) from None
        with self.lock:
            self.generation += 1
            self.pending_model = (m, self.generation)
            return self.generation

    def set_param(self, name: str, value) -> int:
        with self.lock:
            queued = {k: v for k, (v, _) in self.pending_params.items()}
            merged = {**self.tracker.params.as_dict(), **queued, name: value}
            try:
                _params.from_mapping(merged)
            except _params.ParamError as e:
                raise UpdateRejected(e.code, str(e)) from None
            self.generation += 1
            self.pending_params[name] = (value, self.generation)
            return self.generation

    def get_params(self) -> dict:
        with self.lock:
            return self.tracker.params.as_dict()

    def start(self) -> None:
        with self.lock:
            self.running = True

    def stop(self) -> None:
        with self.lock:
            self.running = False

    def reset(self) -> None:
        with self.lock:
            self.tracker = springtrack.Tracker(self.model)
            self.pos, self.t_us = 0, 0

    def stats(self) -> dict:
        with self.lock:
            return dict(self.counters, t_us=self.t_us, tracker=self.tracker.counters)

    def poll_telemetry(self, max_items: int = 64) -> list:
        out = []
        while self.telemetry and len(out) < max_items:
            out.append(self.telemetry.popleft())
        return out

    def poll_applied(self) -> list:
        out = []
        while self.applied:
            out.append(self.applied.popleft())
        return out

    def reports(self, after: int = 0) -> list:
        return self.supervisor.reports(after)

    def report_fault(self, thread: str, error: BaseException, action: str = "restarted") -> None:
        self.supervisor.fault(thread, error, max_faults=None, action=action)

    # ---- the loop ----------------------------------------------------------------------
    def step(self) -> None:
        """Apply queued updates at this chunk boundary, then track one chunk of events."""
        with self.lock:
            self._apply_pending()
            t1 = self.t_us + CHUNK_US
            end = int(np.searchsorted(self.events["t"], t1))
            if end > self.pos:
                self.tracker.process(self.events[self.pos:end])
                self.counters["events_tracked"] += end - self.pos
            self.pos, self.t_us = end, t1
            st = self.tracker.state(t1)           # activity decayed to the snapshot time
            if len(self.telemetry) == self.telemetry.maxlen:
                self.counters["telemetry_dropped"] += 1         # the oldest goes
            en = self.tracker.energies()
            self.telemetry.append(Snapshot(t1, self.generation_live, en["mean"], st,
                                           wire.quantise_trackers(st).tobytes(),
                                           (self.tracker.params.energy_kind_index,
                                            en[en["kind"]].copy())))
            self.counters["snapshots"] += 1

    def _apply_pending(self) -> None:
        gen = None
        if self.pending_model is not None:
            m, gen = self.pending_model
            self.model, self.tracker, self.pending_model = m, springtrack.Tracker(m), None
            self.pending_params = {k: v for k, v in self.pending_params.items() if v[1] > gen}
        if self.pending_params:
            self.tracker.set_params(**{k: v for k, (v, _) in self.pending_params.items()})
            gen = max([g for _, g in self.pending_params.values()] + [gen or 0])
            self.pending_params = {}
        if gen is not None:
            self.generation_live = gen
            self.applied.append((gen, self.t_us))
            self.counters["updates_applied"] += 1

    generation_live = 1

    def run(self) -> "SimEngine":
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        t0 = time.monotonic()
        while not self._stop.is_set():
            self.counters["loops"] += 1
            due = (time.monotonic() - t0) * 1e6 * self.speed
            if self.running and self.t_us + CHUNK_US <= due:   # past the scene: no events
                self.step()
            else:
                if not self.running:
                    t0 = time.monotonic() - self.t_us / 1e6 / self.speed
                time.sleep(0.0005)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2)
