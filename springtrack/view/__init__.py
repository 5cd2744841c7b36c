"""The live view: a track streamed to Rerun as it is made (the optional extra
``springtrack[view]``).

    view = springtrack.view.open("rerun", models)        # spawns the Rerun viewer
    view = springtrack.view.open("run.rrd", models)      # records for later (rerun run.rrd)
    view.events(chunk); view.track(samples); ...; view.close()

What it shows is what ``springtrack render`` draws, with the same colours and legend
(``springtrack.render.LEGEND``): the events of the last ``window_us`` (ON red, OFF blue),
each tracker's 2σ ellipse coloured by its state (active, inactive, insensitive, lost; an
instance still searching is not drawn) and labelled with its id, the springs, each
instance's state, the mean energies and the active count, on the ``event_time``
timeline (s of event time).  Entities are listed in :data:`ENTITIES`.
"""
from __future__ import annotations

from .recorder import ENTITIES, RerunView, VIEW_EVERY_US

__all__ = ["open", "check_target", "add_arguments", "RerunView", "ENTITIES", "VIEW_EVERY_US", "SPAWN", "HELP"]

SPAWN = "rerun"          # the --view value that spawns the viewer
HELP = ("stream the track live to Rerun: 'rerun' spawns the viewer, FILE.rrd records for "
        "later (rerun FILE.rrd); needs pip install 'springtrack[view]' (docs/live.md)")


def check_target(target: str) -> None:
    """ValueError unless ``target`` is ``rerun`` or a path ending in ``.rrd``."""
    if target != SPAWN and not str(target).endswith(".rrd"):
        raise ValueError(f"--view must be {SPAWN} (spawn the viewer) or a FILE.rrd to "
                         f"record, got {target!r}")


def open(target: str, models, name: str = "springtrack",          # noqa: A001
         every_us: int = VIEW_EVERY_US) -> RerunView:
    """A view of ``models`` (a ShapeModel or ModelSet; None: trackers without springs)
    to ``target``: ``"rerun"`` (spawn the viewer) or a path ending in ``.rrd``."""
    check_target(target)
    return RerunView(target, models, name=name, every_us=every_us)


def add_arguments(p) -> None:
    """--view and --view-every-us, for every command that shows a track live
    (springtrack track, hostctl monitor)."""
    p.add_argument("--view", metavar="rerun|FILE.rrd", help=HELP)
    p.add_argument("--view-every-us", type=int, default=VIEW_EVERY_US, metavar="US",
                   help=f"with --view: a frame per US µs of event time, with that "
                        f"period's events (default {VIEW_EVERY_US})")
