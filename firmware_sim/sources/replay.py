"""``replay:FILE``: a recording through the simulated camera, at the recording's geometry.

* A file of camera words (Prophesee RAW EVT 2.0 / 2.1 / 3.0, CCam words) is served as it
  is, by a simulated camera of that kind (an EVK streaming the file's format at the file's
  sensor size, or the CCam ATIS), each 512-byte packet released when its last event is due
  (``simcam.words.packet_chunk``): the loop decodes exactly the recorded bytes.
* Any other file (Event Stream, DAT, AEDAT 4, npy, CSV) is re-encoded as the words of an
  EVT 2.0 EVK of the file's geometry (:data:`REENCODE_PROFILE`).
* ``--profile NAME`` re-encodes any file for that camera (e.g. ``ccam_atis``, the
  304 x 240 ATIS): events outside its sensor are dropped before encoding, counted, and
  reported at start, in every statistics line (``geometry_drops``) and at the end.
* The recording-quirk options of ``springtrack track`` (``--start-us``, ``--end-us``,
  ``--dequantize``, ``--burst-fraction``: ``SourceOptions.prepare``) prepare the events
  as that command does (springtrack.prep), before the camera: a file of words is then
  re-encoded in its own format.
"""
from __future__ import annotations

import builtins
from pathlib import Path

import numpy as np

from springtrack.events import as_events

from .. import camera as camusb
from . import SourceOptions, profile, simulated

USAGE = "replay:FILE"
HELP = ("a recording (any format springtrack.io reads) through the simulated camera at the "
        "file's geometry: RAW EVT 2.0/2.1/3.0 and CCam words served as they are, other "
        "formats re-encoded as EVT 2.0; --profile re-encodes for that camera (events "
        "outside its sensor dropped and counted)")

# the file's format -> the camera that streams it (its words replayed as they are)
WORD_PROFILES = {"ccam": "ccam_atis", "evt2": "evt2", "evt21": "evt21", "evt3": "evt3"}
REENCODE_PROFILE = "evt2"        # other files: an EVT 2.0 EVK of the file's geometry
READ_BYTES = 1 << 18             # file bytes per chunk of words
CHECK_BYTES = 1 << 20            # file bytes decoded at start to refuse what is not its format
# re-encoded recordings that start later than this (the EVT 3.0 time counter's range,
# 2**24 us) are re-based to start at 0, as a camera's counter does: else the words would
# first count up to the recording's time (AEDAT 4 stamps Unix-epoch microseconds)
REBASE_FROM_US = 1 << 24


def _reader(path):
    from springtrack import io as stio
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: replay file not found")
    return stio.open(path)


def check_decodable(reader, name) -> None:
    """Refuse a file whose first CHECK_BYTES are not of its format (mostly corrupt words:
    springtrack.io.stats.CORRUPT_SHARE), as ``springtrack track`` does: random bytes
    behind a header would otherwise be replayed as events at random times."""
    if reader.format in ("npy", "csv"):
        return
    dec = reader.decoder()
    with builtins.open(reader.path, "rb") as f:
        f.seek(reader.offset)
        dec.decode(f.read(CHECK_BYTES))
    dec.stats.check_decodable(name)


def file_source(path, width: int, height: int, stats: dict | None = None):
    """Events of any file ``springtrack.io`` reads, for a ``width x height`` sensor;
    events outside it are dropped and counted in ``stats['outside_sensor']``, all in
    ``stats['events_in']``.  The file is opened (its format and header checked) now, so
    a bad path fails here with a clear error rather than later in the simulated camera's
    reader thread."""
    stats = {} if stats is None else stats
    return _inside(_reader(path), width, height, stats)


def _inside(chunks, width: int, height: int, stats: dict):
    stats.setdefault("outside_sensor", 0)
    stats.setdefault("events_in", 0)
    for chunk in chunks:
        ev = as_events(chunk)
        keep = (ev["x"] < width) & (ev["y"] < height)
        stats["events_in"] += len(ev)
        stats["outside_sensor"] += int((~keep).sum())
        yield ev[keep] if not keep.all() else ev


def rebased(chunks, stats: dict, unit_us: int = 1):
    """Events re-based to start within ``unit_us`` of 0 (``stats['t_offset_us']``, a
    multiple of ``unit_us``, subtracted) if the first one is at ``REBASE_FROM_US`` or
    later, else as they are."""
    offset = None
    for ev in chunks:
        if len(ev) == 0:
            continue
        if offset is None:
            t0 = int(ev["t"][0])
            offset = t0 - t0 % unit_us if t0 >= REBASE_FROM_US else 0
            stats["t_offset_us"] = offset
        if offset:
            ev = ev.copy()
            ev["t"] -= offset
        yield ev


def prepared(chunks, prep, stats: dict):
    """The events of ``chunks`` through a fresh ``springtrack.prep.Preparer`` (as
    ``springtrack track`` prepares them); its summary in ``stats['prepared']``."""
    from springtrack.commands.options import prepared as _prepared
    for ev in _prepared((as_events(c) for c in chunks), prep):
        stats["prepared"] = prep.stats.summary()
        yield ev
    stats["prepared"] = prep.stats.summary()


