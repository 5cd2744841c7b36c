"""File readers: one interface over every format (decoded in chunks, or whole)."""
from __future__ import annotations

import builtins
import importlib
import os
import stat
import warnings

import numpy as np

from ..events import EVENT_DTYPE, EventError, as_events, empty_output
from .detect import FileInfo
from .errors import DecodeError
from .stats import DecodeStats

DEFAULT_CHUNK = 1 << 20
# Reader.read sizes its output by the events per byte of the file's first READ_SAMPLE
# bytes, with READ_MARGIN more room for a denser rest (doubled beyond)
READ_SAMPLE = 1 << 18
READ_MARGIN = 0.05


# format name -> (module of springtrack.io, decoder class): one module per format
DECODERS = {
    "ccam": ("ccam", "CCamDecoder"),
    "evt2": ("evt2", "Evt2Decoder"),
    "evt3": ("evt3", "Evt3Decoder"),
    "es": ("es", "EsDecoder"),
    "dat": ("dat", "DatDecoder"),
    "evt21": ("evt21", "Evt21Decoder"),
    "aedat4": ("aedat4", "Aedat4Decoder"),
}


def make_decoder(fmt: str, **opts):
    """A fresh streaming decoder for ``fmt`` (a key of :data:`DECODERS`)."""
    try:
        module, name = DECODERS[fmt]
    except KeyError:
        raise ValueError(f"unknown decoder format {fmt!r}; known: {', '.join(DECODERS)}") from None
    return getattr(importlib.import_module(f"{__package__}.{module}"), name)(**opts)


class Reader:
    """An event file: ``.format``, ``.width``, ``.height`` (None if unknown), ``.header``.

    ``for chunk in reader`` / ``reader.chunks(nbytes)`` yield event arrays as the file is
    decoded; ``reader.read()`` returns all events.  ``reader.stats`` holds the counters of
    the last pass; ``reader.exposure`` the exposure events kept (keep_exposure=True).
    """

    def __init__(self, path, info: FileInfo, keep_exposure: bool = False):
        self.path = path
        self.format = info.format
        self.width = info.width
        self.height = info.height
        self.header = info.header
        self.offset = info.offset
        self.event_type = info.event_type
        self.options = info.options
        self.keep_exposure = keep_exposure
        self.stats = DecodeStats(self.format)
        self.exposure = np.empty(0, EVENT_DTYPE)

    def __repr__(self):
        return (f"<Reader {self.path} format={self.format} "
                f"geometry={self.width}x{self.height}>")

    def __iter__(self):
        return self.chunks()

    # typical payload bytes per event, for a progress estimate (EVT 3.0: the Gen4.1 sample,
    # AEDAT 4: the DVXplorer sample with its IMU packets)
    BYTES_PER_EVENT = {"evt2": 4.0, "evt21": 4.0, "evt3": 2.8, "es": 5.0, "dat": 8.0,
                       "ccam": 4.0, "aedat4": 8.5}

    @property
    def size_hint(self) -> int:
        """Estimated number of events (exact for npy and CSV), for progress display."""
        payload = max(0, os.path.getsize(self.path) - self.offset)
        return int(payload / self.BYTES_PER_EVENT[self.format])

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def decoder(self):
        opts = {}
        if self.format in ("evt2", "evt21", "evt3", "dat", "es", "aedat4"):
            opts = {"width": self.width or 0, "height": self.height or 0}
        opts.update(self.options)
        if self.format == "es":
            opts["event_type"] = self.event_type
        if self.format in ("es", "ccam"):
            opts["keep_exposure"] = self.keep_exposure
        return make_decoder(self.format, **opts)

    def chunks(self, nbytes: int = DEFAULT_CHUNK):
        """Yield non-empty event arrays, decoding ``nbytes`` of the file at a time."""
        if nbytes < 1:
            raise ValueError(f"chunk size must be >= 1 byte, got {nbytes}")
        dec = self.decoder()
        parts = []
        with builtins.open(self.path, "rb") as f:
            f.seek(self.offset)
            while True:
                data = f.read(nbytes)
                if not data:
                    break
                ev = dec.decode(data)
                self.stats = dec.stats
                if self.keep_exposure:
                    parts.append(dec.take_exposure())
                if len(ev):
                    yield ev
        dec.finish()
        self.stats = dec.stats
        if self.keep_exposure:
            parts.append(dec.take_exposure())
            self.exposure = np.concatenate(parts)

    def read(self, nbytes: int = 1 << 18) -> np.ndarray:
        """All events of the file, in one array.

        The file is read ``nbytes`` at a time into one reused buffer and decoded straight
        into one output array, sized by the events per byte of the first READ_SAMPLE
        bytes (READ_MARGIN more) and doubled if the rest is denser: the allocation follows
        the events (16 bytes each), not the most the file's length could hold (4 to 8
        times that length for words of 4 to 2 bytes).  A rest sparser than the sample
        leaves the array's tail unused: trimmed (copied) when under half used."""
        dec = self.decoder()
        payload = max(0, os.path.getsize(self.path) - self.offset)
        buf = bytearray(nbytes)
        view = memoryview(buf)
        with builtins.open(self.path, "rb") as f:
            f.seek(self.offset)
            first = f.read(min(payload, READ_SAMPLE))
            head = dec.decode(first)
            n = len(head)
            room = int(n / max(len(first), 1) * payload * (1 + READ_MARGIN)) + 1024
            out = empty_output(max(room, n))
            out[:n] = head
            del head
            while True:
                got = f.readinto(buf)
                if not got:
                    break
                out, n = dec.decode_append(view[:got], out, n)
        dec.finish()
        self.stats = dec.stats
        if self.keep_exposure:
            self.exposure = dec.take_exposure()
        if n * 2 < len(out):
            return out[:n].copy()
        return out[:n]


