"""Instructions per event of the whole firmware image (image.py): the EVT 2.0 decoder, the
kernel, the sampling and the telemetry records, run in QEMU with ``-icount shift=0`` (its
virtual clock advances one ns per instruction), counted by the image itself: its SysTick
ticks around each batch of decoding and tracking (STATS ``work_ticks``), Board.qemu_tick_ns
instructions each.  The host link's own work (frames, the UART) is outside the count.

The model is uploaded (a words image) and the stream started over the host link as a host
does, by the few requests below (springtrack.wire).
"""
from __future__ import annotations

import dataclasses
import tempfile
import time

from .. import wire
from . import words as wire_image
from ..wire import MsgType
from .boards import board as get_board
from .build import Capacity
from .image import build_image
from .qemu import Qemu

RUN_S = 600.0             # the stream must end within this (QEMU runs ~10-50 M instr/s)


class _Link:
    """A host end of the link for the profile: one request at a time."""

    def __init__(self, url: str):
        import serial
        self.port = serial.serial_for_url(url, timeout=0.05)
        self.reader = wire.FrameReader(hunting=True)
        self.seq = 0
        self.ended = False
        self.port.write(b"\x00")

    def request(self, mtype, payload: bytes = b"", timeout: float = 120.0) -> list:
        """Send; the frames answering it (ACK, INFO, or every STATS part); RuntimeError on
        a NACK or no answer."""
        self.seq = (self.seq + 1) & 0xFFFF
        frame = wire.encode_frame(mtype, self.seq, payload)
        got, end, again = [], time.monotonic() + timeout, 0.0
        while time.monotonic() < end:
            if not got and time.monotonic() >= again:     # sent again each second: bytes
                self.port.write(frame)                    # sent while the image boots are
                again = time.monotonic() + 1.0            # lost; a repeat is answered from
                                                          # its reply cache
            for f in self.reader.feed(self.port.read(65536)):
                if f.type == MsgType.NOTICE and wire.decode_notice(f.payload).code \
                        == wire.Notice.STREAM_ENDED:
                    self.ended = True
                if f.type == MsgType.INFO and mtype == MsgType.HELLO:
                    return [f]
                if f.type not in wire.REPLY_TYPES or wire.decode_reply(f).seq != self.seq:
                    continue
                r = wire.decode_reply(f)
                if isinstance(r, wire.Refusal):
                    raise RuntimeError(f"{MsgType(mtype).name} refused ({r.code_name}): "
                                       f"{r.reason}")
                got.append(r)
                if not isinstance(r, wire.ReplyPart) or len(got) == r.parts:
                    return got
        raise RuntimeError(f"the image did not answer {MsgType(mtype).name} in {timeout:g} s")

    def upload(self, image: bytes) -> None:
        self.request(MsgType.MODEL_BEGIN, wire.encode_model_begin(image))
        for off in range(0, len(image), wire.MODEL_CHUNK_SIZE):
            self.request(MsgType.MODEL_CHUNK,
                         wire.encode_model_chunk(off, image[off:off + wire.MODEL_CHUNK_SIZE]))
        self.request(MsgType.MODEL_COMMIT, wire.encode_model_begin(image))

    def stats(self) -> dict:
        out = {}
        for part in self.request(MsgType.STATS):
            out.update(part.items)
        return out


def profile_image(model, params, events, board_name: str, sensor=None) -> dict:
    """Run ``events`` (EVENT_DTYPE, on the model's sensor) through the image of
    ``board_name`` built for ``model`` (its sensor, or ``sensor`` = (w, h) if larger) with
    ``params``; returns the figures (instructions_per_event, decode_per_event, ram_bytes,
    flash_bytes, stack_used_bytes, objects, stats)."""
    b = get_board(board_name)
    if not b.qemu_tick_ns:
        raise ValueError(f"{board_name}: QEMU's SysTick rate is not known for this model; "
                         f"profile on an MPS2 board (the same core's code)")
    cap = Capacity.of_model(model)
    if sensor is not None:
        cap = dataclasses.replace(cap, width=max(cap.width, sensor[0]),
                                  height=max(cap.height, sensor[1]))
    image, nc = wire_image.words_image(model.to_toml().encode())
    with tempfile.TemporaryDirectory(prefix="springtrack-profile-") as d:
        res = build_image(board_name, d, cap)
        with Qemu(res.elf, board_name, (events, model.width, model.height), icount=True) as q:
            link = _Link(q.link)
            link.request(MsgType.HELLO, wire.encode_hello("springtrack-profile"))
            link.upload(image)
            link.upload(wire_image.params_image(params.as_dict(), nc))
            link.request(MsgType.START)
            end = time.monotonic() + RUN_S
            while not link.ended:
                if time.monotonic() > end:
                    raise RuntimeError(f"the image did not finish the stream in {RUN_S:g} s")
                st = link.stats()
                link.ended = link.ended or st["state"] == "ended"
                time.sleep(0.2)
            st = link.stats()
            link.port.close()
    n = max(int(st["events_tracked"]), 1)
    return dict(board=board_name, target=b.target, events=int(st["events_tracked"]),
                instructions_per_event=st["work_ticks"] * b.qemu_tick_ns / n,
                decode_per_event=st["decode_ticks"] * b.qemu_tick_ns / n,
                tick_instructions=b.qemu_tick_ns, ram_bytes=res.ram_bytes,
                flash_bytes=res.flash_bytes, stack_used_bytes=int(st["stack_used_bytes"]),
                stack_bytes=res.sections.get(".stack", 0), objects=res.objects,
                capacity=res.capacity, stats=st)
