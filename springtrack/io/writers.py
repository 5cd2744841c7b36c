"""File writers: EVT 2.0 / 2.1 / 3.0 RAW, Event Stream (DVS, ATIS), DAT, AEDAT 4, CCam words,
npy, CSV."""
from __future__ import annotations

import os

import numpy as np

from ..events import as_events
from .detect import EXTENSIONS

WRITE_FORMATS = ("evt2", "evt21", "evt21-legacy", "evt3", "es", "es-dvs", "es-atis", "dat",
                 "aedat4", "ccam", "npy", "csv")


DAT_EVENT_TYPE = 0x0C     # the two bytes after a DAT header: event type, event size
DAT_EVENT_SIZE = 8


def _raw_header(version: str, name: str, width: int, height: int) -> bytes:
    return (f"% evt {version}\n% format {name};height={height};width={width}\n"
            f"% geometry {width}x{height}\n% generator springtrack\n% end\n").encode()


def _evt2(ev, width, height):
    from . import evt2
    return _raw_header("2.0", "EVT2", width, height) + evt2.encode(ev)


def _evt21(legacy):
    def enc(ev, width, height):
        from . import evt21
        name = "EVT21;endianness=legacy" if legacy else "EVT21"
        return _raw_header("2.1", name, width, height) + evt21.encode(ev, legacy)
    return enc


def _evt3(ev, width, height):
    from . import evt3
    return _raw_header("3.0", "EVT3", width, height) + evt3.encode(ev)


def _es(kind):
    def enc(ev, width, height):
        from . import es
        return es.header(kind, width, height) + es.encode(ev, kind)
    return enc


def _dat(ev, width, height):
    from . import dat
    return (f"% Data file containing CD events.\n% Version 2\n% Width {width}\n"
            f"% Height {height}\n% end\n").encode() + bytes([DAT_EVENT_TYPE, DAT_EVENT_SIZE]) \
        + dat.encode(ev)


def _aedat4(ev, width, height):
    from . import aedat4
    return aedat4.encode(ev, width, height)


def _ccam(ev, width, height):
    from . import ccam
    if (width, height) != (ccam.WIDTH, ccam.HEIGHT):
        raise ValueError(f"ccam files are {ccam.WIDTH}x{ccam.HEIGHT}, got {width}x{height}")
    return ccam.encode(ev)


# binary format -> encoder(events, width, height) -> file bytes
ENCODERS = {"evt2": _evt2, "evt21": _evt21(False), "evt21-legacy": _evt21(True),
            "evt3": _evt3, "es": _es("dvs"), "es-dvs": _es("dvs"), "es-atis": _es("atis"),
            "dat": _dat, "aedat4": _aedat4, "ccam": _ccam}


def encode_file(events, width: int, height: int, format: str) -> bytes:
    """The complete file content (header + payload) for ``format``."""
    ev = as_events(events)
    if format not in ENCODERS:
        raise ValueError(f"cannot encode {format!r} to bytes; binary formats: "
                         f"{', '.join(ENCODERS)}")
    if len(ev) and (ev["x"].max() >= width or ev["y"].max() >= height):
        raise ValueError(f"events outside the {width}x{height} geometry "
                         f"(max x {ev['x'].max()}, max y {ev['y'].max()})")
    return ENCODERS[format](ev, width, height)


def write(path, events, width: int | None = None, height: int | None = None,
          format: str | None = None) -> str:
    """Write ``events`` to ``path``; the format defaults from the extension
    (.raw -> evt2, .es -> Event Stream DVS, .dat, .aedat4, .ccam, .npy, .csv; format="evt21"
    for EVT 2.1, "evt21-legacy" for the IMX636's EVT 2.1 word order)."""
    fmt = format or EXTENSIONS.get(os.path.splitext(str(path))[1].lower())
    if fmt not in WRITE_FORMATS:
        raise ValueError(f"{path}: cannot tell the output format from the extension; "
                         f"pass format= one of {', '.join(WRITE_FORMATS)}")
    ev = as_events(events)
    if fmt == "npy":
        with open(path, "wb") as f:
            np.save(f, ev)
        return str(path)
    if fmt == "csv":
        with open(path, "w") as f:
            f.write("t,x,y,p\n")
            np.savetxt(f, np.column_stack([ev[c].astype(np.int64) for c in "txyp"]),
                       fmt="%d", delimiter=",")
        return str(path)
    if fmt == "ccam" and width is None and height is None:
        width, height = 304, 240
    if width is None or height is None:
        raise ValueError(f"{path}: {fmt} files record the sensor geometry; pass width and height")
    data = encode_file(ev, int(width), int(height), fmt)
    with open(path, "wb") as f:
        f.write(data)
    return str(path)
