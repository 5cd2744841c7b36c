"""Recall of trackers left behind: the part of an instance that lost its object's parts
while the rest of it tracks.

A tracker whose part moved out of its gate gets no events; eq. (2) gives it none, eq. (3)
never moves it, and only its springs could bring it back -- springs that, on an object
whose parts move faster than the springs act (a turning object, a fast motion), mostly
hold it to other trackers left behind.  Its instance is not lost (the loss rule counts the
trackers that still track), so re-acquisition never helps it either.

The instance's frame places every tracker's rest position; fitted to the trackers that
are *active* (A_i > A_up, eq. 6: their events keep coming), it says where the object is
now.  The frame is a rotation and a translation, its scale the instance's as placed:
the active trackers of a part-lost instance crowd onto the parts that still fire, and a
scale fitted to them shrinks, and the recalled trackers with it, until the whole
instance sits on a few parts (measured on the real biplane).  A tracker that is inactive, whose gate (``p_threshold``, eq. 2)
no longer holds its rest position in that frame, and whose gate placed there holds at
least A_up events of the last tau (eq. 6's threshold and time constant: the part is
there, firing, and nobody follows it) is recalled there, with its rest
covariance turned by the frame (R Sigma_0 R^T); the active trackers and the
inactive ones still within their gate, or whose rest position is silent (an occluded
part, an edge parallel to the motion, a part that stopped, a view that is no similarity of
the rest shape) are left as they are.  The frame is trusted while the loss rule
(springtrack.acquisition.loss) would keep the instance: at least 1 / LOSS_ACTIVE_DIV of its trackers
active (and two); below that -- a jump, an exit, a full occlusion -- nothing is recalled
and the loss rule decides.

    >>> idx, placed = left_behind(model, snap, gate_d2, recent, a_up)   # doctest: +SKIP
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .acquire import Pose, _Geometry, fit_pose, place
from .loss import LOSS_ACTIVE_DIV
from ..model import ShapeModel, TrackerSpec



def left_behind(model: ShapeModel, snap: dict, gate_d2: float, recent, min_events: float):
    """The trackers of ``model`` (its rest shape, as last placed) to recall, given their
    state ``snap`` (x, y, sxx, sxy, syy, active; one entry per tracker of the instance)
    and ``recent()`` (called only when needed) the events of the last activity time
    constant (fields x, y): (indices, the model placed at the similarity fitted to the
    active trackers).  No indices (and None) when fewer than 1 / LOSS_ACTIVE_DIV of them are
    active or none is left behind."""
    none = np.empty(0, np.intp), None
    active = np.asarray(snap["active"], bool)
    n = len(active)
    if n < 3 or active.all() or LOSS_ACTIVE_DIV * active.sum() < n or active.sum() < 2:
        return none
    x, y = (np.asarray(snap[k], float) for k in ("x", "y"))
    geo = _Geometry(model)
    pose = rigid_pose(geo, fit_pose(model, x, y, weights=active.astype(float)),
                      active.astype(float))
    th = math.radians(pose.angle_deg)
    tx, ty = geo.means(pose.tx, pose.ty, th, pose.scale)
    # the rest place's Mahalanobis distance under the tracker's own covariance (its gate)
    sxx, sxy, syy = (np.asarray(snap[k], float) for k in ("sxx", "sxy", "syy"))
    dx, dy = tx - x, ty - y
    det = np.maximum(sxx * syy - sxy * sxy, 1e-12)
    d2 = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det
    far = np.flatnonzero(~active & (d2 > gate_d2))
    if not len(far):
        return none
    cov = geo.covs(th, pose.scale)
    ev = recent()
    keep = [k for k in far
            if _in_gate(tx[k], ty[k], cov[k], ev, gate_d2) >= min_events]
    if not keep:
        return none
    return np.asarray(keep, np.intp), place(model, pose)


def _in_gate(mx: float, my: float, cov, events, gate_d2: float) -> int:
    """How many of ``events`` fall inside the gate of mean (mx, my), covariance ``cov``."""
    dx = np.asarray(events["x"], float) - mx
    dy = np.asarray(events["y"], float) - my
    sxx, sxy, syy = cov[0, 0], cov[0, 1], cov[1, 1]
    det = max(sxx * syy - sxy * sxy, 1e-12)
    return int(np.count_nonzero((syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det < gate_d2))


def recalled(model: ShapeModel, snap: dict, idx, placed: ShapeModel) -> ShapeModel:
    """``model`` with every tracker as in ``snap`` (position, covariance) but those of
    ``idx``, which take their place in ``placed``."""
    x, y, sxx, sxy, syy = (np.asarray(snap[k], float) for k in ("x", "y", "sxx", "sxy", "syy"))
    take = set(int(i) for i in idx)
    out = []
    for k, (t, p) in enumerate(zip(model.trackers, placed.trackers)):
        out.append(p if k in take else
                   TrackerSpec(t.id, float(x[k]), float(y[k]),
                               (float(sxx[k]), float(sxy[k]), float(syy[k])), t.mass))
    return replace(model, trackers=out)



def rigid_pose(geo: _Geometry, pose, w) -> Pose:
    """The rotation and translation that best map the model (``geo``) onto the positions
    to which ``pose`` is the best similarity (weights ``w``), its scale kept at 1.

    The least-squares rotation does not depend on the scale (Umeyama 1991); the
    translation puts the weighted centroid of the model's points qc, turned, on that of
    the positions: t_s = mc - s R qc for the similarity, so t = t_s + (s - 1) R qc."""
    qc = (np.asarray(w, float) @ geo.q) / float(np.sum(w))
    th = math.radians(pose.angle_deg)
    c, n = math.cos(th), math.sin(th)
    k = pose.scale - 1.0
    return Pose(pose.tx + k * (c * qc[0] - n * qc[1]), pose.ty + k * (n * qc[0] + c * qc[1]),
                pose.angle_deg, 1.0)
