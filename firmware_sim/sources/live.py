"""Live streams (``dv://HOST:PORT``, ``dv:camera[:SERIAL]``, ``udp://HOST:PORT``, every
scheme of ``springtrack.live``) through the simulated camera.

The library owns the stream handlers (``springtrack.live``: connection, geometry from
the stream, counts, how it ends); this module only serves their events to the loop, as
``replay:`` serves a file's: re-encoded as the words of an EVT 2.0 EVK of the stream's
geometry (``--profile`` another camera; events outside its sensor dropped and counted), as
they arrive (no pacing of its own: the stream is the clock).  A stream whose layout
carries no geometry takes ``--geometry WxH``.  Times are re-based by whole seconds to
start below the camera counter's range, as a replay's, so the telemetry's sample times
are the stream's own minus that offset (reported at start of the report).
"""
from __future__ import annotations

import dataclasses

from springtrack import live

from . import SourceOptions, profile, simulated
from .replay import REENCODE_PROFILE, _inside, rebased

USAGE = live.usage()
HELP = ("a live event stream read by springtrack.live (docs/live.md): a DV network stream, "
        "an attached iniVation camera, UDP datagrams in aestream's layout; re-encoded as "
        "EVT 2.0 words at the stream's geometry (--geometry when it carries none)")
REBASE_UNIT_US = 1_000_000    # offsets are whole seconds: the sample grid stays the stream's


def open(target: str, opts: SourceOptions, url: str):         # noqa: A001
    reader = live.open(url)
    w, h = reader.width, reader.height
    where = reader.header.get("geometry_source") or "the stream"
    if not (w and h):
        if opts.geometry is None:
            reader.close()
            raise ValueError(f"--source {url}: the stream carries no sensor size: give "
                             f"--geometry WxH (or ?geometry=WxH in the URL)")
        (w, h), where = opts.geometry, "--geometry"
    prof = profile(opts.profile or REENCODE_PROFILE, w, h)
    stats: dict = {}
    notes = [f"live: {url}: {reader.format} {w}x{h} (from {where}) re-encoded as {prof.fmt} "
             f"words of a {prof.width}x{prof.height} {prof.name} camera"]

    def report() -> list[str]:
        out = [reader.stats.summary()]
        if stats.get("t_offset_us"):
            out.append(f"live: times re-based by -{stats['t_offset_us']} us (whole seconds): "
                       f"add it to the telemetry's t_us for the stream's own times")
        if stats.get("outside_sensor"):
            out.append(f"live: warning: {stats['outside_sensor']} of {stats['events_in']} "
                       f"events lay outside the {prof.width}x{prof.height} sensor and were "
                       f"dropped before encoding")
        return out
    reader.report_to = None            # the report says it, with the rest of the run's
    events = rebased(_inside(reader, prof.width, prof.height, stats), stats, REBASE_UNIT_US)
    return simulated(url, events, dataclasses.replace(opts, realtime=False), prof,
                     report=report, counters=lambda: dict(stats), notes=notes)
