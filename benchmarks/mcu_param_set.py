"""What one PARAM_SET by name costs the firmware image's core: the image runs in QEMU with
``-icount shift=0`` (one instruction per ns of virtual time), hostctl sets parameters by
name, and STATS ``param_ticks`` gives the SysTick ticks the image spent computing the
kernel's words (Board.qemu_tick_ns instructions each).  Prints one line per parameter for
docs/mcu.md ("PARAM_SET by name"); writes nothing.

Run: .venv/bin/python benchmarks/mcu_param_set.py [--board mps2-an386]   (about 20 s)
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from hostctl import Device  # noqa: E402
from springtrack.mcu.boards import BOARDS  # noqa: E402
from springtrack.mcu.image import build_image  # noqa: E402
from springtrack.mcu.qemu import Qemu  # noqa: E402
from springtrack.model import face26  # noqa: E402
from springtrack.sim.sensor import simulate_all  # noqa: E402

CHANGES = (("energy_gain", 0.3), ("p_threshold", 0.05), ("spring_period", 40),
           ("activity_tau_us", 5000.0))
W, H = 304, 240


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--board", default="mps2-an386",
                    choices=[b for b, v in BOARDS.items() if v.qemu_tick_ns])
    args = ap.parse_args()
    tick_ns = BOARDS[args.board].qemu_tick_ns
    res = build_image(args.board, tempfile.mkdtemp(prefix="param-set-"))
    ev, _ = simulate_all("face_occlusion", 0.05, seed=5)
    with Qemu(res.elf, args.board, (ev, W, H), icount=True) as q:
        with Device(q.link, timeout=1.0, retries=30) as dev:
            dev.load_model(face26(cx=W / 2, cy=H / 2, width=W, height=H))
            for name, value in CHANGES:
                dev.set(name, value)
                ticks = dev.stats()["param_ticks"]
                print(f"{args.board} PARAM_SET {name}={value!r}: {ticks} ticks = "
                      f"{ticks * tick_ns:,} instructions")


if __name__ == "__main__":
    main()