class ArrayReader(Reader):
    """``.npy`` (structured t, x, y, p) and CSV (header ``t,x,y,p``) files."""

    def __init__(self, path, info: FileInfo):
        super().__init__(path, info)
        self._events = None

    def _load(self) -> np.ndarray:
        if self._events is None:
            self._events = _load_npy(self.path) if self.format == "npy" else _load_csv(self.path)
            self.stats = DecodeStats(self.format, words=len(self._events),
                                     events=len(self._events))
        return self._events

    def chunks(self, nbytes: int = DEFAULT_CHUNK):
        """Yield arrays of ``nbytes // 16`` events (the in-memory record size)."""
        ev = self._load()
        step = max(1, nbytes // EVENT_DTYPE.itemsize)
        for i in range(0, len(ev), step):
            yield ev[i:i + step]

    def read(self) -> np.ndarray:
        return self._load()

    @property
    def size_hint(self) -> int:
        return len(self._load())


def _check_npy_size(path) -> None:
    """Refuse a .npy whose header declares more data than the file holds (a 292-byte file
    may declare 10^12 events: numpy would allocate them first) or a data type that is not a
    plain structured record."""
    fmt = np.lib.format
    try:
        with builtins.open(path, "rb") as f:
            version = fmt.read_magic(f)
            shape, _, dtype = (fmt.read_array_header_1_0(f) if version == (1, 0)
                               else fmt.read_array_header_2_0(f))
            offset = f.tell()
    except (ValueError, OSError, SyntaxError, TypeError) as e:
        raise DecodeError(f"{path}: not a readable .npy event array: {e}") from None
    if dtype.hasobject:
        raise DecodeError(f"{path}: .npy of Python objects: an event array has numeric fields")
    count = 1
    for n in shape:
        count *= int(n)
    need = count * dtype.itemsize
    have = os.path.getsize(path) - offset
    if need > have:
        raise DecodeError(f"{path}: .npy header declares shape {shape} of {dtype.itemsize}-byte "
                          f"records ({need:,} bytes) but the file holds {have:,} bytes after "
                          f"its header: truncated or corrupt")


def _load_npy(path) -> np.ndarray:
    _check_npy_size(path)
    try:
        arr = np.load(path, allow_pickle=False)
    except ValueError as e:
        raise DecodeError(f"{path}: not a readable .npy event array: {e}") from None
    try:
        return as_events(arr)
    except (TypeError, EventError) as e:
        raise DecodeError(f"{path}: {e}") from None


def _load_csv(path) -> np.ndarray:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)     # "no data": 0 events is fine
            cols = np.loadtxt(path, delimiter=",", skiprows=1, dtype=np.int64, ndmin=2)
    except ValueError as e:
        raise DecodeError(f"{path}: CSV rows must be 4 integers t,x,y,p: {e}") from None
    if cols.size == 0:
        return np.empty(0, EVENT_DTYPE)
    if cols.shape[1] != 4:
        raise DecodeError(f"{path}: CSV rows have {cols.shape[1]} columns, expected 4 (t,x,y,p)")
    rows = np.ascontiguousarray(cols).view([(f, "<i8") for f in ("t", "x", "y", "p")])[:, 0]
    try:
        return as_events(rows)                     # the checks of every event source
    except EventError as e:
        raise DecodeError(f"{path}: line {e.index + 2}: {e.detail}") from None


def is_stream(path) -> bool:
    """A FIFO or character device: it cannot be sniffed and reopened (what detection
    read would be gone, and its writer killed by SIGPIPE), nor sized."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False                 # open() names the problem
    return stat.S_ISFIFO(mode) or stat.S_ISCHR(mode)
