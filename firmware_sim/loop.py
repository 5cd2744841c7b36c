"""The firmware's tracking loop: USB reader thread + fused decode/track thread.

:class:`FirmwareLoop` implements ``firmware_sim.engine.Engine`` (docs/firmware.md) and
composes parts that each keep one job:

* the reader thread (``firmware_sim.reader``) owns the camera and fills a buffer pool;
* the processing thread feeds each transfer, in pieces of ``piece_bytes``, to the nogil
  fused loop (``firmware_sim._fused``), which decodes the profile's words (CCam, EVT 2.0,
  EVT 2.1 or EVT 3.0) at the sensor's geometry and steps the kernel;
* the model slot (``firmware_sim.slot``) validates updates (model, parameters, reset) in
  the caller's thread, builds them completely (a new kernel for a model) and queues them;
  the processing thread applies them between two pieces, i.e. between two events, and
  :class:`~firmware_sim.slot.AppliedLog` reports the event time of the first event
  processed under each generation (:meth:`poll_applied`);
* telemetry snapshots every ``telemetry_period_us`` of event time wait for the link in a
  bounded queue (``firmware_sim.telemetry``: the oldest dropped and counted), and with
  ``record`` all are kept for ``--record`` (``firmware_sim.record``);
* counters and the load meter (processing time per 10 ms of events) in
  ``firmware_sim.meter``;
* supervision (``firmware_sim.supervise``): the reader and processing threads restart
  after an unexpected exception (counted, reported to the hosts as ERROR frames, state
  ``faulted`` until RESET); an update the kernel refuses when it is applied keeps the
  previous configuration (ERROR ``update_failed``); snapshots of a non-finite tracker
  state are dropped and counted, never sent, and the trackers are reset to the model
  (ERROR ``nonfinite_state``); a watchdog reports a stalled loop (transfers waiting,
  nothing processed for ``WATCHDOG_S``).
* end of stream (:meth:`FirmwareLoop.end_of_stream`): the loop goes idle and tells the
  hosts (NOTICE ``stream_ended``); the next START replays the source (``rewind``).
* with ``learn_first_ms`` the feed is ``firmware_sim.learning.LearningFeed``: the model
  is learned from the stream's first milliseconds (springtrack.learning.learner) and swapped in
  like an upload, then the rest is tracked with it.
"""
from __future__ import annotations

import threading
import time

import numpy as np

from springtrack.limits import MAX_CONNECTIONS, MAX_TRACKERS
from springtrack.backends.samples import finite_rows
from springtrack.wire import Fault, Nack, Notice

from ._fused import Fused
from .feed import DecodedFeed
from .learning import LearningFeed
from . import camera as camusb
from . import priority
from .engine import UpdateRejected
from .meter import LoadMeter, LoopCounters
from .reader import Reader
from .record import Recorder, StreamRecorder
from .slot import AppliedLog, ApplyFailed, ModelSlot
from .supervise import Supervisor, where
from .telemetry import Block, TelemetryQueue

FIRMWARE = "firmware-sim 0.1 (fused decode+track loop)"
BIAS_PREFIX = "bias."     # camera biases are parameters "bias.<name>" on the host link
WATCHDOG_S = 2.0          # transfers waiting this long with nothing processed: stalled
WATCHDOG_POLL_S = 0.25


class Stopping(Exception):
    """The loop was told to stop while a transfer was being processed (a jump in time can
    make one transfer take very many snapshots): the rest of it is not processed."""


