"""Outlines: the pieces of one part that fires only at its edges.

A uniform part (a dark disc, a drawn shape) fires where its edges cross pixels, never
inside: the free trackers follow pieces of its outline (arcs, the tips of its leading and
trailing crescents), and the "two edges" rule of the merges (Pool.gaps) joins them only
once the part has moved by its own size since the window's start.  Its outline shows it
sooner: over the trackers' memory (``life_tau_us``) the part draws a curve of recent
pixels around its centre (a ring, or a crescent three quarters round), apart from its
neighbours' curves.  Trackers on one such curve are merged as pieces of one part.

The curve is a connected component of the recent pixels (8 neighbours, lone pixels
dropped as noise) that

* is small: sigma at most :data:`OUTLINE_SIZE` of the widest part (``sigma_max_px``), so a
  long contour (a head's outline), a textured object or a swept background merges nothing;
* surrounds its centroid: pixels in at least ``outline_cover`` of :data:`OUTLINE_BINS`
  directions, counting those beyond half its RMS radius (a straight edge covers two or
  three);
* is a thin circle or close to one: the circle fitted to its pixels (algebraic least
  squares) leaves an RMS residual of at most :data:`OUTLINE_THIN` of its radius (a square's
  outline 0.11; a triangle's or a 2:1 ellipse's 0.22, which keep their pieces), where a
  part that fires all over, or two parts whose curves touch (a figure eight), leave more;

and a tracker is on it when most of its events in the look's batch lie on it and its mean
lies within :data:`OUTLINE_INSIDE` radii (plus a pixel) of the circle's centre: a tracker
between two parts is not a piece of either.

At the discovery's end (discovery.join_outlines) the test is wider (``any_shape``): any
closed curve that keeps one radius per direction (a square, a triangle, an ellipse) or
rings a hole, as wide as a part may be; a tracker is on it when most of its recent pixels
within two sigmas are (:meth:`Outlines.of_pixels`).

Measured in docs/learning.md ("Uniform parts"): one tracker per disc on the second
generator's grid; its face learns the same models as without it, the project
simulator's face one tracker fewer on two of three seeds (one part less covered on one).
"""
from __future__ import annotations

import math

import numpy as np

from . import batch as _learn

OUTLINE_BINS = 16             # directions about an outline's centroid
OUTLINE_MIN_PIXELS = 8        # a component of fewer pixels is no outline
OUTLINE_SIZE = 0.5            # an outline's sigma is at most this share of sigma_max_px
OUTLINE_THIN = 0.15           # RMS distance of its pixels from its fitted circle / radius
OUTLINE_INSIDE = 1.25         # a tracker on it lies this many radii (+1 px) from its centre
OUTLINE_HOLE = 0.35           # any_shape: or no pixel within this many radii of its centroid
                              # (a part that moved: a thick ring round its silent inside)


class Outlines:
    """The outlines of parts among a ``height`` x ``width`` sensor's recent pixels."""

    def __init__(self, width: int, height: int):
        self.label = np.zeros((height, width), np.int32)
        self.stack = np.empty(width * height, np.int32)
        self.circle = np.zeros((1, 3))            # (n + 1, 3): centre x, y, radius

    def find(self, last: np.ndarray, t_from: int, sigma_max_px: float,
             cover: float, any_shape: bool = False) -> np.ndarray:
        """Label the components of the pixels that fired since ``t_from`` (``last``: each
        pixel's latest event time) into ``self.label`` and fit their circles
        (``self.circle``); returns (n + 1,) bool: component k is a part's outline (index
        0, no component, is false).  ``any_shape``: an outline may be as wide as a part
        (sigma up to ``sigma_max_px``) and any curve that keeps one radius per direction
        (:func:`_radial_spread`) or rings a hole (no pixel within OUTLINE_HOLE of its
        median radius from its centroid); ``self.circle`` then holds its centroid and
        median radius.  Without it: only a thin circle at most half as wide."""
        n = _learn.recent_components(last, t_from, self.label, self.stack)
        ok = np.zeros(n + 1, bool)
        self.circle = np.zeros((n + 1, 3))
        if n == 0:
            return ok
        yy, xx = np.nonzero(self.label)
        lab = self.label[yy, xx]
        cnt = np.bincount(lab, minlength=n + 1).astype(float)
        c = np.maximum(cnt, 1.0)
        mx = np.bincount(lab, xx, n + 1) / c
        my = np.bincount(lab, yy, n + 1) / c
        dx, dy = xx - mx[lab], yy - my[lab]
        vx = np.bincount(lab, dx * dx, n + 1) / c
        vy = np.bincount(lab, dy * dy, n + 1) / c
        far = dx * dx + dy * dy >= 0.25 * (vx + vy)[lab]
        directions = _directions(dx[far], dy[far], lab[far], n + 1)
        size = (1.0 if any_shape else OUTLINE_SIZE) * sigma_max_px
        ok = ((cnt >= OUTLINE_MIN_PIXELS)
              & (np.maximum(vx, vy) <= size ** 2)
              & (directions >= cover * OUTLINE_BINS))
        ok[0] = False
        r_max = math.sqrt(2.0) * size
        for k in np.flatnonzero(ok).tolist():
            on = lab == k
            fit = _circle(dx[on], dy[on])
            if fit is not None and fit[3] <= OUTLINE_THIN * fit[2] and fit[2] <= r_max:
                cx, cy, r, _ = fit
                self.circle[k] = (mx[k] + cx, my[k] + cy, r)
                continue
            ok[k] = False
            if any_shape:        # not a circle: an outline if it keeps one radius per
                r, thick = _radial_spread(dx[on], dy[on])     # direction, or rings a hole
                hole = float(np.min(np.hypot(dx[on], dy[on])))
                self.circle[k] = (mx[k], my[k], r)
                ok[k] = (thick <= OUTLINE_THIN * r or hole >= OUTLINE_HOLE * r) and r <= r_max
        return ok

    def of_pixels(self, ok: np.ndarray, pool) -> np.ndarray:
        """(n,) the outline most of each of ``pool``'s trackers' labelled pixels within two
        sigmas of its mean lie on, if its mean lies within OUTLINE_INSIDE radii of the
        outline's centre (plus a pixel); 0 if none (:meth:`of_trackers` without the
        events: at the discovery's end)."""
        out = np.zeros(pool.n, np.int64)
        labelled = self.label > 0
        for i in range(pool.n):
            xx, yy = pool.pixels_near(i, labelled)
            lab = self.label[yy, xx]
            lab = lab[ok[lab]]
            if len(lab):
                out[i] = int(np.bincount(lab).argmax())
        cx, cy, r = self.circle[out].T
        out[np.hypot(pool.x - cx, pool.y - cy) > OUTLINE_INSIDE * r + 1.0] = 0
        return out

    def of_trackers(self, ok: np.ndarray, ev: np.ndarray, winner: np.ndarray,
                    x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(n,) the outline most of each tracker's events in ``ev`` (taken as ``winner``
        says) lie on, if its mean (``x``, ``y``) lies within OUTLINE_INSIDE radii of the
        outline's centre (plus a pixel); 0 if none."""
        n = len(x)
        out = np.zeros(n, np.int64)
        took = winner >= 0
        lab = self.label[ev["y"][took], ev["x"][took]].astype(np.int64)
        w = winner[took].astype(np.int64)
        on = ok[lab]
        if not on.any():
            return out
        key, votes = np.unique(w[on] * len(ok) + lab[on], return_counts=True)
        best = np.zeros(n)
        for k, v in zip(key.tolist(), votes.tolist()):
            i, c = divmod(k, len(ok))
            if v > best[i]:
                best[i], out[i] = v, c
        cx, cy, r = self.circle[out].T
        far = np.hypot(x - cx, y - cy) > OUTLINE_INSIDE * r + 1.0
        out[far] = 0
        return out


