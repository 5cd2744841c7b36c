"""springtrack.learning.edges: which two trackers are the leading and trailing edges of one
uniform part (arcs bending toward each other, of opposite polarities), and the discovery's
end merging them (discovery.join_edges)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from springtrack.learning.discovery import join_edges
from springtrack.learning.edges import bends, facing_pairs
from springtrack.learning.pool import Pool
from springtrack.learning.settings import LearnParams

W, H = 160, 100
T = 100_000


def arc(cx, cy, r, mid_deg, span_deg=140.0):
    """Pixels (x, y) of an arc of the circle (cx, cy, r) centred on direction mid_deg."""
    n = int(2 * r * math.radians(span_deg)) + 1
    a = np.radians(mid_deg - span_deg / 2 + span_deg * np.arange(n + 1) / n)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def pool_of(arcs, lp=None):
    """A pool with one tracker per (pixels, ON share) in ``arcs``: its Gaussian the
    pixels' moments, 100 recent events, the pixels fired at T."""
    pool = Pool(lp or LearnParams(), W, H)
    for pts, on in arcs:
        mu = pts.mean(axis=0)
        cov = np.cov(pts.T) + 0.25 * np.eye(2)
        assert pool.add(mu, cov, T)
        pool.book["recent"][pool.n - 1] = 100.0
        pool.book["on"][pool.n - 1] = 100.0 * on
        for x, y in np.round(pts).astype(int):
            pool.last[y, x] = T
    return pool


def test_an_arc_bends_toward_its_centre():
    pool = pool_of([(arc(50, 50, 12, 0.0), 0.0)])   # the right half of a circle about (50, 50)
    bends(pool, T - 1000)
    r = pool.book["arc_r"][0]
    cx, cy = pool.book["arc_x"][0], pool.book["arc_y"][0]
    assert 8.0 < r < 18.0, r                      # a parabola's curvature at the arc's vertex
    assert cx < pool.x[0] and abs(cy - 50) < 2.0   # its centre of curvature on the inside


def test_a_straight_edge_does_not_bend():
    pts = np.column_stack([np.full(25, 40.0), np.arange(38.0, 63.0)])
    pool = pool_of([(pts, 0.0)])
    bends(pool, T - 1000)
    assert pool.book["arc_r"][0] == 0.0


def test_the_two_edges_of_one_disc_pair_and_the_gap_between_two_discs_does_not():
    # a dark disc moving right: its leading (right) edge OFF, its trailing (left) edge ON;
    # a second disc to its right, the same: the first's OFF edge faces the second's ON edge
    pool = pool_of([(arc(50, 50, 12, 180.0), 1.0), (arc(50, 50, 12, 0.0), 0.0),
                    (arc(90, 50, 12, 180.0), 1.0), (arc(90, 50, 12, 0.0), 0.0)])
    bends(pool, T - 1000)
    i, j, d = facing_pairs(pool)
    pairs = {tuple(sorted(p)) for p in zip(i.tolist(), j.tolist())}
    assert (0, 1) in pairs and (2, 3) in pairs
    assert (1, 2) not in pairs                     # facing edges of two parts bend apart


def test_edges_of_one_polarity_do_not_pair():
    pool = pool_of([(arc(50, 50, 12, 180.0), 0.0), (arc(50, 50, 12, 0.0), 0.0)])
    bends(pool, T - 1000)
    assert len(facing_pairs(pool)[0]) == 0
    mixed = pool_of([(arc(50, 50, 12, 180.0), 0.5), (arc(50, 50, 12, 0.0), 0.0)])
    bends(mixed, T - 1000)
    assert len(facing_pairs(mixed)[0]) == 0       # a textured piece fires both


def test_join_edges_merges_the_pair_into_one_tracker_at_the_centre_and_can_be_off():
    arcs = [(arc(50, 50, 12, 180.0), 1.0), (arc(50, 50, 12, 0.0), 0.0)]
    pool = pool_of(arcs)
    rec = {"t": np.array([T]), "x": pool.x[None, :].copy(), "y": pool.y[None, :].copy(),
           "act": np.ones((1, 2)), "cnt": np.ones((1, 2)), "valid": np.ones((1, 2), bool)}
    stats = {"edge_merged": 0}
    rec = join_edges(pool, rec, T, stats)
    assert pool.n == 1 and stats["edge_merged"] == 1 and rec["x"].shape == (1, 1)
    assert math.hypot(pool.x[0] - 50, pool.y[0] - 50) < 1.0
    off = pool_of(arcs, LearnParams(edge_polarity=0.0))
    stats = {"edge_merged": 0}
    join_edges(off, dict(rec, x=np.zeros((1, 2)), y=np.zeros((1, 2)), act=np.ones((1, 2)),
                         cnt=np.ones((1, 2)), valid=np.ones((1, 2), bool)), T, stats)
    assert off.n == 2 and stats["edge_merged"] == 0


def test_edge_polarity_is_a_share_above_one_half():
    with pytest.raises(ValueError, match="edge_polarity"):
        LearnParams(edge_polarity=0.4)
    with pytest.raises(ValueError, match="edge_polarity"):
        LearnParams(edge_polarity=1.5)
