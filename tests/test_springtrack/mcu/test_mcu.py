"""The microcontroller build of the fixed-point kernel (springtrack/mcu/, issue: a 32-bit
microcontroller build run bit-identical in an emulator).

* the ELF (Cortex-M4, Cortex-M7, RV32IMAC) links with no runtime at all: no floating-point,
  128-bit or 64-bit-division helper, no FPU instruction; a control shows that one line of
  double arithmetic does need such a helper and so fails to link;
* in the emulator it gives the host's ``--backend fixed`` results bit for bit, on random
  models, parameters and streams (hypothesis) and on the simulator's face and grid scenes,
  down to the track CSV's bytes, and through a rigid move of the instance (fx_move);
* ``springtrack mcu build`` / ``profile`` print their documented last lines, and without
  the ``[mcu]`` extra say how to install it.
"""
import math
import re
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

pytest.importorskip("springtrack.fixed.kernel")
for _mod in ("ziglang", "unicorn", "capstone", "elftools"):
    pytest.importorskip(_mod, reason="the [mcu] extra is not installed")

import springtrack  # noqa: E402
from springtrack.events import EVENT_DTYPE  # noqa: E402
from springtrack.mcu.build import Capacity, cached_build, build  # noqa: E402
from springtrack.mcu.targets import TARGETS  # noqa: E402
from springtrack import limits  # noqa: E402
from springtrack.model import SPRING_BIT, Connection, ShapeModel, TrackerSpec  # noqa: E402
from springtrack.gate import covariance_bias  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402
from springtrack.tracker import Tracker  # noqa: E402
from support.elf import RUNTIME, symbols, text_mnemonics  # noqa: E402
from support.wait import wait_drained

FIELDS = ("t_us", "x", "y", "sxx", "sxy", "syy", "activity", "vx", "vy", "active", "sensitive",
          "energy")

@pytest.mark.slow
@pytest.mark.parametrize("instances", [1, 2])
@pytest.mark.parametrize("target", list(TARGETS))
def test_elf_needs_no_runtime_and_no_fpu(target, instances):
    """The build for face26, and for face26 with grid3x3 (several instances: fx_set), which
    a build for one instance leaves out."""
    from springtrack.instances import ModelSet
    m = springtrack.load_model("face26")
    res = cached_build(target, Capacity.of_model(m if instances == 1 else
                                                 ModelSet([m, springtrack.load_model("grid3x3")])))
    syms = symbols(res.elf)
    assert not [n for n, _, shndx in syms if shndx == "SHN_UNDEF"], "undefined symbols"
    bad = [n for n, _, _ in syms if RUNTIME.match(n)]
    assert not bad, f"runtime helpers in the ELF: {bad}"
    funcs = {n for n, t, _ in syms if t == "STT_FUNC"}
    assert {"mcu_main", "fx_steps", "fx_springs", "update_tracker"} <= funcs
    assert ("fx_set_steps" in funcs) == (instances > 1)
    mn = text_mnemonics(res)
    assert len(mn) > 20
    fpu = {x for x in mn if (x.startswith("v") if res.target.arch == "arm" else
                             re.match(r"^f(add|sub|mul|div|sqrt|cvt|mv|l[wd]|s[wd]|madd)", x))}
    assert not fpu, f"floating-point instructions: {sorted(fpu)}"
    assert 0 < res.flash_bytes < 128 * 1024 and 0 < res.ram_bytes < 96 * 1024


@pytest.mark.slow
def test_control_a_double_needs_a_helper_the_build_cannot_link(tmp_path, monkeypatch):
    """One line of double arithmetic in the same unit asks for a soft-float helper, which
    a build without any runtime cannot link: the checks above can fail."""
    import springtrack.mcu.build as B
    src = tmp_path / "with_double.c"
    src.write_text(B.SOURCES[1].read_text()
                   + "\ndouble fx_leak(double v, double w) { return v / w; }\n"
                   "double (*volatile fx_keep)(double, double) = fx_leak;\n"
                   "void fx_use(void) { fx_keep(1.0, 3.0); }\n")
    entry = tmp_path / "entry.c"
    entry.write_text(B.SOURCES[0].read_text().replace(
        "void mcu_main(void)\n{", "void fx_use(void);\nvoid mcu_main(void)\n{\n    fx_use();"))
    monkeypatch.setattr(B, "SOURCES", [entry, src])
    with pytest.raises(RuntimeError, match=r"__aeabi_ddiv|__divdf3|undefined symbol"):
        build("cortex-m4", tmp_path / "out", Capacity(4, 4, 64, 64))


