"""The event stream of the firmware image: the sensor's words as its camera interface
delivers them, in a memory region the firmware reads like a DMA buffer (QEMU loads it
there, springtrack/mcu/boards.py says where).  Layout, little-endian:

    u32 magic "SEVS", u32 format (Format), u32 width, u32 height, u32 bytes of words,
    u32 x 3 reserved (0); then the words

:func:`pack` makes it from an event file: a Prophesee RAW EVT 2.0 / 2.1 recording keeps its
words as they are (what a GenX320 sends), any other file is encoded as EVT 2.0 words
(springtrack.io.evt2.encode), as ``firmware-sim run --source replay:FILE`` does.
"""
from __future__ import annotations

import struct
from enum import IntEnum
from pathlib import Path

MAGIC = struct.unpack("<I", b"SEVS")[0]
HEADER = struct.Struct("<IIIII12x")


class Format(IntEnum):
    EVT2 = 2              # EVT 2.0: 32-bit words
    EVT21 = 21            # EVT 2.1: 64-bit words (GenX320 order)


WORD_BYTES = {Format.EVT2: 4, Format.EVT21: 8}


def pack(path, capacity: int) -> tuple[bytes, dict]:
    """The stream image of event file ``path`` and a summary (format, geometry, words,
    events); ValueError if it does not fit ``capacity`` bytes, naming both sizes."""
    from springtrack import io as stio
    from springtrack.io import evt2
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: event file not found")
    reader = stio.open(path)
    width, height = int(reader.width), int(reader.height)
    if reader.format in ("evt2", "evt21") and not reader.options.get("legacy"):
        words = path.read_bytes()[reader.offset:]
        kind, events = Format.EVT2 if reader.format == "evt2" else Format.EVT21, None
    else:
        ev = reader.read()
        words, kind, events = evt2.encode(ev), Format.EVT2, len(ev)
    return _image(path, words, kind, width, height, events, capacity)


def pack_events(events, width: int, height: int, capacity: int) -> tuple[bytes, dict]:
    """:func:`pack` of an event array (EVENT_DTYPE), encoded as EVT 2.0 words."""
    from springtrack.io import evt2
    return _image("events", evt2.encode(events), Format.EVT2, width, height, len(events),
                  capacity)


def _image(path, words: bytes, kind: Format, width: int, height: int, events, capacity: int):
    need = HEADER.size + len(words)
    if need > capacity:
        raise ValueError(f"{path}: {len(words):,} bytes of {kind.name} words do not fit the "
                         f"board's event stream region of {capacity - HEADER.size:,} bytes; "
                         f"use a shorter recording or an MPS2 board "
                         f"(16 MiB)")
    head = HEADER.pack(MAGIC, int(kind), width, height, len(words))
    return head + words, dict(format=kind.name.lower(), width=width, height=height,
                              words=len(words) // WORD_BYTES[kind], events=events)
