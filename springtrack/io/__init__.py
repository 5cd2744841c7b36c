"""Event I/O: streaming decoders, file readers and writers (docs/formats.md).

>>> reader = springtrack.io.open("rec.raw")      # format detected from the content
>>> for chunk in reader: ...                      # EVENT_DTYPE arrays, streamed
>>> events = reader.read(); reader.stats          # whole file; DecodeStats counters
>>> springtrack.io.write("out.es", events, 304, 240)
>>> dec = springtrack.io.decoder("evt3"); dec.decode(transfer)   # state kept across calls
"""
from .detect import FORMATS, FileInfo, sniff
from .base import simd_path
from .errors import DecodeError
from .reader import ArrayReader, Reader, make_decoder as decoder, open_events as open
from .stats import DecodeStats
from .writers import WRITE_FORMATS, encode_file, write

__all__ = ["open", "write", "decoder", "DecodeError", "DecodeStats", "Reader", "ArrayReader",
           "FORMATS", "WRITE_FORMATS", "sniff", "FileInfo", "encode_file", "simd_path"]