# ---- bit for bit against the host --------------------------------------------------------
CAP = Capacity(trackers=6, connections=8, width=96, height=80)
SPRINGS = [("euclidean",), ("torsional",), ("cartesian",), ("euclidean", "torsional"),
           ("euclidean", "torsional", "cartesian")]


@st.composite
def scenarios(draw):
    n = draw(st.integers(1, CAP.trackers))
    trackers = []
    for i in range(n):
        sx, sy = draw(st.floats(0.6, 6.0)), draw(st.floats(0.6, 6.0))
        rho = draw(st.floats(-0.9, 0.9))
        trackers.append(TrackerSpec(f"t{i}", draw(st.floats(5.0, 90.0)), draw(st.floats(5.0, 75.0)),
                                    (sx * sx, rho * sx * sy, sy * sy),
                                    draw(st.sampled_from([1.0, 1.0, 0.5, 2.0]))))
    pairs = [(a, b) for a in range(n) for b in range(a + 1, n)]
    chosen = draw(st.lists(st.sampled_from(pairs), unique=True, max_size=CAP.connections)) if pairs else []
    drawn = [(a, b, draw(st.sampled_from(SPRINGS)), draw(st.floats(0.001, 0.3))) for a, b in chosen]
    # stiffnesses within the shared spring bound (springtrack.limits)
    scale = limits.spring_scale(n, [a for a, _, _, _ in drawn], [b for _, b, _, _ in drawn],
                                [sum(SPRING_BIT[k] for k in kinds) for _, _, kinds, _ in drawn],
                                [a for *_, a in drawn], [t.mass for t in trackers])
    conns = [Connection(f"t{a}", f"t{b}", kinds, k * scale) for a, b, kinds, k in drawn]
    model = ShapeModel("random", CAP.width, CAP.height, trackers, conns)
    a1, pt = draw(st.floats(0.01, 0.5)), draw(st.floats(1e-4, 0.5))
    # eq. (4)'s gain within the shared bound: alpha_covariance <= covariance_bias
    a2 = min(draw(st.sampled_from([5e-5, 2e-4, 0.01, 0.3])),
             covariance_bias(a1, -2.0 * math.log(pt)))
    params = dict(alpha_position=a1,
                  alpha_covariance=a2,
                  p_threshold=pt,
                  activity_tau_us=draw(st.sampled_from([300.0, 10_000.0, 1e6])),
                  energy_scale=draw(st.floats(0.5, 4.0)),
                  energy_kind=draw(st.sampled_from(["euclidean", "torsional", "cartesian"])),
                  spring_period=draw(st.integers(1, 40)),
                  # the motion model (eqs. M1-M8), off in half of the examples
                  motion_tau_us=draw(st.sampled_from([0.0, 0.0, 1.0, 250.0, 1000.0, 37_500.5])),
                  polarity_gain=draw(st.sampled_from([0.0, 0.3, 1.0])),
                  prediction_horizon_us=draw(st.sampled_from([0.0, 500.0, 1234.56])))
    k = draw(st.integers(50, 600))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    ev = np.zeros(k, EVENT_DTYPE)
    # some go back; a few empty stretches far beyond the HOLD periods of the sampling rule
    gaps = (rng.random(k) < 0.03) * rng.integers(10_000, 40_000, k)
    ev["t"] = np.cumsum(rng.integers(0, 300, k) + gaps) - rng.integers(0, 2, k) * 50
    ev["x"] = rng.integers(0, CAP.width + 4, k)                                    # some outside
    ev["y"] = rng.integers(0, CAP.height + 4, k)
    ev["p"] = rng.integers(0, 2, k)
    return model, params, ev


def track(model, params, ev, backend, sample_us=200):
    if backend.startswith("mcu"):
        from springtrack.mcu.backend import McuBackend
        tr = Tracker(model, params=params, backend="fixed")
        tr._b = McuBackend(tr.model, tr.params, target=backend.partition(":")[2] or "cortex-m4",
                           capacity=CAP)
    else:
        tr = Tracker(model, params=params, backend=backend)
    out = tr.run(ev, sample_us=sample_us)
    return tr, out


