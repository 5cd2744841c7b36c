"""Instructions per event of the whole firmware image (image.py): the EVT 2.0 decoder, the
kernel, the sampling and the telemetry records, run in QEMU with ``-icount shift=0`` (its
virtual clock advances one ns per instruction), counted by the image itself: its SysTick
ticks around each batch of decoding and tracking (STATS ``work_ticks``), Board.qemu_tick_ns
instructions each.  The host link's own work (frames, the UART) is outside the count.

The model is uploaded and the stream started over the host link, with hostctl's Device,
as a user does (``springtrack mcu profile --board``)."""
from __future__ import annotations

import dataclasses
import tempfile
import time

from .boards import board as get_board
from .build import Capacity
from .image import build_image
from .qemu import Qemu

RUN_S = 600.0             # the stream must end within this (QEMU runs ~10-50 M instr/s)


def profile_image(model, params, events, board_name: str, sensor=None) -> dict:
    """Run ``events`` (EVENT_DTYPE, on the model's sensor) through the image of
    ``board_name`` built for ``model`` (its sensor, or ``sensor`` = (w, h) if larger);
    returns the figures (instructions_per_event, ram_bytes, flash_bytes, stack_used_bytes,
    objects, stats)."""
    from hostctl import Device           # the host end of the link
    b = get_board(board_name)
    if not b.qemu_tick_ns:
        raise ValueError(f"{board_name}: QEMU's SysTick rate is not known for this model; "
                         f"profile on an MPS2 board (the same core's code)")
    cap = Capacity.of_model(model)
    if sensor is not None:
        cap = dataclasses.replace(cap, width=max(cap.width, sensor[0]),
                                  height=max(cap.height, sensor[1]))
    with tempfile.TemporaryDirectory(prefix="springtrack-profile-") as d:
        res = build_image(board_name, d, cap)
        with Qemu(res.elf, board_name, (events, model.width, model.height), icount=True) as q:
            with Device(q.link, timeout=2.0, retries=5) as dev:
                dev.load_model(model)
                dev.set(**params.as_dict())
                dev.start()
                end = time.monotonic() + RUN_S
                while not dev.stream_ended:
                    if time.monotonic() > end:
                        raise RuntimeError(f"the image did not finish the stream in {RUN_S:g} s")
                    for _ in dev.telemetry(seconds=0.5):
                        pass
                st = dev.stats()
    n = max(int(st["events_tracked"]), 1)
    return dict(board=board_name, target=b.target, events=int(st["events_tracked"]),
                instructions_per_event=st["work_ticks"] * b.qemu_tick_ns / n,
                decode_per_event=st["decode_ticks"] * b.qemu_tick_ns / n,
                tick_instructions=b.qemu_tick_ns, ram_bytes=res.ram_bytes,
                flash_bytes=res.flash_bytes, stack_used_bytes=int(st["stack_used_bytes"]),
                stack_bytes=res.sections.get(".stack", 0), objects=res.objects,
                capacity=res.capacity, stats=st)
