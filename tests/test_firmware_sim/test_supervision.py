"""Supervision: no firmware thread dies silently, nothing non-finite goes out as a number.

Each reproduction of a thread killed by an exception, a model driving the float kernel to
NaN, a parameter the fixed kernel refuses after the ACK, a stalled loop - both with real
models (refused cleanly or survived) and with faults injected directly into the engine's
parts, so that the supervision path is proven whatever the validation refuses."""
from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

from firmware_sim import link, transport
from firmware_sim import camera as camusb
from firmware_sim.engine import Snapshot, UpdateRejected
from firmware_sim.loop import WATCHDOG_S, FirmwareLoop
from firmware_sim.simcam import SimBackend, SimCamera
from firmware_sim.sources import events_source
from firmware_sim.supervise import Supervisor
from hostctl import Device, Nacked
from springtrack import model as _model
from springtrack import wire
from springtrack.sim.sensor import simulate_all
from springtrack.wire import Fault, MsgType, Nack

from support.fwproc import Firmware
from support.engine import SimEngine
from support.wait import wait_for


@pytest.fixture(scope="module")
def scene():
    ev, _ = simulate_all("face_occlusion", 1.0, seed=1)
    return ev


def make_engine(ev, realtime=False, backend="cython", model="face26", camera_wrap=None,
                transfer_bytes=16384, **kw):
    cam = SimCamera(events_source(ev, 2048), realtime=realtime)
    be = SimBackend(cam)

    def open_camera():
        c = camusb.Camera.open("ccam_atis", backend=be)
        return camera_wrap(c) if camera_wrap else c
    eng = FirmwareLoop(open_camera, model, lossless=not realtime, nbuf=64,
                       transfer_bytes=transfer_bytes, backend=backend, **kw)
    return cam, eng


def run_to_end(cam, eng):
    eng.start()
    wait_for(lambda: cam.finished and eng.caught_up(), what="end of stream")
    eng.stop()


def errors(eng):
    return [(code, text) for _, mtype, code, text in eng.reports() if mtype == MsgType.ERROR]


class FeedProxy:
    """The engine's fused loop with ``feed`` replaced (a Cython object cannot be patched)."""

    def __init__(self, inner, feed):
        self._inner, self._feed = inner, feed

    def feed(self, buf, n=-1, sink=None):
        return self._feed(self._inner, buf, sink)

    def __getattr__(self, name):
        return getattr(self._inner, name)


# ---- models that drove the float kernel to NaN ---------------------------------------------
def nan_models() -> dict:
    """The reproductions, as TOML text (a ShapeModel refuses to hold them): face26 at
    stiffness 0.5 (NaN after about 58 k events before the spring bound), two trackers at 0.9
    with all three spring kinds, a mass of 1e-9."""
    face = _model.face26().to_toml()
    head, _, rest = face.partition("[[trackers]]")
    blocks = rest.split("[[trackers]]")
    two = (head.replace('name = "face26"', 'name = "two"') + "[[trackers]]" + blocks[0]
           + "[[trackers]]" + blocks[1].split("[[connections]]")[0]
           + '[[connections]]\na = "brow_l"\nb = "brow_r"\n'
             'springs = ["euclidean", "torsional", "cartesian"]\nstiffness = 0.9\n')
    return {"face26_stiffness_0.5": re.sub(r"stiffness = [0-9.e-]+", "stiffness = 0.5", face),
            "two_trackers_stiffness_0.9": two,
            "mass_1e-9": face.replace("mass = 1.0", "mass = 1e-9", 1)}


@pytest.mark.parametrize("name", list(nan_models()))
def test_a_model_that_drives_the_kernel_to_nan_is_refused(scene, name):
    """Refused at upload (NACK invalid_model, the reason naming the spring load or the
    mass: springtrack.limits), nothing changes, and the loop runs on."""
    cam, eng = make_engine(scene)
    with pytest.raises(UpdateRejected) as e:
        eng.load_model(nan_models()[name])
    assert e.value.code == Nack.INVALID_MODEL
    assert "spring load" in str(e.value) or "mass" in str(e.value), e.value
    run_to_end(cam, eng)
    st = eng.stats()
    assert st["loop"]["generation"] == 1 and st["events_tracked"] > 0
    assert st["loop"]["nonfinite_snapshots"] == 0 and st["state"] != "faulted"


