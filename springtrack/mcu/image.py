"""A bootable firmware image for a board (springtrack/mcu/boards.py): start-up code, the
board's UART, the host link in C and the fixed-point kernel with its event decoder
(springtrack/mcu/firmware/, entry.c, fixed/csrc/fixed_step.c, fixed_telemetry.c), linked at
the board's memory map into ``DIR/firmware.elf``.

    >>> res = build_image("netduinoplus2", "out/")             # doctest: +SKIP
    >>> res.elf, res.flash_bytes, res.ram_bytes                # doctest: +SKIP

The link's codes and sizes come from springtrack/wire.py as the generated ``wire_codes.h``
(springtrack/mcu/wire_header.py), the parameters' names, ranges and word layout from
springtrack/params.py and fixed/q.py as ``param_specs.h`` (params_header.py), written
beside the ELF.  Same flags as the kernel's
build (build.py): no heap, no libc, no compiler runtime, no floating point.
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

from .boards import board as get_board
import dataclasses

from .build import (CFLAGS, CSRC, FIXED, HERE, SOURCES as KERNEL_SOURCES, BuildResult,
                    Capacity, cache_root, measure, zig_cc)
from .targets import target as get_target
from . import params_header
from .wire_header import header

FIRMWARE = HERE / "firmware"
SOURCES = sorted(FIRMWARE.glob("*.c")) + KERNEL_SOURCES     # the kernel's: entry.c and fixed/csrc
ROOT = HERE.parent.parent                  # for "springtrack/io/evt2_types.h"
STACK_BYTES = 6144             # face26 uses 4.4 KB (STATS stack_used_bytes)
# entry.c's I/O buffers: one snapshot row per MCU_RUN, 64 events per batch (the capacity's
# rows and events), no word buffer (the firmware loads the kernel from its upload buffer),
# only the criterion's energy kind in a row (the one TELEMETRY reports)
IO_DEFINES = ["-DMCU_WORDS=1", "-DMCU_ALL_ENERGIES=0"]
ELF_NAME = "firmware.elf"
# a board image's default capacity: 64 trackers, 128 connections, a 320 x 320 sensor
# (GenX320); --model sizes it to a model instead
DEFAULT_CAPACITY = Capacity(width=320, height=320)


def key_header(key: bytes | None) -> str:
    """``link_key.h``: the host link's HMAC key built into the image (none: an unkeyed
    link).  A key longer than SHA-256's 64-byte block is replaced by its hash, as HMAC
    (RFC 2104) does itself, so the image's HMAC takes keys of at most 64 bytes."""
    import hashlib
    if key is None:
        return "#define LINK_KEY_LEN 0\nstatic const unsigned char link_key[1] = {0};\n"
    if len(key) > 64:
        key = hashlib.sha256(key).digest()
    body = ", ".join(str(b) for b in key)
    return (f"/* the host link's key: keep this directory, and the ELF, secret */\n"
            f"#define LINK_KEY_LEN {len(key)}\n"
            f"static const unsigned char link_key[{len(key)}] = {{{body}}};\n")


def build_image(board_name: str, out_dir, capacity: Capacity | None = None,
                key: bytes | None = None) -> BuildResult:
    """Compile and link the image (``key``: the host link's HMAC key, at least
    wire.MIN_KEY_BYTES; every host frame but HELLO must then be signed); returns the ELF's
    path and its flash / RAM use."""
    from .. import wire
    wire.check_key(key)
    b = get_board(board_name)
    tgt = get_target(b.target)
    cap = dataclasses.replace(capacity or DEFAULT_CAPACITY, events=64, rows=1)
    cap.check()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "wire_codes.h").write_text(header())
    (out / "param_specs.h").write_text(params_header.header())
    (out / "link_key.h").write_text(key_header(key))
    script = out / "firmware.ld"
    script.write_text((FIRMWARE / "firmware.ld").read_text()
                      .replace("@FLASH_ORIGIN@", hex(b.flash[0]))
                      .replace("@FLASH_LENGTH@", hex(b.flash[1]))
                      .replace("@RAM_ORIGIN@", hex(b.ram[0]))
                      .replace("@RAM_LENGTH@", hex(b.ram[1]))
                      .replace("@STACK@", str(STACK_BYTES)))
    elf = out / ELF_NAME
    cmd = [*zig_cc(), "-target", tgt.triple, f"-mcpu={tgt.cpu}", *tgt.flags, *CFLAGS,
           "-mfloat-abi=soft", *cap.defines(), *IO_DEFINES, *b.defines(), f"-I{out}", f"-I{FIRMWARE}",
           f"-I{FIXED}", f"-I{CSRC}", f"-I{ROOT}", *map(str, SOURCES), "-Wl,-T," + str(script),
           "-Wl,--gc-sections", "-o", str(elf)]
    r = subprocess.run(cmd, capture_output=True, text=True,
                       env={**os.environ, "ZIG_GLOBAL_CACHE_DIR": str(cache_root() / "zig")})
    if r.returncode != 0:
        raise RuntimeError(f"building the {b.name} image failed:\n{' '.join(cmd)}\n{r.stderr}")
    return measure(elf, tgt, cap, prefix="")
