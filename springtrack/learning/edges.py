"""Edges: the leading and trailing edges of one uniform part, seen before it has moved.

A uniform part (a dark shape on a bright wall) fires only where its outline crosses
pixels: moving slowly, only the stretches of its outline across the motion fire, the
leading edge with one polarity (OFF for a dark part) and the trailing edge, on the far
side of the silent inside, with the other.  The free trackers follow them apart, and
neither the outline rule (learning.outlines: the stretches along the motion do not fire,
so no curve surrounds the part) nor the covered pixels of Pool.gaps (the part has not
moved by its own size) joins them: the model would place a part's tracker on an edge, a
radius from the part's centre.

Two such edges bend toward each other, which tells them from the facing edges of two
neighbouring parts (the gap between them), whose arcs bend away from each other.  A pair
of trackers is two edges of one part when

* each one's recent pixels bend (:func:`bends`: a parabola fitted across its major axis
  sags by at least :data:`BEND_MIN_PX` over its length) toward the other, within
  :data:`FACING_COS` (the side of its centre of curvature against the direction to the
  other's mean), their radii of curvature within a factor :data:`RADIUS_RATIO` (a face's
  outline and an eye are not one part) and their means within :data:`EDGE_SPAN` mean
  radii of each other;
* their recent events have opposite polarities, each at least ``edge_polarity`` (a
  learner parameter) of its events one way (a textured object's pieces fire both);
* their union is no wider than a part may be (Pool.union_fits).

The merge runs once, at the discovery's end (discovery.join_edges): run at every look,
like the outline merge, it joined a disc's crescents before the outline merge did and
changed how the pool evolved, for the worse on the grids.  Elongated shapes (a bar, an
ellipse moving along its long axis) bend too little or too unevenly and keep their
pieces.  Measured in docs/learning.md ("A rigid scene, a hand-held camera").
"""
from __future__ import annotations

import numpy as np

BEND_MIN_PX = 0.5        # the sag (px) over an edge's length that makes it an arc
BEND_MIN_PIXELS = 8      # recent pixels an edge needs for its bend to be measured
FACING_COS = 0.5         # each bends toward the other within this (cos of the angle)
RADIUS_RATIO = 4.0       # their radii of curvature within this factor
EDGE_SPAN = 3.5          # their means within this many mean radii
EDGE_MIN_EVENTS = 5.0    # recent events a tracker needs to be judged


def bends(pool, t_from: int) -> None:
    """Set each tracker's ``arc_x``, ``arc_y`` (the centre of curvature of its recent
    pixels, px) and ``arc_r`` (their radius of curvature, px) in ``pool.book``; ``arc_r``
    0 where its pixels (those that fired since ``t_from`` within two sigmas of its mean)
    are too few or do not bend."""
    n = pool.n
    for k in ("arc_x", "arc_y", "arc_r"):
        pool.book[k][:n] = 0.0
    recent = pool.last >= t_from
    for i in np.flatnonzero(pool.recent[:n] >= EDGE_MIN_EVENTS).tolist():
        xx, yy = pool.pixels_near(i, recent)
        if len(xx) < BEND_MIN_PIXELS:
            continue
        (mx, my), cov = pool.gaussian(i)
        dx, dy = xx - mx, yy - my
        vecs = np.linalg.eigh(cov)[1]
        e1, e2 = vecs[:, -1], vecs[:, 0]
        u = dx * e1[0] + dy * e1[1]                  # along the edge
        v = dx * e2[0] + dy * e2[1]                  # across it
        A = np.column_stack([np.ones_like(u), u, u * u])
        coef, *_ = np.linalg.lstsq(A, v, rcond=None)
        kappa = float(coef[2])
        span = float(np.max(np.abs(u - u.mean())))
        if not abs(kappa) * span * span >= BEND_MIN_PX:
            continue
        # the parabola v = c0 + c1 u + kappa u^2: its vertex, and the centre of the circle
        # of curvature there, 1 / (2 kappa) across it (toward +e2 where kappa > 0)
        u0 = -float(coef[1]) / (2.0 * kappa)
        v0 = float(coef[0]) + 0.5 * float(coef[1]) * u0 + 1.0 / (2.0 * kappa)
        pool.book["arc_x"][i] = mx + u0 * e1[0] + v0 * e2[0]
        pool.book["arc_y"][i] = my + u0 * e1[1] + v0 * e2[1]
        pool.book["arc_r"][i] = 1.0 / (2.0 * abs(kappa))


def facing_pairs(pool):
    """(i, j, distance) arrays of the pairs of trackers that are two edges of one part
    (see the module), nearest first."""
    n = pool.n
    b = pool.book
    r = b["arc_r"][:n]
    rec = np.maximum(b["recent"][:n], 1e-9)
    f = b["on"][:n] / rec
    share = pool.lp.edge_polarity
    sign = np.where(f >= share, 1, np.where(f <= 1.0 - share, -1, 0))
    ok = (r > 0) & (sign != 0) & (b["recent"][:n] >= EDGE_MIN_EVENTS)
    idx = np.flatnonzero(ok)
    if len(idx) < 2:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0)
    x, y, ri = pool.x[idx], pool.y[idx], r[idx]
    # the side each one bends toward: from its mean to its centre of curvature
    sx, sy = b["arc_x"][idx] - x, b["arc_y"][idx] - y
    sn = np.maximum(np.hypot(sx, sy), 1e-9)
    sx, sy = sx / sn, sy / sn
    dx = x[None, :] - x[:, None]                  # from a to b
    dy = y[None, :] - y[:, None]
    d = np.maximum(np.hypot(dx, dy), 1e-9)
    a_faces = (sx[:, None] * dx + sy[:, None] * dy) / d >= FACING_COS
    b_faces = -(sx[None, :] * dx + sy[None, :] * dy) / d >= FACING_COS
    mean_r = 0.5 * (ri[:, None] + ri[None, :])
    ratio = np.maximum(ri[:, None], ri[None, :]) / np.minimum(ri[:, None], ri[None, :])
    pair = (np.triu(a_faces & b_faces & (ratio <= RADIUS_RATIO) & (d <= EDGE_SPAN * mean_r), 1)
            & (sign[idx][:, None] != sign[idx][None, :]))
    a, c = np.nonzero(pair)
    order = np.argsort(d[a, c], kind="stable")
    return idx[a[order]], idx[c[order]], d[a, c][order]