def test_injected_nan_rows_are_dropped_counted_reported_and_the_trackers_reset(scene):
    """Whatever validation refuses, a kernel that yields NaN/inf never reaches the wire."""
    cam, eng = make_engine(scene)
    calls, emit = [0], eng._emit

    def corrupt(part):                  # the parts the fused loop hands on as it takes them
        calls[0] += 1
        if calls[0] == 5:
            part["trackers"]["x"][::2, 3] = np.nan
            part["trackers"]["sxx"][1::2, 0] = np.inf
        emit(part)
    eng._emit = corrupt
    gen0 = eng.generation
    run_to_end(cam, eng)
    c = eng.stats()["loop"]
    assert c["nonfinite_snapshots"] > 0 and c["nonfinite_resets"] == 1
    assert eng.generation == gen0 + 1                       # the reset took effect
    assert [code for code, _ in errors(eng)] == [Fault.NONFINITE_STATE]
    snaps = eng.poll_telemetry(10 ** 6)
    assert len(snaps) == c["snapshots"]
    assert all(np.isfinite(s.trackers["x"]).all() and np.isfinite(s.trackers["sxx"]).all()
               for s in snaps)


# ---- a parameter the fixed kernel refuses ---------------------------------------------------
@pytest.mark.parametrize("name, value", [("sigma_max_px", 100.0), ("alpha_covariance", 1.0)])
def test_fixed_kernel_parameters_are_refused_before_the_ack(scene, name, value):
    """In a gap of events (the loop idle in its wait for a transfer) and afterwards: a
    NACK out_of_range (springtrack.limits: what every backend runs), no generation handed
    out, the fused-loop thread alive."""
    cam, eng = make_engine(scene, realtime=True, backend="fixed")
    eng.start()
    try:
        wait_for(lambda: eng.fused.tracked > 0, what="tracking")
        gen = eng.generation
        with pytest.raises(UpdateRejected, match=name) as e:
            eng.set_param(name, value)
        assert e.value.code == Nack.OUT_OF_RANGE
        assert eng.set_param("energy_gain", 0.07) == gen + 1        # the next one is fine
        wait_for(lambda: eng.generation == gen + 1, what="the next update applied")
        assert eng.running and eng.stats()["state"] == "streaming"
        assert eng.stats()["loop"]["processing_errors"] == 0 and errors(eng) == []
    finally:
        eng.stop()


def test_an_update_the_kernel_refuses_when_applied_keeps_the_old_one_and_says_so(scene):
    """Defence in depth: a change queued as if it had passed validation is refused in the
    processing thread between two events (here during a gap: no transfer waits).  The
    thread survives, the running parameters are kept, the generation is not advanced,
    and the hosts get ERROR update_failed naming the generation."""
    cam, eng = make_engine(scene, realtime=True, backend="fixed")
    eng.start()
    try:
        wait_for(lambda: eng.fused.tracked > 0, what="tracking")
        before = eng.get_params()["sigma_max_px"]
        gen0 = eng.generation
        with eng.slot.lock:                     # queued unchecked: the defect to survive
            gen = eng.slot._last_gen = eng.slot._last_gen + 1
            eng.slot._params["sigma_max_px"] = (100.0, gen)
        wait_for(lambda: eng.stats()["loop"]["updates_failed"] == 1, what="the apply")
        assert eng.running and eng.generation == gen0
        assert eng.get_params()["sigma_max_px"] == before
        (code, text), = errors(eng)
        assert code == Fault.UPDATE_FAILED and f"generation(s) {gen}" in text
        n = eng.fused.tracked
        wait_for(lambda: eng.fused.tracked > n, what="tracking to go on")
    finally:
        eng.stop()


