"""A shape model against the sensor it tracks on: the guard rails.

A model's ``[sensor]`` says which sensor its positions are in.  Tracking a recording (or
a camera) of another size with it silently skips every event outside the model's sensor
and leaves trackers where no event can reach them, so every entry point checks first:

    >>> model = fit_model(load_model("face.toml"), 640, 480, sensor_from=None,
    ...                   what="rec.raw")                           # doctest: +SKIP

* the model's sensor equals the source's: the model as it is;
* they differ: :class:`SensorMismatch` naming both sizes and the two ways out, unless
  ``sensor_from`` says which to use: ``"file"`` (or ``"source"``: the source's size,
  trackers kept where they are) or ``"model"`` (the model's: events outside it are skipped
  and counted by the tracker);
* then every tracker must lie on the sensor in use (:class:`TrackersOutside`).

Both errors are :class:`springtrack.model.ModelError` (ValueError) subclasses carrying their
NACK code for the firmware (``code``: ``Nack.SENSOR_MISMATCH``), as parameter errors do.
"""
from __future__ import annotations

import dataclasses

from .model import ModelError, ShapeModel
from .wire import Nack

SENSOR_FROM = ("file", "model")          # the choices of --sensor-from (firmware: source)
SOURCE_WORDS = ("file", "source")        # both mean: the source's geometry


class SensorError(ModelError):
    """The model does not fit the sensor it would track on."""
    code = Nack.SENSOR_MISMATCH


class SensorMismatch(SensorError):
    """The model's [sensor] is not the source's."""


class TrackersOutside(SensorError):
    """Trackers lie outside the sensor."""


def outside_trackers(model: ShapeModel, width: int | None = None,
                     height: int | None = None) -> list:
    """The trackers whose initial mean lies outside ``width`` x ``height`` (default: the
    model's own sensor): ``[(id, x, y), ...]``; x must be in [0, width), y in [0, height)."""
    w = model.width if width is None else width
    h = model.height if height is None else height
    return [(t.id, t.x, t.y) for t in model.trackers
            if not (0 <= t.x < w and 0 <= t.y < h)]


def check_inside(model: ShapeModel, width: int | None = None,
                 height: int | None = None) -> ShapeModel:
    """``model``, or :class:`TrackersOutside` naming the trackers off its own sensor (or off
    ``width`` x ``height``)."""
    w = model.width if width is None else width
    h = model.height if height is None else height
    bad = outside_trackers(model, w, h)
    if bad:
        shown = ", ".join(f"{i} ({x:g}, {y:g})" for i, x, y in bad[:6])
        more = f" and {len(bad) - 6} more" if len(bad) > 6 else ""
        raise TrackersOutside(
            f"{model.source}: {len(bad)} tracker(s) outside the {w}x{h} sensor: {shown}{more};"
            f" every tracker needs 0 <= x < {w} and 0 <= y < {h}")
    return model


def fit_model(model: ShapeModel, width: int | None, height: int | None,
              sensor_from: str | None = None, what: str = "the recording",
              flag: str = "--sensor-from", source_word: str = "file",
              way_out: str | None = None) -> ShapeModel:
    """The model to track a ``width`` x ``height`` source with (see the module docstring);
    ``width``/``height`` None: the source's size is unknown (npy, CSV), only the trackers
    are checked.  ``what`` names the source, ``flag`` and ``source_word`` the option in
    the error message; ``way_out``: the mismatch's way out instead of that option (for a
    model that came another way than the option's command, e.g. uploaded)."""
    if sensor_from is not None and sensor_from not in SENSOR_FROM + SOURCE_WORDS:
        raise ValueError(f"{flag} must be {source_word} or model, got {sensor_from!r}")
    if width and height and (model.width, model.height) != (width, height):
        if sensor_from in SOURCE_WORDS:          # checked before the model is rebuilt on it
            check_inside(model, int(width), int(height))
            model = dataclasses.replace(model, width=int(width), height=int(height))
        elif sensor_from is None:
            raise SensorMismatch(
                f"{model.source}: the model's [sensor] is {model.width}x{model.height} but "
                f"{what} is {width}x{height}; " + (way_out or
                f"fix the model's [sensor] and positions, or pass "
                f"{flag} {source_word} (the model on the {width}x{height} sensor, its "
                f"trackers where they are) or {flag} model (keep {model.width}x{model.height}:"
                f" events outside it are skipped and counted)"))
    return check_inside(model)
