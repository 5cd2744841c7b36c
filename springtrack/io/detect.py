"""Format detection by content, and header parsing (docs/formats.md).

RAW (EVT 2.0 / 2.1 / 3.0) and DAT files start with ``% `` text lines; Event Stream files with
the ``Event Stream`` magic; AEDAT 4 with ``#!AER-DAT4.0``; ``.npy`` with the numpy magic;
CSV with the line ``t,x,y,p``.
Only headerless CCam word dumps need the extension (``.ccam``).
"""
from __future__ import annotations

import builtins
import os
import re
from dataclasses import dataclass, field

import numpy as np

from .errors import DecodeError

ES_MAGIC = b"Event Stream"
NPY_MAGIC = b"\x93NUMPY"
AEDAT4_MAGIC = b"#!AER-DAT4.0\r\n"
ES_TYPES = {0: "generic", 1: "dvs", 2: "atis", 4: "color"}
# Sensor geometry by Prophesee plugin name, used only when the header gives none.
PLUGIN_GEOMETRY = {"gen3": (640, 480), "gen31": (640, 480), "gen41": (1280, 720),
                   "imx636": (1280, 720), "imx646": (1280, 720), "imx8": (1280, 720)}
BINARY_FORMATS = ("evt2", "evt21", "evt3", "es", "dat", "ccam", "aedat4")
FORMATS = BINARY_FORMATS + ("npy", "csv")
EXTENSIONS = {".raw": "evt2", ".es": "es", ".dat": "dat", ".ccam": "ccam", ".npy": "npy",
              ".csv": "csv", ".aedat4": "aedat4"}
MAX_HEADER = 1 << 20
# RAW encodings by '% format NAME;...' and by '% evt VERSION'
RAW_FORMAT_NAMES = {"EVT2": "evt2", "EVT21": "evt21", "EVT3": "evt3"}
RAW_EVT_VERSIONS = {"2.0": "evt2", "2": "evt2", "2.1": "evt21", "3.0": "evt3", "3": "evt3"}
EVT21_TYPES = np.array([0x0, 0x1, 0x8, 0xA, 0xE, 0xF], np.uint64)   # evt21.pxd's Evt21Type


@dataclass
class FileInfo:
    """What detection found: format, payload start, geometry and header fields."""
    format: str
    offset: int = 0
    width: int | None = None
    height: int | None = None
    header: dict = field(default_factory=dict)
    event_type: str | None = None      # Event Stream: dvs | atis
    options: dict = field(default_factory=dict)    # decoder options the header implies


def _header_ends(head: bytes) -> bool:
    """True if the ``%`` header lines end inside ``head``."""
    pos = 0
    while head[pos:pos + 1] == b"%":
        end = head.find(b"\n", pos)
        if end < 0:
            return False
        if head[pos:end].strip() == b"% end":
            return True
        pos = end + 1
    return pos < len(head)


def _percent_header(head: bytes, path) -> tuple[dict, int]:
    """Parse ``% key value`` lines; return (fields, offset of the first payload byte)."""
    fields, pos = {}, 0
    while pos < len(head) and head[pos:pos + 1] == b"%":
        end = head.find(b"\n", pos)
        if end < 0:
            raise DecodeError(f"{path}: header line at byte {pos} has no end of line "
                              f"(truncated, or header over {MAX_HEADER} bytes)")
        line = head[pos + 1:end].decode("latin-1").strip()
        pos = end + 1
        if line == "end":
            break
        key, _, value = line.partition(" ")
        if key:
            fields[key] = value.strip()
    return fields, pos


def _int_field(value: str, what: str, path) -> int:
    try:
        v = int(value)
    except ValueError:
        raise DecodeError(f"{path}: header {what} {value!r} is not an integer") from None
    if not 0 < v <= 65535:
        raise DecodeError(f"{path}: header {what} {v} out of range 1..65535")
    return v