@pytest.mark.slow
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios())
def test_random_models_and_streams_equal_the_host(sc):
    model, params, ev = sc
    a_tr, a = track(model, params, ev, "fixed")
    b_tr, b = track(model, params, ev, "mcu")
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert a_tr.counters == b_tr.counters
    assert np.array_equal(a_tr._b.energies(), b_tr._b.energies())
    assert a_tr._b.mean_energy == b_tr._b.mean_energy and a_tr.last_t == b_tr.last_t


@pytest.mark.slow
def test_parameter_change_and_snapshot_equal_the_host():
    """set_params between events (a new tau rescales activities, a new kind of criterion),
    single steps and snapshots: the same integers on both."""
    m = springtrack.load_model("grid3x3")
    ev, _ = simulate_all("grid_inplane", 0.08, seed=2)
    out = {}
    for b in ("fixed", "mcu"):
        tr = Tracker(m, backend="fixed" if b == "fixed" else "mcu")
        tr.run(ev[:3000], sample_us=500)
        tr.set_params(activity_tau_us=3000.0, energy_kind="cartesian", p_threshold=0.05)
        r = tr.run(ev[3000:], sample_us=500)
        out[b] = (r, tr.state(int(ev["t"][-1]) + 777), tr.counters, tr._b.energies())
    (ra, sa, ca, ea), (rb, sb, cb, eb) = out["fixed"], out["mcu"]
    for f in FIELDS:
        assert np.array_equal(getattr(ra, f), getattr(rb, f)), f
    assert sa.tobytes() == sb.tobytes() and ca == cb and np.array_equal(ea, eb)


@pytest.mark.parametrize("target", list(TARGETS))
def test_face_scene_csv_is_byte_identical(tmp_path, target):
    """`springtrack track --backend mcu` writes exactly the CSV of `--backend fixed` on the
    simulator's face scene (occlusion included), on every core."""
    from springtrack.cli import main
    ev, _ = simulate_all("face_occlusion", 0.12 if target == "cortex-m4" else 0.05, seed=5)
    src = tmp_path / "face.npy"
    np.save(src, ev)
    outs = {}
    for b in ("fixed", "mcu"):
        out = tmp_path / f"{b}.csv"
        argv = ["track", str(src), "--model", "face26", "--backend", b, "--out", str(out),
                "--no-progress", "--sample-us", "500"]
        assert main(argv + (["--mcu-target", target] if b == "mcu" else [])) == 0
        outs[b] = out.read_bytes()
    assert outs["fixed"].count(b"\n") > 26 * 20
    assert outs["mcu"] == outs["fixed"]


@pytest.mark.slow
def test_grid_scene_equals_the_host():
    ev, _ = simulate_all("grid_rot_y", 0.25, seed=6)
    m = springtrack.load_model("grid3x3")
    a_tr, a = Tracker(m, backend="fixed"), None
    a = a_tr.run(ev, sample_us=1000)
    b_tr = Tracker(m, backend="mcu:cortex-m7")
    b = b_tr.run(ev, sample_us=1000)
    assert len(a) > 200
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert a_tr.counters == b_tr.counters


def assert_same(a, b):
    """Two runs (tracker, track before, state at the move, track after) bit for bit."""
    (ta, a1, am, a2), (tb, b1, bm, b2) = a, b
    for f in FIELDS:
        assert np.array_equal(getattr(a1, f), getattr(b1, f)), f
        assert np.array_equal(getattr(a2, f), getattr(b2, f)), f
    assert am.tobytes() == bm.tobytes()
    assert ta.counters == tb.counters and np.array_equal(ta._b.energies(), tb._b.energies())


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios(), st.floats(-15.0, 15.0), st.floats(-15.0, 15.0), st.floats(-180.0, 180.0),
       st.floats(0.8, 1.25))
