"""``replay:FILE``: a recording re-encoded as CCam ATIS words by the simulated camera."""
from __future__ import annotations

from pathlib import Path

from springtrack.events import as_events

from .. import usb as camusb
from . import SourceOptions, simulated

USAGE = "replay:FILE"
CCAM = camusb.PROFILES["ccam_atis"]
HELP = (f"any format springtrack.io reads, re-encoded as CCam words through the simulated "
        f"USB camera; events outside {CCAM.width}x{CCAM.height} dropped and counted")


def file_source(path, width: int = CCAM.width, height: int = CCAM.height,
                stats: dict | None = None):
    """Events of any file ``springtrack.io`` reads, for a ``width x height`` sensor;
    events outside it are dropped and counted in ``stats['outside']``.  The file is
    opened (its format and header checked) now, so a bad path fails here with a clear
    error rather than later in the simulated camera's reader thread."""
    from springtrack import io as stio
    stats = {} if stats is None else stats
    stats.setdefault("outside", 0)
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: replay file not found")
    return _inside(stio.open(path), width, height, stats)


def _inside(chunks, width: int, height: int, stats: dict):
    for chunk in chunks:
        ev = as_events(chunk)
        keep = (ev["x"] < width) & (ev["y"] < height)
        stats["outside"] += int((~keep).sum())
        yield ev[keep] if not keep.all() else ev


def limit_seconds(source, seconds: float):
    """The events of ``source`` in its first ``seconds`` of event time."""
    t0 = None
    for ev in source:
        if len(ev) == 0:
            continue
        t0 = int(ev["t"][0]) if t0 is None else t0
        end = t0 + int(seconds * 1e6)
        keep = ev[ev["t"] < end]
        if len(keep):
            yield keep
        if len(keep) < len(ev):
            return


def open(target: str, opts: SourceOptions, url: str):
    stats: dict = {}
    events = file_source(target, stats=stats)
    if opts.seconds is not None:
        events = limit_seconds(events, opts.seconds)

    def report() -> list[str]:
        if not stats.get("outside"):
            return []
        return [f"replay: {stats['outside']} events outside the {CCAM.width}x{CCAM.height} "
                f"sensor dropped before encoding"]
    return simulated(url, events, opts, report=report)