def _raw_geometry(fields: dict, path):
    fmt = fields.get("format", "")
    kv = dict(p.split("=", 1) for p in fmt.split(";")[1:] if "=" in p)
    if "width" in kv and "height" in kv:
        return (_int_field(kv["width"], "format width", path),
                _int_field(kv["height"], "format height", path), "format")
    if "geometry" in fields:
        m = re.fullmatch(r"(\d+)\s*x\s*(\d+)", fields["geometry"])
        if not m:
            raise DecodeError(f"{path}: header geometry {fields['geometry']!r} is not WxH")
        return (_int_field(m[1], "geometry width", path),
                _int_field(m[2], "geometry height", path), "geometry")
    if "Width" in fields and "Height" in fields:
        return (_int_field(fields["Width"], "Width", path),
                _int_field(fields["Height"], "Height", path), "Width/Height")
    plugin = fields.get("plugin_name", "")
    for key in sorted(PLUGIN_GEOMETRY, key=len, reverse=True):
        if re.search(rf"(^|_){key}(_|$)", plugin):
            w, h = PLUGIN_GEOMETRY[key]
            return w, h, f"plugin_name ({key})"
    return None, None, None


def _raw_format(fields: dict, path, ext: str) -> str:
    evt = fields.get("evt", "")
    fmt = fields.get("format", "").split(";")[0].strip().upper()
    if fmt in RAW_FORMAT_NAMES:
        return RAW_FORMAT_NAMES[fmt]
    if not fmt and evt in RAW_EVT_VERSIONS:
        return RAW_EVT_VERSIONS[evt]
    if evt or fmt:
        raise DecodeError(f"{path}: RAW encoding {fmt or evt!r} not supported "
                          "(EVT 2.0, EVT 2.1 and EVT 3.0 are)")
    if "Version" in fields or ext == ".dat":
        return "dat"
    raise DecodeError(f"{path}: '% ' header names no encoding (no '% evt' or '% format' "
                      "line); pass format='evt2', 'evt21' or 'evt3'")


