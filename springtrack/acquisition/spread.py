"""A placed model's covariances measured on the events: the trackers start where eq. (4)
would take them.

A model's covariances are a prior (a part's size as written, or as learned); the
covariance a tracker settles to is that of the events it takes, the fixed point of
eqs. (2)-(5).  The events of a moving part lie on its edges (a disk fires on its rim), and
their spread about the part's centre is wider than the part's own covariance once the
gate's truncation is undone; eq. (4) grows the tracker's covariance to it only slowly
(alpha_2 = 2e-4: a few hundred ms).  Until then the gate of eq. (2) barely holds the far
side of the part's events, and a tracker placed a pixel off its part loses that far side
and settles on the near edge, a state of its own (the gated events' mean is where the
tracker is); the springs carry the whole model there (docs/acquisition.md, "Placement").

:func:`measured_spread` returns the placed model with each tracker's covariance scaled
to that fixed point on a window of events, its shape (the part's aspect and orientation,
from the model) and its mean kept: every event goes to the tracker of smallest Mahalanobis
distance within the gate (eq. 2; the model's own trackers), and a tracker whose events lie
at a mean squared Mahalanobis distance m2 under its model covariance Sigma_0 takes

    Sigma = f Sigma_0,   f = (1 + J) (m2 / 2) / covariance_bias(alpha_1, gate),
    J = alpha_1 / (2 - alpha_1)

(m2 / 2 is the scale of Sigma_0 that fits the events' second moment, trace-wise;
springtrack.reference.covariance_bias: the mean's own jitter J and the gate's truncation,
as eq. (4)'s steady state scales it), the assignment repeated under the new covariances
(ITERATIONS times).  Only the size is measured: the events of a window come from one
motion, and a moving edge fires where its normal meets the motion, so their aspect
follows the motion of the moment (a disk moving sideways fires on its left and right
rims) while their size does not; eq. (4) averages the aspect over the motions to come.
A tracker with fewer than MIN_EVENTS events keeps its covariance, as does one whose
scaled covariance leaves the params' sigma bounds (clamped as eq. (4)'s are).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .acquire import in_claimed_gates
from ..events import as_events
from ..model import ShapeModel, TrackerSpec
from ..params import Params
from ..gate import covariance_bias

ITERATIONS = 3           # assignment and covariance, repeated
MIN_EVENTS = 30          # a tracker measured on fewer events keeps its covariance
#                          (relative error of a variance from n events: sqrt(2 / n) ~ 0.26)
PER_TRACKER = 120        # events measured on: this many per tracker, nearest the placement
BLOCK = 2048             # events per block of distances (memory: BLOCK x trackers doubles)


def nearest_events(events, at_us: int | None, count: int):
    """The ``count`` events of ``events`` nearest in time to ``at_us`` (all of them if
    fewer, or ``at_us`` None), in time order.  A moving edge fires in proportion to the
    distance it moves, so a count of events spans about the same motion at any speed:
    the smear of the measurement does not grow with the object's speed."""
    ev = as_events(events)
    if at_us is None or len(ev) <= count:
        return ev
    near = np.argsort(np.abs(ev["t"].astype(np.int64) - int(at_us)), kind="stable")[:count]
    return ev[np.sort(near)]


def measured_spread(model: ShapeModel, events, params: Params, at_us: int | None = None,
                    claimed=None) -> ShapeModel:
    """``model`` (placed) with its trackers' covariances measured on ``events`` (fields
    t, x, y; a window of the object at the placement) as the steady state of eqs. (2)-(5)
    (module docstring); positions, masses, connections and params kept.  ``at_us``: the
    placement's time: the PER_TRACKER events per tracker nearest to it are measured
    (:func:`nearest_events`; all of ``events`` if None).  ``claimed``: (mx, my, sxx,
    sxy, syy) of other instances' trackers, whose events are not counted."""
    ev = nearest_events(events, at_us, PER_TRACKER * len(model.trackers))
    inside = (ev["x"] < model.width) & (ev["y"] < model.height)
    u = np.column_stack([ev["x"][inside], ev["y"][inside]]).astype(np.float64)
    if claimed is not None:
        u = u[~in_claimed_gates(u, claimed)]
    a = model.arrays()
    mu = np.column_stack([a["x"], a["y"]])
    base = np.stack([a["sxx"], a["sxy"], a["syy"]], -1)          # Sigma_0: the shape kept
    if len(u) == 0:
        return model
    gate = params.gate_d2
    j = params.alpha_position / (2.0 - params.alpha_position)
    gain = (1.0 + j) / covariance_bias(params.alpha_position, gate)
    lo, hi = params.sigma_min_px ** 2, params.sigma_max_px ** 2
    det = base[:, 0] * base[:, 2] - base[:, 1] * base[:, 1]
    f = np.ones(len(mu))
    for _ in range(ITERATIONS):
        n = np.zeros(len(mu))
        m2 = np.zeros(len(mu))
        for b in range(0, len(u), BLOCK):
            # d0^2: squared Mahalanobis distances of a block of events to every tracker
            # under Sigma_0; eq. (2) under Sigma = f Sigma_0: the nearest, within the gate
            dx = u[b:b + BLOCK, 0:1] - mu[:, 0]
            dy = u[b:b + BLOCK, 1:2] - mu[:, 1]
            d0 = (base[:, 2] * dx * dx - 2.0 * base[:, 1] * dx * dy + base[:, 0] * dy * dy) / det
            d2 = d0 / f
            best = np.argmin(d2, axis=1)
            take = d2[np.arange(len(d2)), best] < gate
            k = best[take]
            n += np.bincount(k, minlength=len(mu))
            m2 += np.bincount(k, d0[take, k], len(mu))
        new = gain * m2 / np.maximum(n, 1) / 2.0     # eqs. (4)-(5) at their fixed point
        ok = ((n >= MIN_EVENTS) & (new * base[:, 0] >= lo) & (new * base[:, 0] <= hi)
              & (new * base[:, 2] >= lo) & (new * base[:, 2] <= hi))
        if not ok.any():
            break
        f = np.where(ok, new, f)
    cov = base * f[:, None]
    trackers = [TrackerSpec(t.id, t.x, t.y, tuple(float(v) for v in cov[i]), t.mass)
                for i, t in enumerate(model.trackers)]
    return replace(model, trackers=trackers)


def measured_set(mset, events, at_us: int | None, which) -> "ModelSet":
    """``mset`` (a springtrack.instances.ModelSet, placed) with the instances ``which``
    (indices) measured by :func:`measured_spread` on ``events`` at ``at_us``, each with
    the other instances of ``which`` claiming their gates."""
    out = mset
    for g in which:
        others = [mset[h].model.arrays() for h in which if h != g]
        claimed = ([np.concatenate([a[k] for a in others]) for k in ("x", "y", "sxx", "sxy", "syy")]
                   if others else None)
        inst = mset[g]
        out = out.replaced(g, measured_spread(inst.model, events, inst.params, at_us, claimed))
    return out
