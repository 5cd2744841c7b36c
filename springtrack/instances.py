"""Several model instances in one tracker: the layout every backend shares.

A tracker holds one or more *instances* of shape models -- different models (``--model
face.toml --model grid.toml``) and several copies of one (``--instances N``) -- in one
state: the trackers of all instances side by side, instance by instance (instance g owns
trackers ``[t0, t1)`` and connections ``[c0, c1)``, whose ends are trackers of g only).
Eq. (2) then assigns each event to the most probable sensitive tracker of the union: an
event feeds at most one tracker of one instance, and ties go to the lowest index (the
first instance).  Springs, energies (eq. 13), the criteria (eqs. 21-22), the centre of
mass and the similarity frame are per instance.

Parameters.  The event assignment shares one gate, one clock and one spring period, so
``p_threshold``, ``activity_tau_us``, ``activity_threshold``, ``spring_period``,
``sigma_min_px`` and ``sigma_max_px`` (:data:`SHARED_PARAMS`) are the tracker's: every
instance must resolve them to the same values.  The rest (:data:`INSTANCE_PARAMS`: the
update gains of eqs. 3-4 and the springs' criteria and frames) are each instance's own,
from its model's ``[params]``.  Either way the order is defaults < the model's
``[params]`` < the ``params`` given (``--params``).

Identity.  Tracker ids stay as written in the model files when they are unique across
the instances; an id that several instances share is prefixed with its instance's label
``name#k`` (the model's name and its 1-based number among the instances of that name):
``face26#2/eye_l``.

Capacity (:mod:`springtrack.limits`): a model holds at most ``MAX_TRACKERS`` trackers and
``MAX_CONNECTIONS`` connections; a set at most ``MAX_INSTANCES`` instances and
``MAX_SET_TRACKERS`` / ``MAX_SET_CONNECTIONS`` in all.  Beyond them :class:`ModelError`
names the count and the limit; nothing is truncated.

State.  Each instance is :data:`SEARCHING` (not yet placed by an acquisition),
:data:`TRACKING` or :data:`LOST` (springtrack.acquisition.loss decides); only a tracking instance's
trackers are sensitive and only its springs run.  :data:`NOT_FOUND` is the verdict of an
acquisition whose search budget is spent (the input ended, or ``Tracker``'s
``acquire_budget_ms`` of event time passed) without finding the instance; no kernel holds
it, the Tracker's sample rows of a search carry it (springtrack.tracker).
"""
from __future__ import annotations

import re

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from .limits import MAX_INSTANCES, MAX_SET_CONNECTIONS, MAX_SET_TRACKERS
from .model import ModelError, ShapeModel, load_model
from .params import Params, resolve
from .track import STATE_NAMES

# the parameters of the event assignment, one value for all instances
SHARED_PARAMS = ("p_threshold", "activity_tau_us", "activity_threshold", "spring_period",
                 "sigma_min_px", "sigma_max_px", "motion_tau_us", "prediction_horizon_us",
                 "polarity_gain")
# each instance's own
INSTANCE_PARAMS = ("alpha_position", "alpha_covariance", "energy_scale", "energy_gain",
                   "energy_kind", "pull_frame", "cartesian_frame")


class InstanceState(IntEnum):
    """An instance's state; the value is the code in the kernels and on the wire."""
    SEARCHING = 0      # not yet placed by an acquisition: insensitive
    TRACKING = 1
    LOST = 2           # its evidence collapsed (the loss rule): insensitive, positions kept
    NOT_FOUND = 3      # its search budget spent unfound (the Tracker's rows only)


SEARCHING, TRACKING, LOST = InstanceState.SEARCHING, InstanceState.TRACKING, InstanceState.LOST
NOT_FOUND = InstanceState.NOT_FOUND
# the names in the track CSV (the track record's definition)
assert STATE_NAMES == tuple(s.name.lower().replace("_", " ") for s in InstanceState)


@dataclass(frozen=True)
class Instance:
    """One model instance of a set: its model, label, parameters and index ranges."""
    model: ShapeModel
    label: str               # "name#k"
    params: Params
    t0: int                  # trackers [t0, t1)
    t1: int
    c0: int                  # connections [c0, c1)
    c1: int

    @property
    def n(self) -> int:
        return self.t1 - self.t0

    @property
    def nc(self) -> int:
        return self.c1 - self.c0


def _as_models(models) -> list:
    if isinstance(models, (ShapeModel, str)) or hasattr(models, "__fspath__"):
        models = [models]
    out = [load_model(m) for m in models]
    if not out:
        raise ModelError("a tracker needs at least one model")
    return out