# ---- a thread killed by an exception ---------------------------------------------------------
def test_an_exception_outside_the_transfer_is_caught_counted_reported_and_restarted(scene):
    """An exception in the processing thread outside the processing of a transfer (here
    while it waits for one) is the supervisor's: caught, counted, ERROR thread_fault, state
    faulted until RESET, the thread restarted; the updates queued meanwhile take effect."""
    cam, eng = make_engine(scene, realtime=True)
    real_get, boom = eng.reader.get, [0]

    def get(timeout):
        if boom[0]:
            boom[0] -= 1
            raise RuntimeError("injected")
        return real_get(timeout)
    eng.reader.get = get
    eng.start()
    try:
        wait_for(lambda: eng.fused.tracked > 0, what="tracking")
        boom[0] = 1
        gen = eng.set_param("energy_gain", 0.08)
        wait_for(lambda: eng.generation == gen and eng.supervisor.restarts == 1, what="the restart")
        st = eng.stats()
        assert st["state"] == "faulted" and "RuntimeError: injected" in st["last_error"]
        assert st["supervisor"]["faults_fused_loop"] == 1 and st["supervisor"]["restarts"] == 1
        assert [c for c, _ in errors(eng)] == [Fault.THREAD_FAULT]
        n = eng.fused.tracked
        wait_for(lambda: eng.fused.tracked > n, what="tracking after the restart")
        eng.reset()                                   # the host's RESET clears the state
        assert eng.stats()["state"] == "streaming"
    finally:
        eng.stop()
    assert not any(t.name in ("usb-reader", "fused-loop", "watchdog") for t in threading.enumerate())


def test_a_thread_that_keeps_failing_is_stopped_cleanly_and_can_be_restarted(scene):
    cam, eng = make_engine(scene, realtime=True)
    real_apply = eng.slot.apply
    eng.slot.apply = lambda: (_ for _ in ()).throw(RuntimeError("always"))
    eng.start()
    eng.set_param("energy_gain", 0.08)             # pending: every restart raises again
    wait_for(lambda: not eng.running, what="the supervisor giving up")
    wait_for(lambda: not eng.reader.running, what="the reader stopped")
    st = eng.stats()
    assert st["state"] == "faulted" and st["supervisor"]["threads_stopped"] == 1
    assert Fault.THREAD_STOPPED in [c for c, _ in errors(eng)]
    eng.slot.apply = real_apply
    eng.reset()
    eng.start()
    try:
        n = eng.fused.tracked
        wait_for(lambda: eng.fused.tracked > n, what="tracking after START")
        assert eng.stats()["state"] == "streaming"
    finally:
        eng.stop()


def test_a_stop_in_the_middle_of_a_transfer_still_lets_the_stream_end(scene):
    """A stop abandons the rest of the transfer being processed; the bytes abandoned are
    counted, so the end of the stream is still recognised after the next start."""
    cam, eng = make_engine(scene, transfer_bytes=131072)      # 8 pieces per transfer
    once = [True]

    def feed(inner, buf, sink):
        if once[0] and inner.tracked > 10_000:
            once[0] = False
            eng.stop_event.set()                # the stop arrives while this piece runs
        return inner.feed(buf, sink=sink)
    eng.fused = FeedProxy(eng.fused, feed)
    eng.start()
    wait_for(lambda: not once[0] and not eng.running, what="the stop")
    eng.stop()
    assert eng.counters.bytes_abandoned > 0
    run_to_end(cam, eng)                        # ends: caught_up() counts what was abandoned
    assert eng.stats()["events_decoded"] < len(scene)


def test_the_stream_is_not_caught_up_while_its_last_transfer_is_being_processed(scene):
    """The feed counts a piece's bytes as it starts: until the transfer's processing has
    finished (its snapshots emitted), caught_up() must stay False, or the end of the stream
    would stop the loop in the middle of its last snapshots."""
    cam, eng = make_engine(scene)
    seen = []                          # (every byte counted, caught_up) after each piece

    def feed(inner, buf, sink):
        out = inner.feed(buf, sink=sink)
        rc = eng.reader.counts
        if cam.finished and eng.drained():
            seen.append((inner.bytes_in == rc["bytes"] - rc["bytes_dropped"], eng.caught_up()))
        return out
    eng.fused = FeedProxy(eng.fused, feed)
    run_to_end(cam, eng)
    assert any(every for every, _ in seen), "no observation inside the last piece"
    assert not any(caught for _, caught in seen)
    assert eng.stats()["events_tracked"] == len(scene)