def word_chunks(reader, nbytes: int = READ_BYTES):
    """The file's words as they are, in chunks of ``nbytes`` released packet by packet
    (their event times from the file's own decoder)."""
    from ..simcam.words import packet_chunk
    dec = reader.decoder()
    last = None
    with builtins.open(reader.path, "rb") as f:
        f.seek(reader.offset)
        while data := f.read(nbytes):
            chunk, last = packet_chunk(data, dec, last)
            if chunk is not None:
                yield chunk


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


def limit_chunk_seconds(chunks, seconds: float):
    """The word chunks of the first ``seconds`` of event time, in whole packets."""
    t0 = None
    for c in chunks:
        t0 = int(c.marks_t[0]) if t0 is None else t0
        end = t0 + int(seconds * 1e6)
        k = int(np.searchsorted(c.marks_t, end, side="left"))
        if k == len(c.marks_t):
            yield c
            continue
        if k:
            c.data = c.data[:int(c.marks_off[k - 1])]
            c.marks_t, c.marks_off = c.marks_t[:k], c.marks_off[:k]
            yield c
        return


def _geometry(reader, prof_name: str) -> tuple[int, int, str]:
    """The file's sensor (width, height) and where it came from."""
    if reader.width and reader.height:
        return (reader.width, reader.height,
                reader.header.get("geometry_source") or "the file's header")
    if reader.format in ("npy", "csv"):
        ev = reader.read()
        if len(ev):
            return int(ev["x"].max()) + 1, int(ev["y"].max()) + 1, "the events' extent"
    p = camusb.PROFILES[prof_name]
    return p.width, p.height, f"the {prof_name} profile's default"


def open(target: str, opts: SourceOptions, url: str):
    if not target:
        raise ValueError(f"--source {url!r}: name the file to replay: {USAGE}")
    reader = _reader(target)
    check_decodable(reader, target)
    as_is = opts.profile is None and reader.format in WORD_PROFILES and opts.prepare is None
    name = (opts.profile or WORD_PROFILES.get(reader.format) or REENCODE_PROFILE)
    fw, fh, where = _geometry(reader, name)
    prep = opts.prepare
    prof = profile(name, fw, fh, reader.options.get("legacy") if as_is else None)
    stats: dict = {}
    notes = []
    if as_is:
        notes.append(f"replay: {target}: {reader.format} words as recorded, {fw}x{fh} "
                     f"(from {where}), through a simulated {prof.name} camera")
    else:
        notes.append(f"replay: {target}: {reader.format} {fw}x{fh} (from {where}) "
                     f"re-encoded as {prof.fmt} words of a {prof.width}x{prof.height} "
                     f"{prof.name} camera")
        if (fw, fh) != (prof.width, prof.height) and (fw > prof.width or fh > prof.height):
            notes.append(f"replay: warning: the {fw}x{fh} recording does not fit the "
                         f"{prof.width}x{prof.height} sensor of --profile {prof.name}: events "
                         f"outside it are dropped (counted in geometry_drops); omit --profile "
                         f"to replay at the recording's own geometry")

    readers = [reader]                  # the file's reader of this replay, and the totals of
    before = {}                         # the decoder's anomalies of the replays before it

    def file_anomalies() -> dict:
        out = dict(before)
        for k, v in readers[-1].stats.bad.items():
            out[k] = out.get(k, 0) + v
        return out

    def source(rd):
        """What the simulated camera serves from reader ``rd`` (again at every replay)."""
        if rd is not readers[-1]:
            before.update(file_anomalies())
            readers.append(rd)
            del readers[:-1]
        if as_is:
            chunks = word_chunks(rd)
            return chunks if opts.seconds is None else limit_chunk_seconds(chunks, opts.seconds)
        events = rd if prep is None else prepared(rd, prep(fw, fh), stats)
        events = events if opts.seconds is None else limit_seconds(events, opts.seconds)
        return rebased(_inside(events, prof.width, prof.height, stats), stats)

    def report() -> list[str]:
        out = [f"prepared: {stats['prepared']}"] if stats.get("prepared") else []
        bad = file_anomalies()
        if bad and not as_is:           # (as recorded, the camera's decoder counts them)
            out.append(f"replay: warning: decoding {target} ({reader.format}) met "
                       f"{sum(bad.values())} anomalies ("
                       + ", ".join(f"{k} {v}" for k, v in bad.items())
                       + "): their events never reached the camera (`springtrack info` "
                       f"describes them)")
        if stats.get("t_offset_us"):
            out.append(f"replay: times re-based by -{stats['t_offset_us']} us (the recording "
                       f"starts after the camera counter's {REBASE_FROM_US} us): tracks and "
                       f"statistics count from its first event")
        if not stats.get("outside_sensor"):
            return out
        return out + [f"replay: warning: {stats['outside_sensor']} of {stats['events_in']} events "
                f"({stats['outside_sensor'] / max(stats['events_in'], 1):.1%}) lay outside the "
                f"{prof.width}x{prof.height} sensor and were dropped before encoding"]
    return simulated(url, source(reader), opts, prof, restart=lambda: source(_reader(target)),
                     report=report, notes=notes,
                     counters=lambda: dict(stats, file_anomalies=(
                         0 if as_is else sum(file_anomalies().values()))))