def _evt21_order(fields: dict, payload: bytes) -> tuple[str, str]:
    """EVT 2.1 word order: ('little' | 'legacy', where that came from).

    '% format EVT21;...;endianness=legacy' is the IMX636's order, any other EVT21 format
    line the 64-bit little-endian one (OpenEB's rule).  A file with only '% evt 2.1' does
    not say: its first words decide.  Read in the right order, TIME_HIGH words have their
    other 32 bits zero and every word type is defined; read in the wrong one, a TIME_HIGH
    word shows as a change-detection word and vice versa.  The order with more such
    TIME_HIGH words wins, then the one with fewer undefined types; a tie (no payload)
    keeps the IMX636's, the only EVT 2.1 sensor of the Metavision versions that wrote
    such headers."""
    fmt = fields.get("format", "")
    if fmt:
        opts = dict(p.split("=", 1) for p in fmt.split(";")[1:] if "=" in p)
        return ("legacy" if opts.get("endianness") == "legacy" else "little"), "format"
    words = np.frombuffer(payload[:len(payload) // 8 * 8][:1 << 15], "<u8")
    half = np.uint64(32)
    keys = []
    for v in (words, (words << half) | (words >> half)):
        typ = v >> np.uint64(60)
        clean_th = int(((typ == 0x8) & ((v & np.uint64(0xFFFFFFFF)) == 0)).sum())
        undefined = int((~np.isin(typ, EVT21_TYPES)).sum())
        keys.append((clean_th, -undefined))
    return ("little" if keys[0] > keys[1] else "legacy"), "word types"


def percent_info(head: bytes, path, ext: str = "", format: str | None = None) -> FileInfo:
    """RAW (EVT 2.0 / 2.1 / 3.0) or DAT from ``head``: the ``%`` header lines and the first
    payload bytes after them."""
    fields, offset = _percent_header(head, path)
    fmt = format or _raw_format(fields, path, ext)
    w, h, src = _raw_geometry(fields, path)
    if src:
        fields["geometry_source"] = src
    options = {}
    if fmt == "evt21":
        fields["endianness"], fields["endianness_source"] = _evt21_order(fields,
                                                                        head[offset:])
        options["legacy"] = fields["endianness"] == "legacy"
    if fmt == "dat":
        if len(head) < offset + 2:
            raise DecodeError(f"{path}: DAT file ends before the event type/size bytes")
        etype, esize = head[offset], head[offset + 1]
        if esize != 8:
            raise DecodeError(f"{path}: DAT event size {esize} not supported (8 is)")
        fields["event_type"], fields["event_size"] = str(etype), str(esize)
        offset += 2
    return FileInfo(fmt, offset, w, h, fields, options=options)


def sniff(path, format: str | None = None) -> FileInfo:
    """Detect the format of ``path`` from its first bytes (extension only for CCam)."""
    with builtins.open(path, "rb") as f:
        head = f.read(1 << 16)
        if head.startswith(b"%") and not _header_ends(head):
            head += f.read(MAX_HEADER + 1 - len(head))     # a long text header
            if len(head) > MAX_HEADER and not _header_ends(head):
                raise DecodeError(f"{path}: '%' header lines go on past {MAX_HEADER} bytes "
                                  f"(1 MiB), the most a RAW or DAT header may take")
        if head.startswith(AEDAT4_MAGIC):
            from .aedat4 import MAX_HEADER as AEDAT4_MAX, header_length
            head += f.read(max(0, min(header_length(head), AEDAT4_MAX + 32) - len(head)))
    return sniff_bytes(head, path, format)


def sniff_bytes(head: bytes, path, format: str | None = None) -> FileInfo:
    """Detect the format from ``head``, the first bytes of a file or stream (its whole
    header and, for RAW/DAT, some payload); ``path`` names it in errors (its extension
    matters only for CCam)."""
    ext = os.path.splitext(str(path))[1].lower()
    if not head:
        raise DecodeError(f"{path}: empty file")
    if format is not None and format not in FORMATS:
        raise DecodeError(f"{path}: unknown format {format!r}; known: {', '.join(FORMATS)}")
    if head.startswith(ES_MAGIC):
        return _es_info(head, path)
    if head.startswith(NPY_MAGIC):
        return FileInfo("npy")
    if head.startswith(AEDAT4_MAGIC):
        return _aedat4_info(head, path)
    if head.startswith(b"%"):
        return percent_info(head, path, ext, format)
    first = head.split(b"\n", 1)[0].strip().replace(b" ", b"")
    if first == b"t,x,y,p":
        return FileInfo("csv")
    if format in BINARY_FORMATS:
        w, h = (304, 240) if format == "ccam" else (None, None)
        return FileInfo(format, 0, w, h)
    if ext == ".ccam":
        return FileInfo("ccam", 0, 304, 240)
    raise DecodeError(f"{path}: unknown format (no '% ' header, Event Stream, AEDAT 4 or "
                      f"numpy magic, or 't,x,y,p' CSV header; first bytes {head[:16]!r})")


def _es_info(head: bytes, path) -> FileInfo:
    if len(head) < 16:
        raise DecodeError(f"{path}: Event Stream header truncated ({len(head)} bytes)")
    major, minor, patch, etype = head[12], head[13], head[14], head[15]
    version = f"{major}.{minor}.{patch}"
    if major != 2:
        raise DecodeError(f"{path}: Event Stream version {version} not supported (2.x is)")
    kind = ES_TYPES.get(etype)
    if kind not in ("dvs", "atis"):
        raise DecodeError(f"{path}: Event Stream type {kind or etype} not supported "
                          "(dvs and atis are)")
    if len(head) < 20:
        raise DecodeError(f"{path}: Event Stream header truncated before the geometry")
    w = int.from_bytes(head[16:18], "little")
    h = int.from_bytes(head[18:20], "little")
    if w == 0 or h == 0:
        raise DecodeError(f"{path}: Event Stream geometry {w}x{h} is empty")
    return FileInfo("es", 20, w, h, {"version": version, "type": kind}, event_type=kind)


def _aedat4_info(head: bytes, path) -> FileInfo:
    """AEDAT 4: geometry from the first events stream's info node (aedat4.parse_header)."""
    from .aedat4 import describe_streams, parse_header
    h = parse_header(head, path)
    streams = h["streams"]
    events = sorted(i for i, s in streams.items() if s["type"] == "EVTS")
    if not events:
        raise DecodeError(f"{path}: AEDAT 4 file has no events (EVTS) stream: "
                          f"{describe_streams(streams)}")
    ev = streams[events[0]]
    fields = {"version": "4.0", "compression": h["compression"],
              "streams": describe_streams(streams), "event_stream": str(events[0]),
              "source": ev["source"], "tsOffset": ev["ts_offset"],
              "data_table": str(h["data_table"]), "geometry_source": "info node"}
    options = {"streams": {i: s["type"] for i, s in streams.items()},
               "event_stream": events[0], "compression": h["compression"],
               "data_end": h["data_table"] - h["offset"] if h["data_table"] >= 0 else -1}
    return FileInfo("aedat4", h["offset"], ev["width"], ev["height"], fields, options=options)