class FlakyCamera:
    """A camera whose ``read_into`` raises something that is not a USB error once."""

    def __init__(self, cam, at):
        self.cam, self.left = cam, at

    def read_into(self, buf, timeout_ms):
        self.left -= 1
        if self.left == 0:
            raise MemoryError("injected")
        return self.cam.read_into(buf, timeout_ms)

    def __getattr__(self, name):
        return getattr(self.cam, name)


def test_the_reader_thread_is_restarted_and_the_buffer_pool_kept(scene):
    flaky = []
    cam, eng = make_engine(scene, camera_wrap=lambda c: c if flaky else
                           (flaky.append(FlakyCamera(c, 5)) or flaky[-1]))
    run_to_end(cam, eng)
    st = eng.stats()
    assert st["supervisor"]["faults_usb_reader"] == 1 and st["supervisor"]["restarts"] == 1
    assert st["events_tracked"] > 0 and st["state"] == "faulted"
    assert len(eng.reader.free) + len(eng.reader.filled) == len(eng.reader.pool)


def test_the_watchdog_reports_a_stalled_loop(scene):
    cam, eng = make_engine(scene, realtime=True)
    stall = threading.Event()

    def feed(inner, buf, sink):
        if stall.is_set():
            stall.clear()
            time.sleep(WATCHDOG_S + 1.0)          # stuck: transfers pile up meanwhile
        return inner.feed(buf, sink=sink)
    eng.fused = FeedProxy(eng.fused, feed)
    eng.start()
    try:
        wait_for(lambda: eng.fused.tracked > 0, what="tracking")
        stall.set()
        wait_for(lambda: eng.stats()["loop"]["watchdog_stalls"] == 1, what="the watchdog")
        (code, text), = errors(eng)
        assert code == Fault.STALLED and "nothing processed" in text and "alive" in text
        n = eng.fused.tracked
        wait_for(lambda: eng.fused.tracked > n, what="tracking after the stall")
    finally:
        eng.stop()


# ---- the link thread --------------------------------------------------------------------------
class Served:
    def __init__(self, engine):
        self.port = transport.PtyPort()
        self.stop = threading.Event()
        self.server = link.LinkServer(self.port, engine)
        self.thread = threading.Thread(target=self.server.serve, args=(self.stop,), daemon=True)
        self.thread.start()

    def close(self):
        self.stop.set()
        self.thread.join(3)
        self.port.close()


def test_the_program_log_shows_one_line_of_a_kind_per_interval_and_counts_the_rest():
    from firmware_sim.throttle import Throttle
    th = Throttle(every_s=3600)
    assert th("error nonfinite_state", "a") == "a"
    assert th("error nonfinite_state", "b") is None and th("error nonfinite_state", "c") is None
    assert th("error stalled", "d") == "d"                  # another kind: its own budget
    assert th.unshown() == ["error nonfinite_state: 2 more line(s) not shown"]
    assert th.unshown() == []
    th = Throttle(every_s=0)
    assert th("k", "x") == "x" and th("k", "y") == "y"
    th._last["k"][1] = 3                                    # three were held back before
    assert th("k", "z") == "z (3 more like it not shown)"


def test_the_link_survives_snapshots_it_cannot_encode_and_forwards_errors():
    """An energy beyond float32 is sent as inf; a snapshot whose records do not encode is
    dropped and counted; the link thread goes on answering; ERROR reports reach the host."""
    eng = SimEngine()
    s = Served(eng)
    try:
        with Device(s.port.path) as dev:
            tr = np.zeros(26, wire.TRACK_DTYPE)
            rec = wire.quantise_trackers(tr).tobytes()
            eng.telemetry.extend([Snapshot(1000, 1, 1e300, tr, rec, (0, np.full(40, 1e300))),
                                  Snapshot(2000, 1, 0.0, tr, rec[:-3]),
                                  Snapshot(3000, 1, np.nan, tr, rec)])
            eng.supervisor.report(Fault.THREAD_FAULT, "thread x: injected")
            snaps = list(dev.telemetry(seconds=10, count=2))
            assert [sn.t_us for sn in snaps] == [1000, 3000]
            assert snaps[0].mean_energy == np.inf and np.isnan(snaps[1].mean_energy)
            dev.poll(0.2)
            assert dev.energies is not None and np.all(dev.energies[2] == np.inf)
            assert [(e.code, e.text) for e in dev.errors] == [(Fault.THREAD_FAULT, "thread x: injected")]
            assert dev.errors[0].name(Fault) == "thread_fault"
            assert dev.stats()["link.telemetry_errors"] == 1
            dev.ping()
        assert s.thread.is_alive()
    finally:
        s.close()
        eng.close()


