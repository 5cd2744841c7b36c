"""The hand-written C peer trackers of benchmarks/ctrackers/, built and loaded through ctypes.

    from _ctrackers import CTracker, PACKED
    tr = CTracker("plain", model, params)        # or "simd" (AVX-512 or AVX2 intrinsics)
    tr.process(packed_events)                    # PACKED records, in time order
    tr.state(t)                                  # (n, 6): x, y, sxx, sxy, syy, activity

Each peer is compiled on first use with the compiler Python's extensions use, the
kernels' own flags (setup.py's COMPILE_ARGS: -O3, no FMA contraction) and -march=native
(the SIMD peer takes AVX-512 where the processor has it, else AVX2), into a cache
directory keyed by the sources and flags.  Benchmark-only: nothing here is installed.
"""
from __future__ import annotations

import ast
import ctypes
import hashlib
import shlex
import subprocess
import sysconfig
import tempfile
from pathlib import Path

import numpy as np

from springtrack.gate import covariance_bias

HERE = Path(__file__).resolve().parent
SRC = HERE / "ctrackers"
# kind: (source, -march); the -avx2 kinds are the builds for AVX2 (x86-64-v3), where the
# processor or valgrind (benchmarks/_counts.py) has no AVX-512, and for the test that
# both builds track alike
PEERS = {"plain": ("plain.c", "native"), "simd": ("simd.c", "native"),
         "plain-avx2": ("plain.c", "x86-64-v3"), "simd-avx2": ("simd.c", "x86-64-v3")}
# the packed record of expelliarmus / tonic / numpy files (peer.h PeerEvent)
PACKED = np.dtype([("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")])