class FirmwareLoop:
    """The Engine: ``FirmwareLoop(open_camera, model, params, ...)``; ``open_camera()``
    returns a started ``firmware_sim.camera.Camera`` (called again after a disconnect).
    ``lossless=True`` (simulated camera at max speed only) makes the reader wait instead of
    shedding; ``record=True`` keeps every snapshot for :meth:`write_record`, ``record=PATH``
    writes them to that CSV as they come (firmware_sim.record).  ``profile``
    (``firmware_sim.camera.PROFILES`` name or DeviceProfile) names the word format and the
    sensor's geometry (``width``/``height`` override it), which every model must fit
    (``springtrack.sensor_fit.fit_model``; ``sensor_from`` "source" or "model" takes a model
    of another ``[sensor]``, None refuses it: ValueError here, NACK ``sensor_mismatch`` for
    an upload); ``roi`` ``(x, y, w, h)`` tracks only that region; ``source_counters()``
    (optional) returns what the source dropped
    before the camera (``events_in``, ``outside_sensor``), reported in the statistics.
    ``learn_first_ms``: learn the model from the stream's first milliseconds instead
    (``model`` only holds the slot until then and tracks nothing; ``learn_params``: tracking
    parameters written into the learned model, as ``springtrack learn --params``;
    ``learner``: the learner's parameter overrides, as ``--learn-param``)."""

    def __init__(self, open_camera, model="face26", params=None, telemetry_period_us: int = 1000,
                 nbuf: int = 64, piece_bytes: int = 16384, telemetry_queue: int = 4096,
                 transfer_bytes: int | None = None, lossless: bool = False,
                 biases: dict | None = None, profile="ccam_atis",
                 record: bool = False, width: int | None = None, height: int | None = None,
                 backend: str = "cython", roi=None, source_counters=None, sensor_from=None,
                 supervisor: Supervisor | None = None, rewind=None,
                 acquire: dict | None = None, learn_first_ms: float | None = None,
                 learn_params: dict | None = None, learner: dict | None = None,
                 rt_priority: int | None = None):
        """``rewind()``: called by the START that follows :meth:`end_of_stream`, to serve
        the source again from its beginning (None: START after the end resumes reading).
        ``rt_priority``: from :meth:`start` to :meth:`stop`, every thread of the process
        runs under SCHED_FIFO at it, the reader's and the processing thread too
        (``firmware_sim.priority``; PriorityError here if the system refuses it)."""
        if telemetry_period_us <= 0:
            raise ValueError(f"telemetry_period_us must be positive, got {telemetry_period_us}")
        self.profile = camusb.PROFILES[profile] if isinstance(profile, str) else profile
        self.width = width or self.profile.width          # the sensor
        self.height = height or self.profile.height
        # every model (this one, uploads) must fit the sensor: springtrack.sensor_fit
        self.slot = ModelSlot(backend, model, params, (self.width, self.height), sensor_from,
                              acquire)
        self.applied = AppliedLog()
        self.learner = None
        if learn_first_ms is not None:      # decoded events for the learner: springtrack.io
            if roi is not None:
                raise ValueError("--roi and --learn-first-ms cannot be combined")
            self.fused = self.learner = LearningFeed(
                self.slot.kernel, telemetry_period_us, self.profile, learn_first_ms,
                self.width, self.height, learn_params, learner)
        elif not backend.startswith("mcu") and acquire is None:
            self.fused = Fused(self.slot.kernel, telemetry_period_us, 512, fmt=self.profile.fmt,
                               width=self.width, height=self.height,
                               legacy=self.profile.legacy, roi=roi)
        else:        # a kernel in an emulator, with no C step, or one that acquires (it
            #          needs the events): springtrack.io decoder + run
            if roi is not None:
                raise ValueError("--roi needs a kernel the fused loop runs (cython, fixed; "
                                 "not --acquire)")
            self.fused = DecodedFeed(self.slot.kernel, telemetry_period_us, self.profile)
        self.source_counters = source_counters or dict
        self.period = int(telemetry_period_us)
        self.piece = int(piece_bytes)
        self.supervisor = supervisor or Supervisor()
        self.rewind = rewind
        self.rt_priority = None if rt_priority is None else priority.check(rt_priority)
        self.reader = Reader(open_camera, nbuf=nbuf, shed=not lossless,
                             supervisor=self.supervisor, on_give_up=self._gave_up,
                             **({"transfer_bytes": transfer_bytes} if transfer_bytes else {}))
        # shared with open_camera (the CLI passes the same dict) so a reconnect reloads the
        # biases the host set last
        self.biases = biases if biases is not None else {}
        self.biases.update(camusb.check_biases(self.biases))
        self.telemetry = TelemetryQueue(telemetry_queue)
        self.recorder = (None if not record else Recorder() if record is True
                         else StreamRecorder(record))
        self.counters = LoopCounters()
        self.in_transfer = False          # the processing thread is inside a transfer
        self.meter = LoadMeter()
        self.last_error = ""
        self.learn_report = ""              # what the learner found (learn_first_ms)
        self.stop_event = threading.Event()
        self.thread = None
        self.watchdog = None
        self.ended = False                    # the source ran out; START replays it
        self._life = threading.RLock()        # start / stop / end_of_stream, any thread
        self._nonfinite_gen = None            # generation last reset for non-finite state

    # the running model, read-only (the slot swaps them)
    backend = property(lambda self: self.slot.backend)
    model = property(lambda self: self.slot.model)
    params = property(lambda self: self.slot.params)
    kernel = property(lambda self: self.slot.kernel)
    generation = property(lambda self: self.slot.generation)

    # ---- Engine: lifecycle ---------------------------------------------------------------
    def start(self) -> None:
        with self._life:
            if self.running:
                return
            if self.thread is not None:       # stopped by its supervisor: join what is left
                self.stop()
            if self.ended and self.rewind is not None:
                self.rewind()
            self.ended = False
            self.stop_event.clear()
            priority.apply(self.rt_priority)    # before the threads: they inherit it
            self.reader.start()
            target = self.supervisor.thread_target("fused-loop", self._run, self.stop_event,
                                                   on_give_up=self._gave_up)
            self.thread = threading.Thread(target=target, name="fused-loop", daemon=True)
            self.thread.start()
            self.watchdog = threading.Thread(target=self._watch, name="watchdog", daemon=True)
            self.watchdog.start()

    def stop(self, timeout: float = 5.0) -> None:
        with self._life:
            self.stop_event.set()
            for attr in ("thread", "watchdog"):
                t = getattr(self, attr)
                if t is not None and t is not threading.current_thread():
                    t.join(timeout)
                    if t.is_alive():
                        raise RuntimeError(f"{t.name} thread did not stop within {timeout} s "
                                           f"(at {where(t)})")
                    setattr(self, attr, None)
            self.reader.stop(timeout)
            priority.release(self.rt_priority)
            # transfers read but not processed are dropped (counted with the abandoned
            # bytes): the rest of a transfer the stop cut short is gone, so what was queued
            # after it would be decoded out of step with its words
            self.counters.bytes_abandoned += self.reader.discard_queued()

    def end_of_stream(self) -> None:
        """The source has no more data and every byte was processed: stop the threads and
        tell the hosts; the next :meth:`start` replays the source (``rewind``)."""
        with self._life:
            if self.ended:
                return
            self.stop()
            self._finish_kernel()
            self.ended = True
        self.supervisor.notice(Notice.STREAM_ENDED, "the source has no more data; the loop is "
                                                    "idle (START replays it)")

    def _gave_up(self) -> None:
        """A thread faulted too often (its supervisor stopped it): stop the loop cleanly;
        the state stays ``faulted`` until RESET, START runs it again."""
        self.stop_event.set()
        try:
            self.reader.stop(1.0)
        except RuntimeError as e:
            self.supervisor.report(Fault.THREAD_STOPPED, str(e))

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def drained(self) -> bool:
        return self.reader.queue_depth() == 0

    def caught_up(self) -> bool:
        """Every byte read so far has been processed: nothing queued, no transfer in the
        middle of its processing (the feed counts its bytes as it starts), and the fused
        loop has consumed all read bytes but the dropped ones."""
        rc = self.reader.counts
        return (self.drained() and not self.in_transfer
                and self.fused.bytes_in + self.counters.bytes_abandoned
                == rc["bytes"] - rc["bytes_dropped"])

    def reset(self) -> None:
        """Restart the tracker from the current model (queued like a model swap) and clear
        the ``faulted`` state."""
        self.slot.queue_reset()
        self.supervisor.clear()
        self._apply_if_idle()

    def acquire(self) -> int:
        """Search for the model again (ACQUIRE): a fresh acquiring kernel of the current
        model, queued like a reset; its state is ``searching`` until it is found.  Refused
        (BAD_STATE) when the firmware runs without acquisition."""
        if self.slot.acquire is None:
            raise UpdateRejected(Nack.BAD_STATE, "this firmware runs without acquisition: "
                                                 "start it with --acquire")
        gen = self.slot.queue_reset()
        self._apply_if_idle()
        return gen

    # ---- Engine: updates -------------------------------------------------------------------
    def load_model(self, toml_text: str) -> int:
        gen = self._counting_rejections(self.slot.queue_model, toml_text)
        self._apply_if_idle()
        return gen

    def set_param(self, name: str, value) -> int:
        if name.startswith(BIAS_PREFIX):
            return self._counting_rejections(self._set_bias, name[len(BIAS_PREFIX):], value)
        gen = self._counting_rejections(self.slot.queue_param, name, value)
        self._apply_if_idle()
        return gen

    def _counting_rejections(self, update, *args) -> int:
        try:
            return update(*args)
        except UpdateRejected:
            self.counters.updates_rejected += 1
            raise

    def get_params(self) -> dict:
        out = self.slot.params_dict()
        out.update({BIAS_PREFIX + k: v for k, v in self.biases.items()})
        return out

    def _set_bias(self, name: str, value) -> int:
        """A camera bias: validated here, sent by the reader thread (which owns the device)
        between two bulk reads; effective from the next event read.  Without an open camera
        (not started yet, reconnecting) it is kept and loaded when the camera opens."""
        value = _check_bias(name, value)
        with self.slot.lock:
            old = self.biases[name]
            self.biases[name] = value     # (re)opening the camera loads this dict
        if self.reader.cam is not None:   # open now: the reader thread sends it
            try:
                self.reader.call(lambda cam: cam.load_biases({name: value}))
            except (TimeoutError, OSError, camusb.CameraError) as e:
                with self.slot.lock:
                    self.biases[name] = old
                raise UpdateRejected(Nack.BUSY, f"bias {name}: camera did not take it: {e}") from None
            except RuntimeError:          # closed meanwhile: loaded at the next open
                pass
        gen = self.slot.next_generation()
        self.applied.report(gen, max(self.fused.last_t, 0))
        return gen

    def _apply_if_idle(self) -> None:
        if not self.running:
            self._apply_pending()

    def _apply_pending(self) -> None:
        """Processing thread (or idle caller), between two feeds: swap in what is queued."""
        try:
            swap = self.slot.apply()
        except ApplyFailed as e:              # the rest of the update did take effect
            self.counters.updates_failed += 1
            self.supervisor.report(Fault.UPDATE_FAILED, str(e))
            swap = e.swap
        if swap is None:
            return
        if swap.new_kernel:
            self.fused.set_kernel(self.slot.kernel)
            self.counters.kernel_swaps += 1
        else:
            self.fused.mark_next()
        self.counters.updates_applied += 1
        self.applied.took_effect(swap.generation, self.fused.tracked)

    # ---- processing thread ---------------------------------------------------------------
    def _run(self) -> None:
        """The processing thread's body (restarted by the supervisor if anything but one
        transfer's processing raises)."""
        r = self.reader
        while not self.stop_event.is_set():
            if self.slot.pending:
                self._apply_pending()
            item = r.get(0.02)
            if item is None:
                continue
            idx, n, gap = item
            try:
                if gap:
                    self.fused.gap()
                self._feed(memoryview(r.pool[idx])[:n])
            except Stopping:                # stopped in the middle of a transfer
                self.fused.gap()
            except Exception as e:          # never let one transfer kill the loop
                self.counters.processing_errors += 1
                self.last_error = f"processing: {type(e).__name__}: {e}"
                self.supervisor.report(Fault.THREAD_FAULT, f"fused-loop: transfer of {n} bytes "
                                                           f"skipped: {type(e).__name__}: {e}")
                self.fused.gap()
            finally:
                r.release(idx)
        if self.slot.pending:
            self._apply_pending()

    def _watch(self) -> None:
        """Watchdog: transfers waiting while the processing thread makes no progress for
        WATCHDOG_S is a stall (reported once per episode, counted)."""
        last, since, stalled = None, time.monotonic(), False
        while not self.stop_event.wait(WATCHDOG_POLL_S):
            now = time.monotonic()
            progress = (self.counters.pieces, self.fused.bytes_in)
            if self.reader.queue_depth() == 0 or progress != last:
                last, since, stalled = progress, now, False
                continue
            if not stalled and now - since >= WATCHDOG_S:
                stalled = True
                self.counters.watchdog_stalls += 1
                alive = self.thread is not None and self.thread.is_alive()
                self.supervisor.report(Fault.STALLED, f"{self.reader.queue_depth()} transfers "
                                                      f"waiting, nothing processed for "
                                                      f"{now - since:.1f} s (processing thread "
                                                      f"{'alive' if alive else 'dead'})")

    def _feed(self, mv) -> None:
        n = len(mv)
        fed = 0
        f = self.fused
        self.in_transfer = True
        try:
            while fed < n:
                k = min(self.piece, n - fed)
                fed += k                        # the feed counts it (bytes_in) as it starts
                t0 = time.perf_counter_ns()
                out = f.feed(mv[fed - k:fed], sink=self._emit)     # parts as they fill
                dt = time.perf_counter_ns() - t0
                self.counters.pieces += 1
                self.counters.proc_ns += dt
                self.meter.account(f.last_t, dt, f.tracked)
                if self.learner is not None and self.learner.learned is not None:
                    self._load_learned()
                if self.applied.waiting and f.first_t >= 0:
                    self.applied.first_event(f.first_t)
                if out is not None:             # a feed without a sink (tests)
                    self._emit(out)
                if self.slot.pending:
                    self._apply_pending()
        finally:                                # the rest of a transfer abandoned (an error,
            self.counters.bytes_abandoned += n - fed    # a stop): caught_up() counts it
            self.in_transfer = False

    def _load_learned(self) -> None:
        """Processing thread: the learner's model becomes the running one (a new
        generation, like an upload); the window's tail is tracked with it."""
        res, self.learner.learned = self.learner.learned, None
        m = res.model
        self.learn_report = (f"learned {len(m.trackers)} trackers, {len(m.connections)} "
                             f"springs from {res.events:,} events over "
                             f"{(res.t_end_us - res.t_start_us) / 1e3:.1f} ms in "
                             f"{res.wall_s:.2f} s; " + ", ".join(f"{k}={v}" for k, v in
                                                               m.params.items()))
        self.slot.queue_model(m.to_toml())
        self._apply_pending()
        self.learner.track_rest(sink=self._emit)

    def _finish_kernel(self) -> None:
        """The source ended (the loop stopped): a kernel that still searches for its model
        ends its search (``AcquiringKernel.finish``: found, or not found), and the rows that
        makes go out like the others."""
        finish = getattr(self.kernel, "finish", None)
        out = finish() if finish is not None else None
        if out is not None:
            self._queue(out)

    def _emit(self, out: dict) -> None:
        """One part of the snapshots a feed took (at most the fused loop's capacity in rows):
        checked, recorded, queued for the link.  Processing thread."""
        if self.stop_event.is_set():
            raise Stopping()
        self._queue(out)

    def _queue(self, out: dict) -> None:
        """Sample rows checked, recorded and queued for the link."""
        if not self.fused.native_records:       # the fixed kernel's state is integer
            ok = finite_rows(out["trackers"])
            if not ok.all():
                out = self._drop_nonfinite(out, ok)
                if out is None:
                    return
        self.counters.snapshots += len(out["t"])
        kind = self.params.energy_kind_index
        self.telemetry.push(Block(self.generation, kind, out, self.kernel.energies()[kind].copy(),
                                  self.fused.native_records))
        if self.recorder is not None:       # after the link's copy: never delays telemetry
            self.recorder.add(self.model.ids, out, time.monotonic())

    def _drop_nonfinite(self, out: dict, ok: np.ndarray) -> dict | None:
        """Snapshots whose tracker state is not finite are dropped and counted (never sent
        as numbers); the trackers restart from the model (once per generation)."""
        bad = int((~ok).sum())
        self.counters.nonfinite_snapshots += bad
        if self._nonfinite_gen != self.generation:
            self._nonfinite_gen = self.generation
            self.counters.nonfinite_resets += 1
            self.slot.queue_reset()
            self.supervisor.report(Fault.NONFINITE_STATE,
                                   f"tracker state not finite from t={int(out['t'][~ok][0])} us "
                                   f"(model {self.model.name!r}, generation {self.generation}): "
                                   f"snapshots dropped, trackers reset to the model")
        if not ok.any():
            return None
        return {k: v[ok] for k, v in out.items()}

    # ---- Engine: observation ---------------------------------------------------------------
    def poll_telemetry(self, max_items: int = 64) -> list:
        return self.telemetry.poll(max_items)

    def poll_applied(self) -> list:
        return self.applied.poll()

    def reports(self, after: int = 0) -> list:
        return self.supervisor.reports(after)

    def report_fault(self, thread: str, error: BaseException, action: str = "restarted") -> None:
        self.supervisor.fault(thread, error, max_faults=None, action=action)

    @property
    def state(self) -> str:
        """``faulted`` (until RESET), ``ended`` (the source ran out), else the reader's
        (idle, streaming, disconnected, reconnecting, stopped)."""
        if self.supervisor.faulted:
            return "faulted"
        if self.ended:
            return "ended"
        return self.reader.state

    def info(self) -> dict:
        with self.slot.lock:
            return dict(firmware=FIRMWARE, backend=self.backend, width=self.width,
                        height=self.height,
                        max_trackers=MAX_TRACKERS, max_connections=MAX_CONNECTIONS,
                        model=self.model.name, model_hash=self.model.digest(),
                        trackers=list(self.model.ids), running=self.running,
                        learning=self.learner is not None and self.learner.learning,
                        generation=self.generation, telemetry_period_us=self.period)

    def model_text(self) -> str:
        with self.slot.lock:
            return self.model.to_toml()

    def stats(self) -> dict:
        fc = self.fused.counters()
        rc = dict(self.reader.counts)
        return dict(
            state=self.state,
            last_error=self.supervisor.last_error or self.reader.last_error or self.last_error,
            transfers=rc["transfers"], bytes=rc["bytes"],
            transfers_dropped=rc["transfers_dropped"], bytes_dropped=rc["bytes_dropped"],
            events_decoded=fc["events_decoded"], events_tracked=fc["events_tracked"],
            queue_depth=self.reader.queue_depth(), queue_hwm=rc["queue_hwm"],
            event_rate=self.meter.event_rate(),
            proc_us_per_10ms=self.meter.proc_us_per_10ms(),
            usb=dict(timeouts=rc["timeouts"], stalls=rc["stalls"], disconnects=rc["disconnects"],
                     reconnects=rc["reconnects"], open_failures=rc["open_failures"],
                     short_transfers=rc["short_transfers"], odd_transfers=rc["odd_transfers"],
                     commands=rc["commands"], command_errors=rc["command_errors"],
                     coalesced=rc["coalesced"]),
            decode=dict(format=fc["format"], width=self.width, height=self.height,
                        words=fc["words"], time_high_words=fc["time_high_words"],
                        time_wraps=fc["time_wraps"], exposure_events=fc["exposure_events"],
                        gaps=fc["gaps"], pending_bytes=fc["pending_bytes"],
                        triggers=fc["triggers"], other_words=fc["other_words"],
                        time_low_backwards=fc["time_low_backwards"],
                        outside_roi=fc["outside_roi"]),
            geometry_drops=self._geometry_drops(fc),
            source=self.source_counters(),
            anomalies=self._anomalies(fc),
            loop=dict(self.counters.as_dict(), telemetry_dropped=self.telemetry.dropped,
                      generation=self.generation, last_t_us=int(self.fused.last_t)),
            kernel=self.slot.kernel_counters(),
            supervisor=self.supervisor.counters(),
            instances=self._instances(),
            learn=self._learn_stats())

    def _learn_stats(self) -> dict:
        """The learner's state (learn_first_ms): learning, learned or failed, and events."""
        le = self.learner
        if le is None:
            return {}
        state = ("failed" if le.error else "learned" if self.learn_report else "learning")
        c = le.counters()
        return dict(state=state, events=c["events_learned"], dropped=c["events_unlearned"],
                    untracked=c["events_untracked"], error=le.error, report=self.learn_report)

    def _instances(self) -> dict:
        """Each model instance's state (searching, tracking, lost), with acquisition."""
        kern = self.slot.kernel
        if not hasattr(kern, "instances"):
            return {}
        return {i["label"]: i["state"] for i in kern.instances()}

    def _instances_line(self) -> str:
        """Each instance's state and counts of changes (with acquisition), or ''."""
        kern = self.slot.kernel
        if not hasattr(kern, "instances"):
            return ""
        return ",".join(f"{i['label']}:{i['state']}(acquired={i['acquired']},lost={i['lost']},"
                        f"reacquired={i['reacquired']})" for i in kern.instances())

    def _anomalies(self, fc: dict) -> dict:
        """The camera decoder's anomalies, the kernel's skips, and (``replay_file``) those
        of the decoder that read a replayed file before re-encoding it."""
        an = dict(fc["anomalies"])
        an["replay_file"] = int(self.source_counters().get("file_anomalies", 0))
        return an

    def _geometry_drops(self, fc: dict) -> dict:
        """Events lost because they lay outside the sensor: in the words (the decoder's
        ``out_of_geometry``) and before them (a source that re-encoded a larger recording
        for a smaller camera), with their share of all events."""
        src = self.source_counters()
        words = fc["anomalies"]["out_of_geometry"]
        before = src.get("outside_sensor", 0)
        seen = src.get("events_in", 0) or fc["events_decoded"] + words
        total = words + before
        return dict(events=total, in_words=words, before_encoding=before,
                    fraction=total / seen if seen else 0.0)

    def stats_line(self) -> str:
        s = self.stats()
        an = {k: v for k, v in s["anomalies"].items() if v}
        usb = {k: v for k, v in s["usb"].items() if v}
        g = s["geometry_drops"]
        geo = (f"geometry_drops={g['events']} ({g['fraction']:.1%} of the events, outside "
               f"the {self.width}x{self.height} sensor)" if g["events"] else "geometry_drops=0")
        d = s["decode"]
        roi = f" outside_roi={d['outside_roi']}" if d["outside_roi"] else ""
        return (f"transfers={s['transfers']} bytes={s['bytes']} dropped={s['transfers_dropped']} "
                f"dropped_bytes={s['bytes_dropped']} "
                f"decoded={s['events_decoded']} tracked={s['events_tracked']} {geo}{roi} "
                f"format={d['format']} sensor={self.width}x{self.height} "
                f"queue_hwm={s['queue_hwm']} rate={s['event_rate']:.3g}/s "
                f"proc_us_per_10ms(mean={s['proc_us_per_10ms']['mean']:.0f} "
                f"max={s['proc_us_per_10ms']['max']:.0f}) state={s['state']} "
                f"usb={usb or 'ok'} anomalies={an or 'none'} kernel={s['kernel']['backend']}"
                + (f" learn={s['learn']['state']}" if s["learn"] else "")
                + (f" instances={inst}" if (inst := self._instances_line()) else "")
                + (f" saturated={sat}" if (sat := {k[10:]: v for k, v in s["kernel"].items()
                                                    if k.startswith("saturated_") and v}) else ""))

    # ---- record ----------------------------------------------------------------------------
    def write_record(self, path) -> int:
        """Write every snapshot as a springtrack track CSV; returns the number of rows."""
        if self.recorder is None:
            raise RuntimeError("this engine was made without record=True")
        return self.recorder.write(path)

    def has_output(self) -> bool:
        """Snapshots or APPLIED reports are still waiting for the link."""
        return self.telemetry.rows > 0 or self.applied.pending()


def _check_bias(name: str, value) -> int:
    """A camera bias value as an int 0..255, or UpdateRejected naming the problem."""
    if name not in camusb.BIASES:
        raise UpdateRejected(Nack.UNKNOWN_NAME, f"unknown bias {name!r}; known: "
                                                f"{', '.join(camusb.BIASES)}")
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise UpdateRejected(Nack.WRONG_TYPE, f"bias {name} must be an integer 0..255, got {value!r}")
    if not 0 <= value <= 255:
        raise UpdateRejected(Nack.OUT_OF_RANGE, f"bias {name}={value} out of range [0, 255]")
    return value