def test_a_fault_in_one_tcp_session_closes_that_session_not_the_link():
    eng = SimEngine()
    srv = transport.TcpServer("127.0.0.1", 0)
    stop = threading.Event()
    sup = Supervisor()
    hub = link.Hub(eng, log=lambda line: None)
    th = threading.Thread(target=sup.thread_target("host-link", lambda: hub.serve_tcp(srv, stop),
                                                   stop, max_faults=None), daemon=True)
    th.start()
    try:
        with Device(srv.url):
            victim = hub.sessions[0]
            victim.tick = lambda now: (_ for _ in ()).throw(KeyError("injected"))
            wait_for(lambda: victim not in hub.sessions, what="the session closed")
        assert hub.counts["session_faults"] == 1
        (_, _, code, text), = eng.reports()
        assert code == Fault.THREAD_FAULT and "KeyError" in text and "session closed" in text
        hub.pump, real = (lambda: (_ for _ in ()).throw(ValueError("injected"))), hub.pump
        wait_for(lambda: sup.faults.get("host-link", 0) >= 1, what="the link's supervisor")
        hub.pump = real
        with Device(srv.url) as dev:                 # the link was restarted, answers
            dev.ping()
        assert th.is_alive() and sup.restarts >= 1
    finally:
        stop.set()
        th.join(3)
        srv.close()
        eng.close()


@pytest.mark.parametrize("backend", ["cython", "fixed"])
def test_hostile_models_get_their_nack_code_never_internal(scene, backend):
    """A 20,000-deep TOML and sigma = 1e12: refused as invalid_model (or run) - never an
    exception inside the handler (NACK internal)."""
    cam, eng = make_engine(scene, backend=backend)
    s = Served(eng)
    try:
        with Device(s.port.path) as dev:
            with pytest.raises(Nacked) as e:
                dev.load_model("a = " + "[" * 20_000 + "]" * 20_000 + "\n[[trackers]]\n")
            assert e.value.code == Nack.INVALID_MODEL and "nested too deeply" in e.value.reason
            wide = _model.face26().to_toml().replace("sigma = [", "sigma = [1e12, 0.0, 1e12] #", 1)
            try:
                dev.load_model(wide)
            except Nacked as refused:
                assert refused.code == Nack.INVALID_MODEL, refused
            assert dev.stats()["link.handler_errors"] == 0
    finally:
        s.close()


# ---- a model that drives the kernel to NaN, firmware and host as processes ----------------
@pytest.mark.hil
def test_hil_a_nan_model_does_not_make_the_device_deaf(tmp_path):
    """The reproduction: face26 with stiffness 0.5 uploaded to a running firmware over TCP.
    Refused (NACK invalid_model); the link keeps answering, telemetry keeps coming, every
    snapshot is finite, and a new session can still say HELLO.  (Non-finite state that
    escapes validation anyway is dropped, counted and reported: the tests above.)"""
    fw = Firmware("--source", "sim:face_occlusion", "--seconds", "60", "--listen", "127.0.0.1:0")
    try:
        with Device(fw.path) as dev:
            with pytest.raises(Nacked) as e:
                dev.load_model(nan_models()["face26_stiffness_0.5"])
            assert e.value.code == Nack.INVALID_MODEL and "spring load" in e.value.reason
            snaps = list(dev.telemetry(seconds=1.0))
            assert snaps and all(np.isfinite(s.trackers["x"]).all() for s in snaps)
            st = dev.stats()
            assert st["loop.generation"] == 1 and st["state"] == "streaming"
            assert st["link.telemetry_errors"] == 0 and not dev.errors
        with Device(fw.path) as again:
            assert again.info["model"] == "face26"
            again.ping()
    finally:
        fw.close()
    assert "Traceback" not in fw.err, fw.err[-3000:]
