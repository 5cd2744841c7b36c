"""Consistent Overhead Byte Stuffing (Cheshire & Baker 1999), the byte format of the host
link's frames (springtrack.wire): bytes recoded without 0x00, so that 0x00 ends a frame."""
from __future__ import annotations


class CobsError(ValueError):
    """Bytes that are no COBS encoding; the message says where."""


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: the output contains no 0x00 byte."""
    out = bytearray()
    for block in bytes(data).split(b"\x00"):
        while len(block) >= 254:
            out.append(255)
            out += block[:254]
            block = block[254:]
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(enc: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises CobsError on a zero byte or a short block."""
    out = bytearray()
    i, n = 0, len(enc)
    while i < n:
        code = enc[i]
        if code == 0:
            raise CobsError(f"COBS: zero byte at offset {i}")
        end = i + code
        if end > n:
            raise CobsError(f"COBS: block at offset {i} needs {code - 1} bytes, {n - i - 1} left")
        block = enc[i + 1:end]
        if 0 in block:
            raise CobsError(f"COBS: zero byte inside block at offset {i}")
        out += block
        i = end
        if code < 255 and i < n:
            out.append(0)
    return bytes(out)
