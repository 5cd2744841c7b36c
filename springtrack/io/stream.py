"""Event streams on a pipe: ``springtrack.io.open("-")`` reads standard input.

Another stack's live output -- a Prophesee RAW stream (EVT 2.0, 2.1 or 3.0 after its ``%``
header), or Event Stream, DAT or AEDAT 4 -- is decoded as it arrives, in bounded chunks: the
header is read (line by line for ``%`` headers), then every ``read1`` (whatever the pipe
holds, up to the chunk size) is decoded at once and its events yielded, so memory stays
bounded however long the stream runs.
"""
from __future__ import annotations

import io
import sys

import numpy as np

from ..events import EVENT_DTYPE
from .detect import AEDAT4_MAGIC, ES_MAGIC, MAX_HEADER, sniff_bytes
from .errors import DecodeError
from .reader import DEFAULT_CHUNK, Reader

STREAM_FORMATS = ("evt2", "evt21", "evt3", "es", "dat", "aedat4")
ES_HEADER = 20          # Event Stream 2.x: magic, version, type, width, height
STDIN = "-"


def read_header(f, name: str) -> bytes:
    """The ``%`` header lines at the start of ``f`` (a buffered binary stream), consumed."""
    head = bytearray()
    while f.peek(1)[:1] == b"%":
        line = f.readline(MAX_HEADER - len(head) + 1)
        if not line.endswith(b"\n"):
            raise DecodeError(f"{name}: header line at byte {len(head)} has no end of line "
                              f"(stream ended, or header over {MAX_HEADER} bytes)")
        head += line
        if line.strip() == b"% end":
            break
    return bytes(head)


class StreamReader(Reader):
    """A RAW stream read once, front to back (``chunks()`` / ``read()``; no ``size_hint``)."""

    def __init__(self, f, info, name: str = STDIN):
        super().__init__(name, info)
        self.stream = f

    @property
    def size_hint(self):
        return None

    def chunks(self, nbytes: int = DEFAULT_CHUNK):
        """Yield the events of every ``nbytes`` or less the stream delivers, as it comes."""
        if nbytes < 1:
            raise ValueError(f"chunk size must be >= 1 byte, got {nbytes}")
        dec = self.decoder()
        while True:
            data = self.stream.read1(nbytes)
            if not data:
                break
            ev = dec.decode(data)
            self.stats = dec.stats
            if len(ev):
                yield ev
        dec.finish()
        self.stats = dec.stats

    def read(self, nbytes: int = DEFAULT_CHUNK) -> np.ndarray:
        parts = list(self.chunks(nbytes))
        return np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)


def open_stream(f=None, format: str | None = None, name: str = STDIN) -> StreamReader:
    """An event stream with its header (RAW EVT 2.0 / 2.1 / 3.0, Event Stream, DAT,
    AEDAT 4) on the binary file object ``f`` (default: standard input)."""
    if f is None:
        f = sys.stdin.buffer
    if not hasattr(f, "peek") or not hasattr(f, "read1"):
        f = io.BufferedReader(f)
    first = f.peek(len(AEDAT4_MAGIC))[:len(AEDAT4_MAGIC)]
    if first.startswith(b"%"):
        head = read_header(f, name)
    elif first.startswith(ES_MAGIC):
        head = f.read(ES_HEADER)
    elif first.startswith(AEDAT4_MAGIC):
        from .aedat4 import MAX_HEADER as AEDAT4_MAX, header_length
        head = f.read(len(AEDAT4_MAGIC) + 4)
        head += f.read(max(0, min(header_length(head), AEDAT4_MAX + 32) - len(head)))
    else:
        raise DecodeError(f"{name}: a stream must start with its header (a Prophesee RAW "
                          "'%' header, Event Stream, DAT or AEDAT 4); first bytes "
                          f"{f.peek(16)[:16]!r}")
    info = sniff_bytes(head + f.peek(1 << 16), name, format)
    if info.format not in STREAM_FORMATS:
        raise DecodeError(f"{name}: {info.format} is read from files only; streams may be "
                          f"{', '.join(STREAM_FORMATS)}")
    f.read(info.offset - len(head))       # what the header holds past its lines (DAT: 2)
    info.offset = 0
    return StreamReader(f, info, name)
