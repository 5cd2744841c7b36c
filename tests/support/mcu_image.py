"""Test helper: the firmware images of springtrack/mcu/firmware/ (built once per test
session) and the face scene they run on (docs/mcu.md, "The firmware image")."""
from __future__ import annotations

import os
import shutil
import sys
import tempfile

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
