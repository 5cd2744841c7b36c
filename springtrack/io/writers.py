"""File writers: EVT 2.0 / 2.1 / 3.0 RAW, Event Stream (DVS, ATIS), DAT, AEDAT 4, CCam words,
npy, CSV."""
from __future__ import annotations

import os

import numpy as np

from ..events import as_events
from .detect import EXTENSIONS

WRITE_FORMATS = ("evt2", "evt21", "evt21-legacy", "evt3", "es", "es-dvs", "es-atis", "dat",
                 "aedat4", "ccam", "npy", "csv")


def _raw_header(enc: str, width: int, height: int) -> bytes:
    name = {"evt2": ("2.0", "EVT2"), "evt21": ("2.1", "EVT21"),
            "evt21-legacy": ("2.1", "EVT21;endianness=legacy"), "evt3": ("3.0", "EVT3")}[enc]
    return (f"% evt {name[0]}\n% format {name[1]};height={height};width={width}\n"
            f"% geometry {width}x{height}\n% generator springtrack\n% end\n").encode()


def _dat_header(width: int, height: int) -> bytes:
    return (f"% Data file containing CD events.\n% Version 2\n% Width {width}\n"
            f"% Height {height}\n% end\n").encode() + bytes([0x0C, 8])


def encode_file(events, width: int, height: int, format: str) -> bytes:
    """The complete file content (header + payload) for ``format``."""
    ev = as_events(events)
    if format not in WRITE_FORMATS or format in ("npy", "csv"):
        raise ValueError(f"cannot encode {format!r} to bytes; binary formats: "
                         f"{', '.join(f for f in WRITE_FORMATS if f not in ('npy', 'csv'))}")
    if len(ev) and (ev["x"].max() >= width or ev["y"].max() >= height):
        raise ValueError(f"events outside the {width}x{height} geometry "
                         f"(max x {ev['x'].max()}, max y {ev['y'].max()})")
    if format == "evt2":
        from . import evt2
        return _raw_header("evt2", width, height) + evt2.encode(ev)
    if format in ("evt21", "evt21-legacy"):
        from . import evt21
        return _raw_header(format, width, height) + evt21.encode(ev, format == "evt21-legacy")
    if format == "evt3":
        from . import evt3
        return _raw_header("evt3", width, height) + evt3.encode(ev)
    if format in ("es", "es-dvs", "es-atis"):
        from . import es
        kind = "atis" if format == "es-atis" else "dvs"
        return es.header(kind, width, height) + es.encode(ev, kind)
    if format == "dat":
        from . import dat
        return _dat_header(width, height) + dat.encode(ev)
    if format == "aedat4":
        from . import aedat4
        return aedat4.encode(ev, width, height)
    from . import ccam
    if (width, height) != (ccam.WIDTH, ccam.HEIGHT):
        raise ValueError(f"ccam files are {ccam.WIDTH}x{ccam.HEIGHT}, got {width}x{height}")
    return ccam.encode(ev)


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