class ModelSet:
    """The instances one tracker holds, in order.

    ``ModelSet(models, params=None, instances=1)``: ``models`` a ShapeModel, preset name or
    TOML path, or a list of them; ``instances`` copies of each (placed where the model
    says: an acquisition moves them apart); ``params`` as for ``springtrack.Tracker``
    (Params, dict of overrides, TOML path or None), resolved per instance over its
    model's ``[params]``.  Raises ModelError on a set beyond the limits, models of
    different sensors, or models that disagree on a shared parameter.
    """

    def __init__(self, models, params=None, instances: int = 1):
        models = _as_models(models)
        if isinstance(instances, bool) or not isinstance(instances, int) or instances < 1:
            raise ModelError(f"instances must be a whole number >= 1, got {instances!r}")
        models = [m for m in models for _ in range(instances)]
        if len(models) > MAX_INSTANCES:
            raise ModelError(f"{len(models)} instances exceed the limit of {MAX_INSTANCES}")
        n = sum(len(m.trackers) for m in models)
        nc = sum(len(m.connections) for m in models)
        if n > MAX_SET_TRACKERS:
            raise ModelError(f"{len(models)} instances hold {n} trackers, beyond the limit of "
                             f"{MAX_SET_TRACKERS} trackers in one tracker")
        if nc > MAX_SET_CONNECTIONS:
            raise ModelError(f"{len(models)} instances hold {nc} connections, beyond the limit "
                             f"of {MAX_SET_CONNECTIONS} connections in one tracker")
        w, h = models[0].width, models[0].height
        for m in models[1:]:
            if (m.width, m.height) != (w, h):
                raise ModelError(f"{m.source}: sensor {m.width}x{m.height} differs from "
                                 f"{models[0].source}'s {w}x{h}: the instances of one tracker "
                                 f"share its sensor")
        self.width, self.height = w, h
        self.params_given = params
        plist = [resolve(m, params) for m in models]
        _check_shared(models, plist)
        labels = _labels(models)
        self.instances: list[Instance] = []
        t = c = 0
        for m, p, lab in zip(models, plist, labels):
            self.instances.append(Instance(m, lab, p, t, t + len(m.trackers),
                                           c, c + len(m.connections)))
            t += len(m.trackers)
            c += len(m.connections)
        self.n, self.nc = t, c
        self.ids = unique_ids(self.instances)

    # ---- views ------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.instances)

    def __iter__(self):
        return iter(self.instances)

    def __getitem__(self, g: int) -> Instance:
        return self.instances[g]

    @property
    def models(self) -> list:
        return [i.model for i in self.instances]

    @property
    def params(self) -> Params:
        """The first instance's parameters (the shared ones are every instance's)."""
        return self.instances[0].params

    @property
    def params_list(self) -> list:
        return [i.params for i in self.instances]

    def instance_of(self) -> np.ndarray:
        """(n,) int32: the instance of each tracker."""
        return np.repeat(np.arange(len(self), dtype=np.int32), [i.n for i in self.instances])

    def replaced(self, g: int, model: ShapeModel) -> "ModelSet":
        """This set with instance g's model replaced by ``model`` (same trackers and
        connections, e.g. placed elsewhere by an acquisition), parameters kept."""
        old = self.instances[g]
        if model.ids != old.model.ids or len(model.connections) != old.nc:
            raise ModelError(f"instance {old.label}: a replacement must have the same trackers "
                             f"and connections")
        new = object.__new__(ModelSet)
        new.__dict__.update(self.__dict__)
        new.instances = list(self.instances)
        new.instances[g] = Instance(model, old.label, old.params, old.t0, old.t1, old.c0, old.c1)
        return new

    def with_params(self, plist) -> "ModelSet":
        """This set with the instances' parameters replaced (one Params, or one per
        instance), checked for the shared ones."""
        plist = per_instance(plist, len(self))
        _check_shared(self.models, plist)
        new = object.__new__(ModelSet)
        new.__dict__.update(self.__dict__)
        new.instances = [Instance(i.model, i.label, p, i.t0, i.t1, i.c0, i.c1)
                         for i, p in zip(self.instances, plist)]
        return new

    def arrays(self) -> dict:
        """The kernels' arrays of every instance side by side (``ShapeModel.arrays()``
        concatenated, connection ends as indices into all trackers), and per instance
        ``inst_t0``, ``inst_t1``, ``inst_c0``, ``inst_c1`` (int32)."""
        parts = [i.model.arrays() for i in self.instances]
        out = {}
        for key in parts[0]:
            out[key] = np.concatenate([p[key] for p in parts])
        for key in ("ca", "cb"):
            out[key] = np.concatenate([p[key] + i.t0 for p, i in zip(parts, self.instances)]
                                      ).astype(np.int32)
        for key in ("t0", "t1", "c0", "c1"):
            out["inst_" + key] = np.array([getattr(i, key) for i in self.instances], np.int32)
        return out


def per_instance(params, count: int) -> list:
    """``params`` (one Params for all, or a sequence of one per instance) as a list."""
    if isinstance(params, Params):
        return [params] * count
    plist = list(params)
    if len(plist) != count or not all(isinstance(p, Params) for p in plist):
        raise ValueError(f"need one Params or {count} of them, one per instance")
    return plist


def _check_shared(models, plist) -> None:
    first = plist[0]
    for m, p in zip(models[1:], plist[1:]):
        for name in SHARED_PARAMS:
            a, b = getattr(first, name), getattr(p, name)
            if a != b:
                raise ModelError(
                    f"{m.source}: {name}={b!r} differs from {a!r} of {models[0].source}; "
                    f"{', '.join(SHARED_PARAMS)} are shared by all the instances of a "
                    f"tracker (one event assignment): set it with --params")


def _labels(models) -> list:
    """``name#k``: k the 1-based number of the instance among those of its model's name;
    the name's characters outside the tracker ids' safe set (springtrack.limits.TRACKER_ID)
    become ``_``, since a label prefixes ids that name CSV columns."""
    seen: dict = {}
    out = []
    for m in models:
        seen[m.name] = seen.get(m.name, 0) + 1
        safe = re.sub(r"[^A-Za-z0-9_.\-]", "_", m.name)
        out.append(f"{'_' + safe[1:] if safe[:1] in ('-', '.') else safe}#{seen[m.name]}")
    return out


def unique_ids(instances) -> list:
    """Tracker ids, as written where unique across the instances, else prefixed with
    the instance's label (``face26#2/eye_l``)."""
    count: dict = {}
    for inst in instances:
        for i in inst.model.ids:
            count[i] = count.get(i, 0) + 1
    ids = [i if count[i] == 1 else f"{inst.label}/{i}"
           for inst in instances for i in inst.model.ids]
    if len(set(ids)) != len(ids):          # a prefixed id equal to another's own id
        ids = [f"{inst.label}/{i}" for inst in instances for i in inst.model.ids]
    return ids