def kernel_flags() -> list[str]:
    """setup.py's COMPILE_ARGS: the flags the kernels are compiled with."""
    tree = ast.parse((HERE.parent / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "COMPILE_ARGS"
                                                for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise RuntimeError("setup.py has no COMPILE_ARGS")


def compile_command(kind: str, out: Path) -> list[str]:
    cc = shlex.split(sysconfig.get_config_var("CC") or "cc")
    src, march = PEERS[kind]
    flags = [f for f in kernel_flags() if not f.startswith("-march=")] + [f"-march={march}"]
    return [*cc, *flags, "-std=gnu11", "-fPIC", "-shared", "-o", str(out),
            str(SRC / src), "-lm"]


def build(kind: str) -> Path:
    """The peer's shared library, compiled if not cached."""
    probe = compile_command(kind, Path("x"))
    key = hashlib.sha256(" ".join(probe).encode() + b"".join(
        p.read_bytes() for p in sorted(SRC.glob("*.[ch]")))).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / f"springtrack_ctracker_{kind}_{key}.so"
    if not out.exists():
        tmp = out.with_suffix(".tmp.so")
        subprocess.run(compile_command(kind, tmp), check=True)
        tmp.rename(out)
    return out


_LIBS: dict[str, ctypes.CDLL] = {}


def library(kind: str) -> ctypes.CDLL:
    if kind not in _LIBS:
        lib = ctypes.CDLL(str(build(kind)))
        P, I64 = ctypes.c_void_p, ctypes.c_int64
        lib.peer_new.restype = P
        lib.peer_new.argtypes = [ctypes.c_int] * 4 + [P] * 4
        lib.peer_free.argtypes = [P]
        lib.peer_run.restype = I64
        lib.peer_run.argtypes = [P, P, I64]
        lib.peer_state.argtypes = [P, I64, P, P]
        lib.peer_isa.restype = ctypes.c_char_p
        _LIBS[kind] = lib
    return _LIBS[kind]


class CTracker:
    """One peer tracker on ``model`` (a springtrack ShapeModel) with ``params`` (Params)."""

    def __init__(self, kind: str, model, params):
        self.lib = library(kind)
        a = model.arrays()
        self.n, nc = len(a["x"]), len(a["ca"])
        p = params
        par = np.array([p.alpha_position, p.alpha_covariance, p.gate_d2, p.activity_tau_us,
                        p.alpha_covariance / covariance_bias(p.alpha_position, p.gate_d2),
                        p.sigma_min_px, p.sigma_max_px, p.energy_scale, p.energy_gain,
                        p.spring_period, p.energy_kind_index, p.pull_similarity,
                        p.cartesian_similarity], np.float64)
        tr = np.ascontiguousarray(np.stack([a[k] for k in ("x", "y", "sxx", "sxy", "syy",
                                                           "mass", "gdx0", "gdy0")], 1))
        ci = np.ascontiguousarray(np.stack([a["ca"], a["cb"], a["kinds"]], 1), np.int32)
        cd = np.ascontiguousarray(np.stack([a[k] for k in ("stiffness", "l0", "th0", "dx0",
                                                           "dy0")], 1), np.float64)
        self._keep = (par, tr, ci, cd)
        self._counters = np.zeros(6, np.int64)
        self.ptr = self.lib.peer_new(self.n, nc, model.width, model.height, par.ctypes.data,
                                     tr.ctypes.data, ci.ctypes.data, cd.ctypes.data)
        if not self.ptr:
            raise ValueError(f"model too large for the C peer ({self.n} trackers, {nc} "
                             f"connections)")

    def __del__(self):
        if getattr(self, "ptr", None):
            self.lib.peer_free(self.ptr)
            self.ptr = None

    def process(self, events: np.ndarray) -> None:
        """Track ``events``: a C-contiguous array of :data:`PACKED` records."""
        if events.dtype != PACKED or not events.flags.c_contiguous:
            raise TypeError(f"the C peers read {PACKED} records, C-contiguous")
        self.lib.peer_run(self.ptr, events.ctypes.data, len(events))

    def state(self, t: int) -> np.ndarray:
        """(n, 6) array: x, y, sxx, sxy, syy and the activity at time t of every tracker."""
        out = np.empty((self.n, 6))
        self.lib.peer_state(self.ptr, int(t), out.ctypes.data, self._counters.ctypes.data)
        return out

    @property
    def counters(self) -> dict:
        self.state(0)
        c = self._counters
        return dict(events_valid=int(c[0]), events_assigned=int(c[1]),
                    skipped_back_in_time=int(c[2]), skipped_outside_sensor=int(c[3]),
                    spring_updates=int(c[4]), reindexed=int(c[5]))

    @property
    def isa(self) -> str:
        """What the peer's scan and springs are written with (e.g. "AVX-512 scan, ...")."""
        return self.lib.peer_isa().decode()


def agreement(kind: str, model, params, events: np.ndarray, sample_us: int = 1000) -> dict:
    """How closely the peer tracks like springtrack's float64 kernel on ``events`` (PACKED),
    both on ``model`` (a preset name or ShapeModel) with ``params`` (None: the defaults):
    both sampled every ``sample_us`` (the state after all events with t < the sample time),
    the largest differences over all samples and trackers: positions (px), covariances
    relative to their size, activities relative; and whether the counters agree."""
    import springtrack
    ref = springtrack.Tracker(model, params)
    track = ref.run(events, sample_us=sample_us)
    peer = CTracker(kind, ref.model, ref.params)
    cuts = np.searchsorted(events["t"], track.t_us, side="left")
    pos, dx, dcov, dact = 0, 0.0, 0.0, 0.0
    for k, (t, cut) in enumerate(zip(track.t_us, cuts)):
        peer.process(events[pos:cut])
        pos = cut
        st = peer.state(t)
        dx = max(dx, np.abs(st[:, 0] - track.x[k]).max(), np.abs(st[:, 1] - track.y[k]).max())
        scale = np.sqrt(track.sxx[k] * track.syy[k])
        for j, f in ((2, "sxx"), (3, "sxy"), (4, "syy")):
            dcov = max(dcov, (np.abs(st[:, j] - getattr(track, f)[k]) / scale).max())
        act = track.activity[k]
        dact = max(dact, (np.abs(st[:, 5] - act) / np.maximum(act, 1e-300)).max())
    peer.process(events[pos:])
    ref.process(events[:0])
    theirs = peer.counters
    theirs.pop("reindexed")
    ours = {k: ref.counters[k] for k in theirs}
    return dict(samples=len(track), position_px=dx, covariance_rel=dcov, activity_rel=dact,
                counters_equal=ours == theirs, counters=theirs)