def test_a_move_on_random_models_and_streams_equals_the_host(sc, dx, dy, deg, k):
    """fx_move in the firmware (MCU_MOVE) between two halves of a random stream: the same
    integers as the host's fixed kernel before, at and after the move."""
    from support.moves import similarity
    model, params, ev = sc
    sim, moved = similarity(model, dx, dy, deg, k)
    runs = []
    for b in ("fixed", "mcu"):
        tr, t1 = track(model, params, ev[:len(ev) // 2], b)
        tr._ib.move(0, sim, moved)
        mid = tr.state(int(ev["t"][len(ev) // 2]))
        runs.append((tr, t1, mid, tr.run(ev[len(ev) // 2:], sample_us=200)))
    assert_same(*runs)


def test_a_move_of_the_face_equals_the_host():
    """face26 on a stream that follows it to its moved place, on the firmware built for
    the model: bit for bit the host's fixed kernel."""
    from support.moves import moved_stream, run_moved, similarity
    f = springtrack.load_model("face26")
    sim, moved = similarity(f, -20.0, 12.0, -25.0, 1.15)
    ev1, ev2 = moved_stream(f, sim, 8000, seed=3)
    runs = [run_moved(b, f, {"spring_period": 5}, sim, moved, ev1, ev2) for b in ("fixed", "mcu")]
    assert len(runs[0][2]) > 5
    assert_same(*[(tr, t1, mid, t2) for t1, mid, t2, tr in runs])


@pytest.mark.slow
def test_after_a_reacquisition_the_firmware_moves_as_the_fixed_kernel():
    """``acquire=True`` on the face jumping 60 px (found moved, moved onto its new place,
    refined): the firmware's track is the host fixed kernel's bit for bit."""
    from support.moves import jump_run
    (ta, a), (tb, b) = jump_run("fixed"), jump_run("mcu")
    assert ta.recovery.moves >= 1 and ta.changes == tb.changes
    for f in FIELDS + ("state",):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert ta.counters == tb.counters


# ---- command line ----------------------------------------------------------------------
# ---- several model instances (springtrack.instances): McuSet == FixedSet ----------------
SET_CAP = Capacity(trackers=6, connections=8, width=96, height=80, instances=3, set_trackers=18)


def run_set(models, params, ev, backend, steps=()):
    """(tracker, tracks) of a set of ``models`` on ``ev`` cut in len(steps) + 1 parts, each
    step (a function of the tracker's instances interface) applied between two parts."""
    tr = Tracker(models, params=params, backend="fixed")
    if backend == "mcu":
        from springtrack.mcu.backend import McuSet
        tr._b = tr._ib = McuSet(tr.models, capacity=SET_CAP)
    parts = np.array_split(ev, len(steps) + 1)
    out = [tr.run(parts[0], sample_us=200)]
    for step, part in zip(steps, parts[1:]):
        step(tr._ib)
        out.append(tr.run(part, sample_us=200))
    return tr, out


def assert_same_sets(a, b):
    (ta, pa), (tb, pb) = a, b
    for x, y in zip(pa, pb):
        for f in FIELDS + ("state",):
            assert np.array_equal(getattr(x, f), getattr(y, f)), f
    assert ta.counters == tb.counters and ta._ib.states() == tb._ib.states()
    assert np.array_equal(ta._b.energies(), tb._b.energies())
    assert ta._ib.mean_energies() == tb._ib.mean_energies()
    assert all(ta._ib.frame(q) == tb._ib.frame(q) for q in range(len(ta.models)))


@pytest.mark.slow
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(scenarios(), min_size=2, max_size=3), st.floats(-10.0, 10.0),
       st.floats(-90.0, 90.0), st.integers(0, 2))
def test_random_instance_sets_equal_the_host(scs, d, deg, lost):
    """Two or three random models in one tracker (the first's parameters and stream, which
    covers the sensor: their trackers compete for its events), with an instance moved, one
    lost then placed again between parts of the stream: the firmware's set (MCU_SET_INIT)
    gives the host's FixedSet integers bit for bit."""
    from support.moves import similarity
    models = [m for m, _, _ in scs]
    _, params, ev = scs[0]
    lost %= len(models)
    sim, moved = similarity(models[-1], d, -d, deg, 1.0)
    back = similarity(models[lost], -d, d, 0.0, 1.0)[1]
    steps = (lambda ib: ib.move(len(models) - 1, sim, moved),
             lambda ib: ib.set_state(lost, 2),
             lambda ib: ib.place(lost, back))
    assert_same_sets(*(run_set(models, params, ev, b, steps) for b in ("fixed", "mcu")))


@pytest.mark.slow
def test_a_face_and_a_grid_equal_the_host():
    """A face and a grid with their presets' own parameters, on the build for exactly this
    set (Capacity.of_model): the rows, states and counters of the host, bit for bit."""
    from springtrack.model import face26, grid3x3
    from springtrack.sim.synthetic import blob_stream
    g = grid3x3(cx=90, cy=120, spacing=30, sigma_px=4, width=400, height=240)
    f = face26(cx=290, cy=120, scale=110, width=400, height=240)
    ev = np.sort(np.concatenate([blob_stream(g, 2500, noise=0.1, seed=1)[0],
                                 blob_stream(f, 5000, noise=0.1, seed=2)[0]]), order="t")
    runs = []
    for b in ("fixed", "mcu"):
        tr = Tracker([g, f], params={"spring_period": 5}, backend=b)
        runs.append((tr, [tr.run(ev, sample_us=1000)]))
    assert type(runs[1][0]._b).__name__ == "McuSet" and len(runs[0][1][0]) > 10
    assert runs[1][0]._b.build.capacity.instances == 2
    assert_same_sets(*runs)


@pytest.mark.slow
def test_cli_build_prints_flash_and_ram(tmp_path, capsys):
    from springtrack.cli import main
    assert main(["mcu", "build", "--target", "rv32imac", "--out", str(tmp_path), "--model",
                 "grid3x3"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    m = re.fullmatch(r"flash_bytes=(\d+) ram_bytes=(\d+)", last)
    assert m and int(m.group(1)) > 10_000 and int(m.group(2)) > 1_000
    assert (tmp_path / "springtrack-rv32imac.elf").exists()


def test_cli_profile_counts_instructions(tmp_path, capsys):
    from springtrack.cli import main
    ev, _ = simulate_all("grid_inplane", 0.05, seed=1)
    src = tmp_path / "grid.npy"
    np.save(src, ev)
    assert main(["mcu", "profile", str(src), "--model", "grid3x3", "--target", "cortex-m4",
                 "--events", "400"]) == 0
    out = capsys.readouterr().out
    n = float(re.search(r"instructions_per_event=([0-9.]+)", out.strip().splitlines()[-1]).group(1))
    assert 30 < n < 20_000
    assert "in spring updates" in out and "cycles per instruction" in out


def test_missing_extra_names_the_install_command(tmp_path, monkeypatch, capsys):
    """Without the [mcu] extra (its packages unimportable) the commands and the backend
    fail with a message naming pip install 'springtrack[mcu]', not a traceback."""
    from springtrack.cli import main
    for mod in ("ziglang", "unicorn"):
        monkeypatch.setitem(sys.modules, mod, None)           # import raises ImportError
    assert main(["mcu", "build", "--target", "cortex-m4", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "pip install 'springtrack[mcu]'" in err and "ziglang" in err
    with pytest.raises(ValueError, match=r"pip install 'springtrack\[mcu\]'"):
        Tracker("grid3x3", backend="mcu")


# ---- the firmware loop with the microcontroller build in the middle ---------------------
def run_firmware(ev, backend, model="face26"):
    import threading
    from firmware_sim import camera as camusb
    from firmware_sim.loop import FirmwareLoop
    from firmware_sim.simcam import SimBackend, SimCamera
    from firmware_sim.sources import events_source
    cam = SimCamera(events_source(ev, 2048), realtime=False)
    be = SimBackend(cam)
    eng = FirmwareLoop(lambda: camusb.Camera.open("ccam_atis", backend=be), model,
                       telemetry_period_us=1000, nbuf=256, transfer_bytes=16384, lossless=True,
                       record=True, backend=backend)
    eng.start()
    wait_drained(cam, eng, timeout=120)
    eng.stop()
    assert not any(t.name in ("usb-reader", "fused-loop") for t in threading.enumerate())
    return eng


def test_firmware_loop_with_the_mcu_build_equals_the_fixed_kernel():
    """Simulated camera -> USB words -> CCam decoding -> the emulated Cortex-M4 kernel ->
    telemetry: the same samples and the same TELEMETRY records, byte for byte, as the
    fixed kernel in the fused loop (whose records the host's C packer makes)."""
    ev, _ = simulate_all("face_occlusion", 0.1, seed=5)
    got = {}
    for b in ("fixed", "mcu"):
        eng = run_firmware(ev, b)
        s = eng.stats()
        assert s["events_tracked"] == len(ev) and s["transfers_dropped"] == 0
        assert s["kernel"]["backend"] == b
        got[b] = (eng.poll_telemetry(10 ** 6), s["kernel"])
    (fa, ka), (fb, kb) = got["fixed"], got["mcu"]
    assert len(fa) == len(fb) > 50
    for a, b in zip(fa, fb):
        assert a.t_us == b.t_us and a.records == b.records
        assert a.mean_energy == b.mean_energy
        for f in a.trackers.dtype.names:             # field by field: TRACK_DTYPE has padding
            assert np.array_equal(a.trackers[f], b.trackers[f]), f
    assert {k: v for k, v in ka.items() if k != "backend"} == {k: v for k, v in kb.items()
                                                                 if k != "backend"}


@pytest.mark.slow
@pytest.mark.hil
def test_hil_chain_with_the_mcu_build_records_what_the_fixed_kernel_does(tmp_path):
    """The whole hardware-in-the-loop chain as separate processes: firmware-sim (simulated
    camera, USB words, decoding, the emulated Cortex-M4 kernel, telemetry) on a pty, hostctl
    recording the telemetry; the recording equals, byte for byte, the one of the same chain
    with --backend fixed."""
    from hostctl import Device
    from hostctl.record import save
    from firmware_sim import transport
    from support.fwproc import Firmware
    recs = {}
    for b in ("fixed", "mcu"):
        pty = transport.PtyPort()
        try:
            fw = Firmware("--source", "sim:face_occlusion", "--max-speed", "--seconds", "0.15",
                          "--backend", b, "--port", pty.path, "--wait-start", announce=False)
            try:
                snaps = []
                with Device(pty, timeout=0.05, retries=400) as dev:
                    dev.timeout = 0.5
                    info = dev.info
                    dev.start()
                    while True:             # until the firmware says the scene ended
                        got = list(dev.telemetry(seconds=0.3))
                        snaps += got
                        if dev.stream_ended and not got:
                            break
                    lost = dev.link_counters()["lost"]
                    dev.shutdown()          # it serves its link until told to end
                fw.proc.wait(60)
            finally:
                fw.close()
        finally:
            pty.close()
        assert fw.proc.returncode == 0, fw.err[-2000:]
        assert lost == 0 and len(snaps) == 149
        save(tmp_path / f"{b}.csv", snaps, info)
        recs[b] = (tmp_path / f"{b}.csv").read_bytes()
    assert recs["mcu"] == recs["fixed"]


def test_a_faulting_firmware_is_a_clear_error():
    """A fault in the emulated core (here: a jump to unmapped memory) is a RuntimeError
    naming the core and the command."""
    from springtrack.mcu import emulator as E
    from springtrack.mcu.backend import McuBackend
    m = springtrack.load_model("grid3x3")
    be = McuBackend(m, Tracker(m).params)
    be.emu.main = E.FLASH_BASE - 0x100                    # no code there
    with pytest.raises(RuntimeError, match=r"cortex-m4 firmware faulted in command 4"):
        be.emu.call(E.MCU_STEP)


@pytest.mark.parametrize("preset", ["grid3x3", "face26"])
def test_the_firmware_stays_within_the_bound_of_the_float_kernel(preset):
    """The bound of docs/fixed_point.md, checked on the firmware itself (RV32IMAC here; the
    other cores equal it bit for bit): positions, covariances, flags, no saturation."""
    from support.fixed_bound import compare, scene_stream, violations
    model, ev = scene_stream(preset, 20_000, seed=7)
    res = compare(model, ev, sample_us=1000, backend="mcu:rv32imac")
    assert res["samples"] > 60 and not violations(res), violations(res)
    assert sum(v for k, v in res["counters_fixed"].items() if k.startswith("saturated_")) == 0


MOTION = dict(motion_tau_us=1000.0, polarity_gain=1.0)


def test_the_motion_model_equals_the_host(data_file, tmp_path):
    """The motion model (eqs. M1-M8, fixed/csrc/fixed_motion.c) on the microcontroller:
    the real dot of evt2_sample.raw (a one-tracker model placed on it; its first 60,000
    events, ~6 ms at ~13,000 px/s) and the simulator's face with its occluder (springs,
    eq. M8's pull), velocities included, bit for bit with the host's fixed kernel."""
    import springtrack.io
    from support.dot_truth import dot_model_toml, dot_truth
    events = springtrack.io.open(data_file("evt2_sample.raw")).read()
    path = tmp_path / "dot.toml"
    path.write_text(dot_model_toml(dot_truth(events)))
    face, _ = simulate_all("face_occlusion", 0.12, seed=5)
    for model, ev in ((springtrack.load_model(str(path)), events[:60_000]),
                      (springtrack.load_model("face26"), face)):
        a_tr, b_tr = (Tracker(model, params=MOTION, backend=b) for b in ("fixed", "mcu"))
        a, b = (tr.run(ev, sample_us=200) for tr in (a_tr, b_tr))
        assert np.abs(a.vx).max() > 1000
        for f in FIELDS:
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
        assert a_tr.counters == b_tr.counters
