"""Camera sources by URL, as pyserial maps port URLs to handler modules.

    src = open_source("sim:face_occlusion", SourceOptions(seconds=5, realtime=False))
    cam = src.open_camera()          # a firmware_sim.camera.Camera, simulated or real

A URL is ``SCHEME:TARGET``.  :data:`SCHEMES` maps each scheme to the module that handles
it, imported only when a URL names it.  A handler module defines ``USAGE`` (``"sim:SCENE"``),
``HELP`` (one line for ``firmware-sim run --help``) and ``open(target, opts, url) ->
CameraSource``; :func:`register` adds one without editing any caller.

Simulated sources are generators of event arrays (``t`` µs ascending, ``x``, ``y``, ``p``),
or of ready word chunks (a recording replayed as it is), served by a
:class:`firmware_sim.simcam.SimCamera` that presents itself as the CCam ATIS or as a
Prophesee-style EVK streaming EVT 2.0 / 2.1 / 3.0 (:func:`simulated`, ``--profile``); a
Python program can serve an array it holds with :func:`events_source`.  Every source says
what it serves: the device profile (word format and sensor geometry) the loop decodes.
"""
from __future__ import annotations

import dataclasses
import importlib
import textwrap
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

from springtrack import live
from springtrack.events import as_events

from .. import faults as _faults
from .. import camera as camusb

if TYPE_CHECKING:
    from ..simcam import SimCamera

# scheme -> handler module
SCHEMES: dict[str, str] = {
    "sim": "firmware_sim.sources.sim",
    "replay": "firmware_sim.sources.replay",
    "usb": "firmware_sim.sources.usb",
}
# live streams: springtrack.live owns their handlers, one module here serves them all
SCHEMES.update({s: "firmware_sim.sources.live" for s in live.SCHEMES})


@dataclass
class SourceOptions:
    """What ``firmware-sim run`` tells every source; each handler uses what applies to it."""
    seconds: float | None = None      # simulated: event time to serve (None: all of it)
    seed: int = 0                     # scene and fault seed
    realtime: bool = True             # simulated: release events at their timestamps
    faults: str | tuple = ()          # fault names (firmware_sim.faults), simulated only
    serial: int | None = None         # the camera's serial (None: the first found)
    profile: str | None = None        # device profile (firmware_sim.camera.PROFILES); None:
                                      # the source's own (replay: the file's format)
    biases: dict = field(default_factory=dict)    # read at every (re)connection
    geometry: tuple[int, int] | None = None     # usb EVT boards: the sensor's width, height
    # replay: the recording's preparation (springtrack.prep, the options of springtrack
    # track): (width, height) -> a Preparer, or None to replay the recording as it is
    prepare: Callable[[int, int], object] | None = None


@dataclass
class CameraSource:
    """An opened source: how to (re)open its camera and what is known about it."""
    url: str
    open_camera: Callable[[], camusb.Camera]   # called at every (re)connection
    # how the loop decodes its transfers: word format and sensor geometry
    profile: camusb.DeviceProfile = camusb.PROFILES["ccam_atis"]
    device: SimCamera | None = None            # the simulated camera, None for hardware
    default_model: Callable[[], object] = lambda: None    # the scene's own model, if any
    report: Callable[[], list[str]] = lambda: []         # end-of-run lines (what was dropped)
    rewind: Callable[[], None] | None = None   # serve the source again from its start
    # what the source dropped before the camera: events_in, outside_sensor (statistics)
    counters: Callable[[], dict] = dict
    notes: list[str] = field(default_factory=list)    # start-up lines (re-encoding, drops)

    @property
    def width(self) -> int:
        return self.profile.width

    @property
    def height(self) -> int:
        return self.profile.height


def register(scheme: str, module: str) -> None:
    """Serve ``scheme:TARGET`` URLs with handler ``module`` (an importable module name)."""
    SCHEMES[scheme] = module


def handler(scheme: str):
    if scheme not in SCHEMES:
        raise ValueError(f"unknown source scheme {scheme!r}; use {usage()}")
    return importlib.import_module(SCHEMES[scheme])


