"""The firmware's tracking loop: USB reader thread + fused decode/track thread.

:class:`FirmwareLoop` implements ``firmware_sim.engine.Engine`` (docs/firmware.md):

* the reader thread (``firmware_sim.reader``) owns the camera and fills a buffer pool;
* the processing thread feeds each transfer, in pieces of ``piece_bytes``, to the nogil
  fused loop (``firmware_sim._fused``), which decodes CCam words and steps the kernel;
* updates (model, parameters, reset) are validated in the caller's thread, built
  completely (a new Kernel for a model), queued, and applied by the processing thread
  between two pieces, i.e. between two events; the event time of the first event
  processed under each generation is reported by :meth:`poll_applied`;
* telemetry snapshots every ``telemetry_period_us`` of event time; kept in a bounded
  queue (oldest dropped and counted) for :meth:`poll_telemetry`, and optionally all kept
  for ``--record``.
"""
from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np

from springtrack import model as _model
from springtrack import params as _params
from springtrack.limits import MAX_CONNECTIONS, MAX_TRACKERS
from springtrack.track import CSV_HEADER, Track
from springtrack.tracker import make_backend, resolve_params
from springtrack.wire import TRACK_DTYPE

from ._fused import SNAP_FIELDS, Fused
from . import usb as camusb
from .engine import UpdateRejected
from .reader import Reader

FIRMWARE = "firmware-sim 0.1 (fused CCam loop)"
# the tracker kernels a firmware can run (springtrack.tracker); "mcu" is the fixed kernel's
# microcontroller build in its emulator (slow: for correctness tests of the whole chain)
BACKENDS = ("cython", "fixed", "mcu")
TRACKER_DTYPE = TRACK_DTYPE      # per-tracker telemetry record, defined once in springtrack.wire
BIAS_PREFIX = "bias."     # camera biases are parameters "bias.<name>" on the host link
WINDOW_US = 10_000        # processing time is reported per 10 ms of events (paper Figs. 22-23)


def param_error_code(e: Exception) -> str:
    msg = str(e)
    if "unknown parameter" in msg:
        return "unknown_name"
    if "must be a number" in msg or "must be one of" in msg or "whole number" in msg:
        return "wrong_type"
    return "out_of_range"


