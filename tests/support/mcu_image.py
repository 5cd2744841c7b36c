"""Test helper: the firmware images of springtrack/mcu/firmware/ (built once per test
session) and the face scene they run on (docs/mcu.md, "The firmware image")."""
from __future__ import annotations

import os
import shutil
import sys
import tempfile

import numpy as np
import pytest

from springtrack import io as sio
from springtrack.model import face26
from springtrack.sim.sensor import simulate_all

W, H = 304, 240
_images = {}


def require_qemu():
    """At a test module's top: skip it without the fixed kernel, the [mcu] extra or QEMU
    (Debian's qemu-system-arm, which `make test` installs), except in CI (CI=true), where a
    missing QEMU fails."""
    pytest.importorskip("springtrack.fixed.kernel")
    for mod in ("ziglang", "elftools", "capstone"):
        pytest.importorskip(mod, reason="the [mcu] extra is not installed")
    if shutil.which("qemu-system-arm") is None:
        if os.environ.get("CI") == "true":
            pytest.fail("qemu-system-arm is missing in CI: `make test` installs it "
                        "(apt-get install qemu-system-arm)", pytrace=False)
        pytest.skip("qemu-system-arm is not installed (apt-get install qemu-system-arm; "
                    "`make test` installs it as root)", allow_module_level=True)


def image(board):
    """The board's image with the default capacity (built once per test session)."""
    from springtrack.mcu.image import build_image
    if board not in _images:
        _images[board] = build_image(board, tempfile.mkdtemp(prefix=f"fw-{board}-"))
    return _images[board]


def write_scene(d):
    """0.2 s of the face scene in ``d`` as RAW EVT 2.0 (face.raw, what a Prophesee sensor
    sends) and EVT 2.1 (face21.raw, a GenX320's word format), and face26 on its sensor
    (face.toml); returns the events."""
    ev, _ = simulate_all("face_occlusion", 0.2, seed=5)
    sio.write(d / "face.raw", ev, W, H)
    sio.write(d / "face21.raw", ev, W, H, format="evt21")
    (d / "face.toml").write_text(face26(cx=W / 2, cy=H / 2, width=W, height=H).to_toml())
    return ev


def springtrack_cmd(*args):
    exe = os.path.join(os.path.dirname(sys.executable), "springtrack")
    return ([exe] if os.path.exists(exe) else [sys.executable, "-m", "springtrack.cli"]) + list(args)


def same_snapshots(a, b):
    """Two telemetry recordings (hostctl Snapshots) are the same, snapshot for snapshot:
    time, mean energy and every tracker field."""
    assert len(a) == len(b) > 150
    for x, y in zip(a, b):
        assert x.t_us == y.t_us and x.mean_energy == y.mean_energy
        for f in x.trackers.dtype.names:
            assert np.array_equal(x.trackers[f], y.trackers[f]), (x.t_us, f)


def run_to_end(dev):
    """START, then hostctl's snapshots until the device says the stream ended."""
    dev.start()
    snaps = []
    while True:
        got = list(dev.telemetry(seconds=0.5))
        snaps += got
        if dev.stream_ended and not got:
            return snaps


def host_library(out_dir):
    """The image's parameter conversion (firmware/xfloat.c, param_words.c) compiled for
    this machine as a shared library, with the headers the image build generates."""
    import ctypes
    import subprocess
    from pathlib import Path
    from springtrack.mcu import params_header, wire_header
    from springtrack.mcu.build import zig_cc
    from springtrack.mcu.image import FIRMWARE
    out = Path(out_dir)
    (out / "wire_codes.h").write_text(wire_header.header())
    (out / "param_specs.h").write_text(params_header.header())
    lib = out / "param_words.so"
    subprocess.run([*zig_cc(), "-O2", "-shared", "-fPIC", "-Wall", "-Wextra", "-Werror",
                    f"-I{out}", f"-I{FIRMWARE}", str(FIRMWARE / "xfloat.c"),
                    str(FIRMWARE / "param_words.c"), "-o", str(lib)], check=True)
    return ctypes.CDLL(str(lib))