def usage() -> str:
    """The URL forms of every registered scheme: ``sim:SCENE | replay:FILE | usb``."""
    return " | ".join(handler(s).USAGE for s in _one_per_handler())


def _one_per_handler() -> list[str]:
    """The first scheme of each handler module (one module may serve several)."""
    first: dict[str, str] = {}
    for scheme, module in SCHEMES.items():
        first.setdefault(module, scheme)
    return list(first.values())


def describe(indent: int = 0, width: int = 88) -> str:
    """A help paragraph per registered scheme, ``indent`` spaces in from the second line."""
    pad = " " * indent
    return "\n".join(textwrap.fill(f"{handler(s).USAGE}: {handler(s).HELP}", width,
                                   subsequent_indent=pad + "  ", initial_indent=pad
                                   ).removeprefix(pad if i == 0 else "")
                     for i, s in enumerate(_one_per_handler()))


def open_source(url: str, opts: SourceOptions | None = None) -> CameraSource:
    """The source ``url`` names; ValueError (or CameraError, FileNotFoundError) saying
    what is wrong with it."""
    opts = opts or SourceOptions()
    _faults.parse(opts.faults)                 # unknown fault names first, for every source
    scheme, _, target = url.partition(":")
    try:
        mod = handler(scheme)
    except ValueError as e:
        raise ValueError(f"--source {url!r}: {e}") from None
    return mod.open(target, opts, url)


def profile(name: str | None, width: int | None = None, height: int | None = None,
            legacy: bool | None = None) -> camusb.DeviceProfile:
    """The device profile ``name`` (default ``ccam_atis``) for a sensor of ``width`` x
    ``height`` (EVT boards: any size the words address; the CCam ATIS is 304 x 240)."""
    name = name or "ccam_atis"
    if name not in camusb.PROFILES:
        raise ValueError(f"unknown device profile {name!r}; known: {', '.join(camusb.PROFILES)}")
    p = camusb.PROFILES[name]
    changes = {}
    if p.fmt != "ccam" and width and height:
        changes.update(width=int(width), height=int(height))
    if legacy is not None and p.fmt == "evt21":
        changes["legacy"] = bool(legacy)
    return dataclasses.replace(p, **changes) if changes else p


def simulated(url: str, events, opts: SourceOptions,
              prof: camusb.DeviceProfile | None = None, restart=None, **known) -> CameraSource:
    """A source whose ``events`` (an iterable of event arrays, or of word chunks already
    in ``prof``'s format) are served by a simulated camera presenting itself as ``prof``
    (default: the CCam ATIS; an EVT profile: a Prophesee-style EVK), with ``opts``' faults,
    clock and serial; ``restart()`` returns the same events anew (a replay from the start;
    None: cannot rewind); ``known``: further :class:`CameraSource` fields (default model,
    report, counters)."""
    from ..simcam import SimBackend, SimCamera
    prof = prof or camusb.PROFILES["ccam_atis"]
    faults = _faults.Faults(_faults.parse(opts.faults), seed=opts.seed)
    cam = SimCamera(events, realtime=opts.realtime, faults=faults, fmt=prof.fmt,
                    legacy=prof.legacy)
    backend = SimBackend(cam, vid=prof.vid, pid=prof.pid)

    def open_camera():
        return camusb.Camera.open(prof, opts.serial, backend=backend, biases=opts.biases)
    rewind = (lambda: cam.restart(restart())) if restart is not None else None
    return CameraSource(url, open_camera, profile=prof, device=cam, rewind=rewind, **known)


def failure(source: CameraSource) -> str | None:
    """Why a simulated source stopped before its end (its events raised), else None."""
    return source.device.source_error if source.device is not None else None


def events_source(events, chunk_events: int = 4096):
    """An in-memory event array, in pieces of ``chunk_events``."""
    ev = as_events(events)
    for s in range(0, len(ev), chunk_events):
        yield ev[s:s + chunk_events]