class DecodedFeed:
    """The non-fused path for the EVT 2.0 / 3.0 profiles, with the interface of
    ``_fused.Fused``: a ``springtrack.io`` streaming decoder turns each piece into an event
    array, then ``Kernel.run`` tracks it with the same sampling rule.  One Python call per
    piece, never per event."""

    def __init__(self, kernel, period_us: int, profile):
        self.profile = profile
        self.decoder = camusb.make_decoder(profile)
        self.kernel = kernel
        self.period = int(period_us)
        self.next_t = None
        self.first_t = -1
        self.mark = False
        self.tracked = 0
        self.bytes_in = 0
        self.gaps = 0
        self.old_words = 0            # counts of decoders replaced after gaps
        self.old_events = 0

    @property
    def kernel_obj(self):
        return self.kernel

    @property
    def last_t(self):
        return self.kernel.last_t

    def set_kernel(self, kernel) -> None:
        self.kernel = kernel
        self.mark_next()

    def mark_next(self) -> None:
        self.mark = True
        self.first_t = -1

    def gap(self) -> None:
        """Data lost: restart the decoder (its time base and partial word are stale);
        events it emits before a fresh time base go back in time and the kernel skips and
        counts them."""
        st = self.decoder.stats
        self.old_words += st.words
        self.old_events += st.events
        self.decoder = camusb.make_decoder(self.profile)
        self.gaps += 1

    def feed(self, buf, n: int = -1):
        mv = memoryview(buf).cast("B")
        if n >= 0:
            mv = mv[:n]
        self.bytes_in += len(mv)
        ev = self.decoder.decode(mv)
        if len(ev) == 0:
            return None
        if self.mark:
            self.mark = False
            self.first_t = int(ev["t"][0])
        if self.next_t is None:
            t0 = int(ev["t"][0])
            self.next_t = -(-t0 // self.period) * self.period
        parts, pos = [], 0
        while pos < len(ev):
            consumed, self.next_t, out = self.kernel.run(ev[pos:], self.period, self.next_t, 512)
            pos += consumed
            if out is not None and len(out["t"]):
                parts.append(out)
        self.tracked += len(ev)
        if not parts:
            return None
        return parts[0] if len(parts) == 1 else {k: np.concatenate([q[k] for q in parts])
                                                  for k in parts[0]}

    def counters(self) -> dict:
        st = self.decoder.stats
        kc = self.kernel.counters()
        an = {k: int(v) for k, v in st.anomalies.items()}
        an.update(tracker_back_in_time=kc["skipped_back_in_time"],
                  tracker_outside_sensor=kc["skipped_outside_sensor"])
        return dict(words=self.old_words + st.words, time_high_words=st.info.get("time_high_words", 0),
                    events_decoded=self.old_events + st.events, exposure_events=0,
                    events_tracked=self.tracked, time_wraps=st.info.get("time_wraps", 0),
                    gaps=self.gaps, bytes=self.bytes_in, pending_bytes=st.pending_bytes,
                    anomalies=an)


class FirmwareLoop:
    """The Engine: ``FirmwareLoop(open_camera, model, params, ...)``; ``open_camera()``
    returns a started ``firmware_sim.usb.Camera`` (called again after a disconnect).
    ``lossless=True`` (simulated camera at max speed only) makes the reader wait instead of
    shedding; ``record=True`` keeps every snapshot for :meth:`write_record`."""

    def __init__(self, open_camera, model="face26", params=None, telemetry_period_us: int = 1000,
                 nbuf: int = 64, piece_bytes: int = 16384, telemetry_queue: int = 4096,
                 transfer_bytes: int | None = None, lossless: bool = False,
                 biases: dict | None = None, profile="ccam_atis",
                 record: bool = False, width: int | None = None, height: int | None = None,
                 backend: str = "cython", energy_period_us: int = 100_000):
        if telemetry_period_us <= 0:
            raise ValueError(f"telemetry_period_us must be positive, got {telemetry_period_us}")
        if backend.partition(":")[0] not in BACKENDS:
            raise ValueError(f"backend {backend!r}: the firmware runs one of {', '.join(BACKENDS)}")
        self.backend = backend
        self.model = _model.load_model(model)
        self.params = resolve_params(self.model, params)
        self.kernel = self._new_kernel(self.model, self.params)
        self.profile = camusb.PROFILES[profile] if isinstance(profile, str) else profile
        if self.profile.fmt == "ccam" and not backend.startswith("mcu"):
            self.fused = Fused(self.kernel, telemetry_period_us, 512)
        else:            # EVT boards, or a kernel in an emulator: springtrack.io decoder + run
            self.fused = DecodedFeed(self.kernel, telemetry_period_us, self.profile)
        self.period = int(telemetry_period_us)
        self.reader = Reader(open_camera, nbuf=nbuf, shed=not lossless,
                             **({"transfer_bytes": transfer_bytes} if transfer_bytes else {}))
        self.piece = int(piece_bytes)
        self.width = width or self.profile.width          # the sensor, for INFO
        self.height = height or self.profile.height
        # shared with open_camera (the CLI passes the same dict) so a reconnect reloads the
        # biases the host set last
        self.biases = biases if biases is not None else {}
        self.biases.update(camusb.check_biases(self.biases))
        self.lock = threading.Lock()
        self.generation = 1                 # generation in effect
        self.gen_next = 1                   # last generation handed out
        self.pending_model = None           # (model, params, kernel, generation)
        self.pending_params: dict = {}      # name -> (value, generation)
        self.tele: deque = deque()          # [generation, energy kind, block, first row, energies]
        self.tele_rows = 0
        self.tele_cap = int(telemetry_queue)
        self.applied: deque = deque()
        self._await_first = []              # generations waiting for their first event
        self.swaps: deque = deque(maxlen=1024)  # (generation, events tracked before it)
        self.record = record
        self.recorded: list = []            # (ids, block)
        self.stop_event = threading.Event()
        self.thread = None
        self.t_start = None
        self.c = dict(pieces=0, snapshots=0, telemetry_dropped=0, updates_applied=0,
                      updates_rejected=0, proc_ns=0, kernel_swaps=0, processing_errors=0)
        self.last_error = ""
        self.retired: dict = {}             # counters of the kernels swapped out
        self.energy_period_us, self.next_energy_t = int(energy_period_us), None
        self.windows: deque = deque(maxlen=4096)   # processing us per 10 ms of events
        self._win_t0 = None
        self._win_ns = 0
        self._rate = deque(maxlen=64)               # (wall, events tracked)
        self.snap_wall: deque | None = None         # (t_us, wall) when a benchmark asks

    def _new_kernel(self, model, params):
        """A tracker state for ``model`` on this firmware's backend: float64 ("cython"),
        integer-only ("fixed", docs/fixed_point.md) or that kernel's microcontroller build
        in an emulator ("mcu", docs/mcu.md)."""
        return make_backend(self.backend, model, params)

    # ---- Engine: lifecycle ---------------------------------------------------------------
    def start(self) -> None:
        if self.running:
            return
        self.stop_event.clear()
        self.t_start = time.monotonic()
        self.reader.start()
        self.thread = threading.Thread(target=self._run, name="fused-loop", daemon=True)
        self.thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self.stop_event.set()
        if self.thread is not None:
            self.thread.join(timeout)
            if self.thread.is_alive():
                raise RuntimeError(f"processing thread did not stop within {timeout} s")
            self.thread = None
        self.reader.stop(timeout)

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def drained(self) -> bool:
        return self.reader.queue_depth() == 0

    def caught_up(self) -> bool:
        """Every byte read so far has been processed: nothing queued, and the fused loop
        has consumed all read bytes but the dropped ones."""
        rc = self.reader.counts
        return self.drained() and self.fused.bytes_in == rc["bytes"] - rc["bytes_dropped"]

    def reset(self) -> None:
        """Restart the tracker from the current model (queued like a model swap)."""
        with self.lock:
            m = self.pending_model[0] if self.pending_model else self.model
            p = self.pending_model[1] if self.pending_model else self.params
            self.gen_next += 1
            self.pending_model = (m, p, self._new_kernel(m, p), self.gen_next)
        self._apply_if_idle()

    # ---- Engine: updates -------------------------------------------------------------------
    def load_model(self, toml_text: str) -> int:
        try:
            m = _model.loads(toml_text, "uploaded model")
            p = resolve_params(m)
            k = self._new_kernel(m, p)
        except (ValueError, TypeError) as e:       # ModelError, ParamError are ValueErrors
            self.c["updates_rejected"] += 1
            raise UpdateRejected("invalid_model", str(e)) from None
        with self.lock:
            self.gen_next += 1
            self.pending_model = (m, p, k, self.gen_next)
            self.pending_params = {}
            gen = self.gen_next
        self._apply_if_idle()
        return gen

    def set_param(self, name: str, value) -> int:
        if name.startswith(BIAS_PREFIX):
            return self._set_bias(name[len(BIAS_PREFIX):], value)
        with self.lock:
            base = self.pending_model[1] if self.pending_model else self.params
            merged = {k: v for k, (v, _) in self.pending_params.items()}
            merged[name] = value
            try:
                _params.from_mapping(merged, base)
            except _params.ParamError as e:
                self.c["updates_rejected"] += 1
                raise UpdateRejected(param_error_code(e), str(e)) from None
            self.gen_next += 1
            self.pending_params[name] = (_params.check(name, value), self.gen_next)
            gen = self.gen_next
        self._apply_if_idle()
        return gen

    def get_params(self) -> dict:
        with self.lock:
            out = self.params.as_dict()
        out.update({BIAS_PREFIX + k: v for k, v in self.biases.items()})
        return out

    def _set_bias(self, name: str, value) -> int:
        """A camera bias: validated here, sent by the reader thread (which owns the device)
        between two bulk reads; effective from the next event read.  Without an open camera
        (not started yet, reconnecting) it is kept and loaded when the camera opens."""
        if name not in camusb.BIASES:
            self.c["updates_rejected"] += 1
            raise UpdateRejected("unknown_name", f"unknown bias {name!r}; known: "
                                                 f"{', '.join(camusb.BIASES)}")
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            self.c["updates_rejected"] += 1
            raise UpdateRejected("wrong_type", f"bias {name} must be an integer 0..255, got {value!r}")
        if not 0 <= value <= 255:
            self.c["updates_rejected"] += 1
            raise UpdateRejected("out_of_range", f"bias {name}={value} out of range [0, 255]")
        with self.lock:
            old = self.biases[name]
            self.biases[name] = value     # (re)opening the camera loads this dict
        if self.reader.cam is not None:   # open now: the reader thread sends it
            try:
                self.reader.call(lambda cam: cam.load_biases({name: value}))
            except (TimeoutError, OSError, camusb.CameraError) as e:
                with self.lock:
                    self.biases[name] = old
                raise UpdateRejected("busy", f"bias {name}: camera did not take it: {e}") from None
            except RuntimeError:          # closed meanwhile: loaded at the next open
                pass
        with self.lock:
            self.gen_next += 1
            gen = self.gen_next
        self.applied.append((gen, int(max(self.fused.last_t, 0))))
        return gen

    def _apply_if_idle(self) -> None:
        if not self.running:
            self._apply_pending()

    def _apply_pending(self) -> None:
        """Processing thread (or idle caller), between two feeds: swap in what is queued."""
        with self.lock:
            pm, self.pending_model = self.pending_model, None
            pp, self.pending_params = self.pending_params, {}
        gen = None
        if pm is not None:
            m, p, k, gen = pm
            self._retire_kernel()
            self.fused.set_kernel(k)
            self.model, self.params, self.kernel = m, p, k
            self.c["kernel_swaps"] += 1
        if pp:
            new = _params.from_mapping({n: v for n, (v, _) in pp.items()}, self.params)
            self.kernel.set_params(new)
            self.params = new
            gen = max([g for _, g in pp.values()] + [gen or 0])
            if pm is None:
                self.fused.mark_next()
        if gen is not None:
            self.generation = gen
            self.c["updates_applied"] += 1
            self._await_first.append(gen)
            self.swaps.append((gen, int(self.fused.tracked)))

    # ---- processing thread ---------------------------------------------------------------
    def _run(self) -> None:
        r = self.reader
        while not self.stop_event.is_set():
            if self.pending_model is not None or self.pending_params:
                self._apply_pending()
            item = r.get(0.02)
            if item is None:
                continue
            idx, n, gap = item
            try:
                if gap:
                    self.fused.gap()
                self._feed(memoryview(r.pool[idx])[:n])
            except Exception as e:          # never let one transfer kill the loop
                self.c["processing_errors"] += 1
                self.last_error = f"processing: {type(e).__name__}: {e}"
                self.fused.gap()
            finally:
                r.release(idx)
        if self.pending_model is not None or self.pending_params:
            self._apply_pending()

    def _feed(self, mv) -> None:
        n = len(mv)
        pos = 0
        f = self.fused
        while pos < n:
            k = min(self.piece, n - pos)
            t0 = time.perf_counter_ns()
            out = f.feed(mv[pos:pos + k])
            dt = time.perf_counter_ns() - t0
            pos += k
            self.c["pieces"] += 1
            self.c["proc_ns"] += dt
            self._account(dt)
            if self._await_first and f.first_t >= 0:
                for g in self._await_first:
                    self.applied.append((g, int(f.first_t)))
                self._await_first = []
            if out is not None:
                self._emit(out)
            if self.pending_model is not None or self.pending_params:
                self._apply_pending()

    def _account(self, dt_ns: int) -> None:
        t = self.fused.last_t
        if t < -(1 << 60):
            return
        if self._win_t0 is None:
            self._win_t0 = t
        self._win_ns += dt_ns
        if t - self._win_t0 >= WINDOW_US:
            span = t - self._win_t0
            self.windows.append(self._win_ns / 1e3 * WINDOW_US / span)
            self._win_t0 = t
            self._win_ns = 0
        self._rate.append((time.monotonic(), self.fused.tracked))

    def _emit(self, out: dict) -> None:
        rows = len(out["t"])
        self.c["snapshots"] += rows
        if self.snap_wall is not None:
            now = time.monotonic()
            self.snap_wall.extend((int(t), now) for t in out["t"])
        if self.record:
            self.recorded.append((list(self.model.ids), out))
        energies = self._energies_due(int(out["t"][-1]))
        with self.lock:
            self.tele.append([self.generation, self.params.energy_kind_index, out, 0, energies])
            self.tele_rows += rows
            while self.tele_rows > self.tele_cap and self.tele:   # drop the oldest rows
                item = self.tele[0]
                avail = len(item[2]["t"]) - item[3]
                drop = min(avail, self.tele_rows - self.tele_cap)
                if drop == avail:
                    self.tele.popleft()
                else:
                    item[3] += drop
                self.tele_rows -= drop
                self.c["telemetry_dropped"] += drop

    def _energies_due(self, t_us: int):
        """Per-connection energies of the criterion's kind (eqs. 12, 17, 20) from the last
        spring update, at most once per ``energy_period_us`` of event time, else None.
        They ride on the block's last snapshot, which lies within one telemetry period of
        that update (the link sends them as ENERGIES)."""
        if self.next_energy_t is not None and t_us < self.next_energy_t:
            return None
        self.next_energy_t = t_us + self.energy_period_us
        return self.kernel.energies()[self.params.energy_kind_index].copy()

    # ---- Engine: observation ---------------------------------------------------------------
    def poll_telemetry(self, max_items: int = 64) -> list:
        res = []
        with self.lock:
            while self.tele and len(res) < max_items:
                item = self.tele[0]
                g, ek, blk, first, energies = item
                take = min(len(blk["t"]) - first, max_items - len(res))
                for r in range(first, first + take):
                    tr = np.empty(blk["x"].shape[1], TRACKER_DTYPE)
                    for f in SNAP_FIELDS:
                        tr[f] = blk[f][r]
                    res.append(dict(t_us=int(blk["t"][r]), generation=g,
                                     mean_energy=float(blk["energy"][r, ek]), trackers=tr))
                    if "wire" in blk:        # fixed kernel: records packed from its integer state
                        res[-1]["records"] = blk["wire"][r].tobytes()
                    if energies is not None and r == len(blk["t"]) - 1:
                        res[-1]["energies"] = (ek, energies)
                item[3] = first + take
                self.tele_rows -= take
                if item[3] >= len(blk["t"]):
                    self.tele.popleft()
        return res

    def poll_applied(self) -> list:
        out = []
        while self.applied:
            out.append(self.applied.popleft())
        return out

    def info(self) -> dict:
        with self.lock:
            return dict(firmware=FIRMWARE, backend=self.backend, width=self.width,
                        height=self.height,
                        max_trackers=MAX_TRACKERS, max_connections=MAX_CONNECTIONS,
                        model=self.model.name, model_hash=self.model.digest(),
                        trackers=list(self.model.ids), running=self.running,
                        generation=self.generation, telemetry_period_us=self.period)

    def event_rate(self) -> float:
        if len(self._rate) < 2:
            return 0.0
        (w0, e0), (w1, e1) = self._rate[0], self._rate[-1]
        return (e1 - e0) / (w1 - w0) if w1 > w0 else 0.0

    def stats(self) -> dict:
        fc = self.fused.counters()
        rc = dict(self.reader.counts)
        win = np.array(list(self.windows) or [0.0])     # list(): atomic copy under the GIL
        return dict(
            state=self.reader.state, last_error=self.reader.last_error or self.last_error,
            transfers=rc["transfers"], bytes=rc["bytes"],
            transfers_dropped=rc["transfers_dropped"], bytes_dropped=rc["bytes_dropped"],
            events_decoded=fc["events_decoded"], events_tracked=fc["events_tracked"],
            queue_depth=self.reader.queue_depth(), queue_hwm=rc["queue_hwm"],
            event_rate=self.event_rate(),
            proc_us_per_10ms=dict(last=float(win[-1]), mean=float(win.mean()),
                                  p99=float(np.percentile(win, 99)), max=float(win.max())),
            usb=dict(timeouts=rc["timeouts"], stalls=rc["stalls"], disconnects=rc["disconnects"],
                     reconnects=rc["reconnects"], open_failures=rc["open_failures"],
                     short_transfers=rc["short_transfers"], odd_transfers=rc["odd_transfers"],
                     commands=rc["commands"], command_errors=rc["command_errors"],
                     coalesced=rc["coalesced"]),
            decode=dict(words=fc["words"], time_high_words=fc["time_high_words"],
                        time_wraps=fc["time_wraps"], exposure_events=fc["exposure_events"],
                        gaps=fc["gaps"], pending_bytes=fc["pending_bytes"]),
            anomalies=fc["anomalies"],
            loop=dict(self.c, generation=self.generation, last_t_us=int(self.fused.last_t)),
            kernel=self.kernel_counters())

    def kernel_counters(self) -> dict:
        """The tracker kernel's counters summed over every kernel this run (a model load or
        RESET starts a new one): events it skipped and, for the fixed backend, the values
        it saturated (docs/fixed_point.md)."""
        out = dict(self.retired)
        for k, v in self.kernel.counters().items():
            out[k] = out.get(k, 0) + int(v)
        return dict(out, backend=self.backend)

    def _retire_kernel(self) -> None:
        for k, v in self.kernel.counters().items():
            self.retired[k] = self.retired.get(k, 0) + int(v)

    def stats_line(self) -> str:
        s = self.stats()
        an = {k: v for k, v in s["anomalies"].items() if v}
        usb = {k: v for k, v in s["usb"].items() if v}
        return (f"transfers={s['transfers']} bytes={s['bytes']} dropped={s['transfers_dropped']} "
                f"decoded={s['events_decoded']} tracked={s['events_tracked']} "
                f"queue_hwm={s['queue_hwm']} rate={s['event_rate']:.3g}/s "
                f"proc_us_per_10ms(mean={s['proc_us_per_10ms']['mean']:.0f} "
                f"max={s['proc_us_per_10ms']['max']:.0f}) state={s['state']} "
                f"usb={usb or 'ok'} anomalies={an or 'none'} kernel={s['kernel']['backend']}"
                + (f" saturated={sat}" if (sat := {k[10:]: v for k, v in s["kernel"].items()
                                                    if k.startswith("saturated_") and v}) else ""))

    # ---- record ----------------------------------------------------------------------------
    def write_record(self, path) -> int:
        """Write every snapshot as a springtrack track CSV; returns the number of rows."""
        import io as _io
        rows = 0
        with open(path, "w", newline="") as f:
            f.write(",".join(CSV_HEADER) + "\n")
            for ids, b in self.recorded:
                tr = Track(b["t"], ids, b["x"], b["y"], b["sxx"], b["sxy"], b["syy"],
                           b["activity"], b["active"].astype(bool), b["sensitive"].astype(bool))
                buf = _io.StringIO()
                tr.to_csv(buf)
                f.write(buf.getvalue().split("\n", 1)[1])
                rows += len(tr) * len(ids)
        return rows