def _direction_bins(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Which of the OUTLINE_BINS directions (0 .. OUTLINE_BINS - 1) each offset points in."""
    return (np.floor((np.arctan2(dy, dx) + math.pi) * (OUTLINE_BINS / (2.0 * math.pi)))
            .astype(np.int64) % OUTLINE_BINS)


def _directions(dx: np.ndarray, dy: np.ndarray, group: np.ndarray, groups: int) -> np.ndarray:
    """(groups,) how many of the OUTLINE_BINS directions the offsets (dx, dy) of each
    group (``group``: its index per offset) point in."""
    b = _direction_bins(dx, dy)
    seen = np.zeros(groups * OUTLINE_BINS, bool)
    seen[group * OUTLINE_BINS + b] = True
    return seen.reshape(groups, OUTLINE_BINS).sum(axis=1)


def _radial_spread(dx: np.ndarray, dy: np.ndarray):
    """(median radius, RMS distance of the points from their direction's median radius)
    of offsets (dx, dy) from a centroid, over OUTLINE_BINS directions: small for the
    outline of a shape seen from inside (a square 0.07 of the radius, a triangle 0.12, a
    15 x 7 ellipse 0.11), large for a shape that fires all over (a filled disc 0.34) or two
    outlines that touch (a figure eight 0.28)."""
    r = np.hypot(dx, dy)
    b = _direction_bins(dx, dy)
    order = np.lexsort((r, b))
    rs, bs = r[order], b[order]
    start = np.searchsorted(bs, np.arange(OUTLINE_BINS))
    count = np.bincount(bs, minlength=OUTLINE_BINS)
    lo = start + (count - 1) // 2                       # the median of each direction
    hi = start + count // 2
    seen = count > 0
    med = np.zeros(OUTLINE_BINS)
    med[seen] = 0.5 * (rs[lo[seen]] + rs[hi[seen]])
    res = rs - med[bs]
    return float(np.median(r)), math.sqrt(float(np.mean(res * res)))


def _circle(x: np.ndarray, y: np.ndarray):
    """The circle through points centred on their mean (x, y sum to 0), fitted by algebraic
    least squares (x^2 + y^2 + a x + b y + e = 0, Kasa's fit): (cx, cy, r, rms of the
    points' distances from it), or None if no circle fits (collinear points)."""
    z = x * x + y * y
    sxx, sxy, syy = float(x @ x), float(x @ y), float(y @ y)
    det = sxx * syy - sxy * sxy
    if det <= 1e-9 * max(sxx * syy, 1.0):
        return None
    # normal equations of (a, b); e = -mean(z) since x and y sum to 0
    sxz, syz = float(x @ z), float(y @ z)
    a = -(syy * sxz - sxy * syz) / det
    b = -(sxx * syz - sxy * sxz) / det
    e = -float(z.mean())
    cx, cy = -0.5 * a, -0.5 * b
    r2 = cx * cx + cy * cy - e
    if r2 <= 0.0:
        return None
    r = math.sqrt(r2)
    res = np.hypot(x - cx, y - cy) - r
    return cx, cy, r, math.sqrt(float(np.mean(res * res)))
