"""Outlines: the pieces of one part that fires only at its edges (off by default).

A uniform part (a dark disc, a drawn shape) fires where its edges cross pixels, never
inside: the free trackers follow pieces of its outline (arcs, the tips of its leading and
trailing crescents), and the "two edges" rule of the merges (Pool.gaps) joins them only
once the part has moved by its own size since the window's start.  Its outline shows it
sooner: over the trackers' memory (``life_tau_us``) the part draws a curve of recent
pixels that curls around its centre (a ring, or a crescent three quarters round), apart
from its neighbours' curves.  Trackers whose events lie on one such curve are merged as
pieces of one part.  The curve must be a connected component (8 neighbours, lone pixels
dropped as noise) of sigma at most :data:`OUTLINE_SIZE` of the widest part
(``sigma_max_px``) that surrounds its centroid (pixels in at least ``outline_cover`` of
:data:`OUTLINE_BINS` directions, counting those beyond half its RMS radius: a straight
edge covers two or three), so a long contour (a head's outline), a textured object or a
swept background (one large component) merges nothing.

Measured (docs/learning.md "Uniform parts"): on the second generator's grid of dark discs
it learns one tracker per disc (seeds 0-2: 9 of 9, at most 2.1 px from a centre; without
it 13-22 trackers on the crescents).  But where neighbouring parts' curves touch it merges
them: the project simulator's face, whose Gaussian blobs fire in touching rings, learns 17
to 22 trackers for 26 parts instead of 26.  So it is off by default (``outline_cover`` 0):
``--learn-param outline_cover=0.75`` for scenes of separate uniform shapes.
"""
from __future__ import annotations

import math

import numpy as np

from . import batch as _learn

OUTLINE_BINS = 16             # directions about an outline's centroid
OUTLINE_MIN_PIXELS = 8        # a component of fewer pixels is no outline
OUTLINE_SIZE = 0.5            # an outline's sigma is at most this share of sigma_max_px


class Outlines:
    """The closed outlines of a ``height`` x ``width`` sensor's recent pixels."""

    def __init__(self, width: int, height: int):
        self.label = np.zeros((height, width), np.int32)
        self.stack = np.empty(width * height, np.int32)

    def closed(self, last: np.ndarray, t_from: int, sigma_max_px: float,
               cover: float) -> np.ndarray:
        """Label the components of the pixels that fired since ``t_from`` (``last``: each
        pixel's latest event time) into ``self.label``; returns (n + 1,) bool: component
        k is a closed outline of a part (index 0, no component, is false)."""
        n = _learn.recent_components(last, t_from, self.label, self.stack)
        ok = np.zeros(n + 1, bool)
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
        r2 = dx * dx + dy * dy
        far = r2 >= 0.25 * (vx + vy)[lab]
        b = (np.floor((np.arctan2(dy, dx) + math.pi) * (OUTLINE_BINS / (2.0 * math.pi)))
             .astype(np.int64) % OUTLINE_BINS)
        seen = np.zeros((n + 1) * OUTLINE_BINS, bool)
        seen[lab[far] * OUTLINE_BINS + b[far]] = True
        directions = seen.reshape(n + 1, OUTLINE_BINS).sum(axis=1)
        ok = ((cnt >= OUTLINE_MIN_PIXELS) & (np.maximum(vx, vy) <= (OUTLINE_SIZE * sigma_max_px) ** 2)
              & (directions >= cover * OUTLINE_BINS))
        ok[0] = False
        return ok

    def of_trackers(self, ok: np.ndarray, ev: np.ndarray, winner: np.ndarray,
                    n: int) -> np.ndarray:
        """(n,) the closed outline most of each tracker's events in ``ev`` (taken as
        ``winner`` says) lie on, 0 if none."""
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
        return out
