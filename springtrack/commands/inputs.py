"""A whole event file read for a command (``learn``, ``render``): its events, the sensor
size (the header's, else the events' extent), checked against what can be allocated, and
the decoder's drops reported as a warning on standard error (a stream mostly of corrupt
words refused: springtrack.io.stats.CORRUPT_SHARE)."""
from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

from ..limits import MAX_SENSOR_PX


@dataclass
class Input:
    events: np.ndarray
    width: int
    height: int
    known: bool            # the size came from the file's header
    stats: object          # springtrack.io.DecodeStats: what the decoder saw and dropped


def check_sensor(width: int, height: int, source) -> None:
    """A sensor size a command may allocate images and maps for: at most MAX_SENSOR_PX a
    side (a header declaring 65535x65535 would ask for 16 GiB per map)."""
    if not (0 < width <= MAX_SENSOR_PX and 0 < height <= MAX_SENSOR_PX):
        raise ValueError(f"{source}: a {width}x{height} sensor: at most {MAX_SENSOR_PX} px a "
                         f"side is supported (springtrack.limits.MAX_SENSOR_PX); a header "
                         f"or event coordinates this large are corrupt")


def read_input(path) -> Input:
    from .. import io as stio
    r = stio.open(path)
    ev = r.read()
    checked(r, path)
    w = r.width or (int(ev["x"].max()) + 1 if len(ev) else 1)
    h = r.height or (int(ev["y"].max()) + 1 if len(ev) else 1)
    check_sensor(w, h, path)
    return Input(ev, w, h, bool(r.width and r.height), r.stats)


def checked(reader, path) -> None:
    """After a whole input was read: a stream mostly of corrupt words refused (random bytes
    are not learned or drawn), the decoder's drops warned about on standard error."""
    reader.stats.check_decodable(path)
    warn = reader.stats.warning(path)
    if warn:
        print(warn, file=sys.stderr)


def stream_input(path):
    """(chunks, width, height, reader) of an input read chunk by chunk when its header gives
    the sensor (memory: a chunk); otherwise read whole (its size from the events' extent).
    Call :func:`checked` once the chunks are consumed."""
    from .. import io as stio
    r = stio.open(path)
    if r.width and r.height:
        check_sensor(r.width, r.height, path)
        return iter(r), r.width, r.height, r
    ev = r.read()
    w = int(ev["x"].max()) + 1 if len(ev) else 1
    h = int(ev["y"].max()) + 1 if len(ev) else 1
    check_sensor(w, h, path)
    return iter([ev] if len(ev) else []), w, h, r
