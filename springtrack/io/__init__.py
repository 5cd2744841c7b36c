"""Event I/O: streaming decoders, file readers and writers (docs/formats.md).

>>> reader = springtrack.io.open("rec.raw")      # format detected from the content
>>> for chunk in reader: ...                      # EVENT_DTYPE arrays, streamed
>>> events = reader.read(); reader.stats          # whole file; DecodeStats counters
>>> springtrack.io.write("out.es", events, 304, 240)
>>> dec = springtrack.io.decoder("evt3"); dec.decode(transfer)   # state kept across calls
"""
import builtins

from .detect import FORMATS, FileInfo, sniff
from .base import simd_path
from .errors import DecodeError
from .reader import ArrayReader, Reader, is_stream, make_decoder as decoder
from .stats import DecodeStats
from .stream import open_stream
from .writers import WRITE_FORMATS, encode_file, write


def open(path, format: str | None = None, keep_exposure: bool = False) -> Reader:
    """Open an event file of any supported format (detected by content); ``"-"``: the event
    stream on standard input, and a named pipe or character device: the stream it delivers
    (springtrack.io.stream); a live source URL (``dv://HOST:PORT``, ``udp://HOST:PORT``,
    springtrack.live): that stream, connected."""
    from .. import live
    if live.is_live(path):
        return live.open(path)
    if isinstance(path, str) and path == "-":
        return open_stream(format=format)
    if is_stream(path):              # a named pipe or a device: read once, as a stream
        return open_stream(builtins.open(path, "rb"), format=format, name=str(path))
    info = sniff(path, format)
    if info.format in ("npy", "csv"):
        return ArrayReader(path, info)
    return Reader(path, info, keep_exposure=keep_exposure)


__all__ = ["open", "write", "decoder", "DecodeError", "DecodeStats", "Reader", "ArrayReader",
           "FORMATS", "WRITE_FORMATS", "sniff", "FileInfo", "encode_file", "simd_path"]
