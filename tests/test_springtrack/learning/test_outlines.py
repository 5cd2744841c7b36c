"""springtrack.learning.outlines: which curves of recent pixels count as one part's outline,
and which trackers lie on one."""
from __future__ import annotations

import math

import numpy as np

from springtrack.events import EVENT_DTYPE
from springtrack.learning.outlines import Outlines

W, H = 120, 100
NEVER = np.iinfo(np.int64).min


def fired(points, t=1000):
    """A time map in which ``points`` (x, y) fired at ``t``."""
    last = np.full((H, W), NEVER, np.int64)
    for x, y in points:
        last[int(round(y)), int(round(x))] = t
    return last


def ring(cx, cy, r, start_deg=0.0, span_deg=360.0):
    n = int(8 * r)
    return [(cx + r * math.cos(math.radians(start_deg + span_deg * k / n)),
             cy + r * math.sin(math.radians(start_deg + span_deg * k / n))) for k in range(n + 1)]


def disc(cx, cy, r):
    return [(x, y) for x in range(int(cx - r), int(cx + r) + 1)
            for y in range(int(cy - r), int(cy + r) + 1) if (x - cx) ** 2 + (y - cy) ** 2 <= r * r]


def outlines_of(points, cover=0.75, sigma_max_px=16.0):
    o = Outlines(W, H)
    ok = o.find(fired(points), 0, sigma_max_px, cover)
    return o, ok


def test_a_ring_and_a_crescent_are_outlines_a_line_is_not():
    o, ok = outlines_of(ring(30, 30, 8) + ring(80, 30, 8, 0, 280)
                        + [(20 + k, 80) for k in range(20)])
    assert o.label.max() == 3
    assert ok[o.label[30, 38]]                   # the ring
    assert ok[o.label[30, 88]]                   # three quarters of a ring
    assert not ok[o.label[80, 25]]               # a straight edge
    cx, cy, r = o.circle[o.label[30, 88]]
    assert abs(cx - 80) < 0.5 and abs(cy - 30) < 0.5 and abs(r - 8) < 0.5


def test_a_filled_blob_and_two_touching_rings_are_not_outlines():
    o, ok = outlines_of(disc(30, 30, 6) + ring(70, 50, 6) + ring(82, 50, 6))
    assert o.label.max() == 2
    assert not ok[o.label[30, 30]]               # fires all over: far from a thin circle
    assert not ok[o.label[50, 76]]               # a figure eight


def test_a_curve_wider_than_half_the_widest_part_is_not_one():
    o, ok = outlines_of(ring(60, 50, 14))         # sigma ~ 14 / sqrt(2) = 9.9 > 8
    assert not ok[o.label[50, 74]]
    o, ok = outlines_of(ring(60, 50, 14), sigma_max_px=24.0)
    assert ok[o.label[50, 74]]


def test_lone_pixels_are_noise_and_old_pixels_are_not_recent():
    last = fired([(5, 5), (50, 50)], t=1000)
    last[10, 10] = 10                             # fired long before
    last[10, 11] = 10
    o = Outlines(W, H)
    ok = o.find(last, 500, 16.0, 0.75)
    assert o.label.max() == 0 and len(ok) == 1 and not ok.any()


def test_trackers_take_the_outline_their_events_lie_on_if_they_lie_about_it():
    o, ok = outlines_of(ring(30, 30, 8) + ring(80, 30, 8))
    ev = np.zeros(5, EVENT_DTYPE)
    ev["x"], ev["y"] = [38, 22, 88, 5, 72], [30, 30, 30, 5, 30]
    winner = np.array([0, 0, 1, 2, 3], np.int32)
    x = np.array([32.0, 84.0, 5.0, 60.0])          # tracker 3 sits 20 px from its ring's centre
    y = np.array([30.0, 30.0, 5.0, 30.0])
    on = o.of_trackers(ok, ev, winner, x, y)
    assert on[0] == o.label[30, 38] and on[1] == o.label[30, 88]
    assert on[2] == 0 and on[3] == 0


def polygon(cx, cy, r, sides):
    """The outline of a regular polygon of circumradius r, one point per pixel or so."""
    pts = []
    corners = [(cx + r * math.cos(2 * math.pi * k / sides), cy + r * math.sin(2 * math.pi * k / sides))
               for k in range(sides)]
    for k in range(sides):
        (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % sides]
        n = int(2 * math.hypot(x1 - x0, y1 - y0)) + 1
        pts += [(x0 + (x1 - x0) * j / n, y0 + (y1 - y0) * j / n) for j in range(n)]
    return pts


def test_a_square_is_close_enough_to_a_circle_a_triangle_is_not():
    """The circle test's residuals: a square's outline 0.11 of the radius, a triangle's
    0.22 (OUTLINE_THIN 0.15)."""
    o, ok = outlines_of(polygon(30, 40, 10, 4) + polygon(85, 40, 10, 3))
    assert o.label.max() == 2
    assert ok[o.label[40, 40]]                   # the square's right corner
    assert not ok[o.label[40, 95]]               # the triangle's right corner


def test_any_shape_takes_closed_outlines_as_wide_as_a_part():
    """At the discovery's end (Outlines.find(any_shape=True)): a square's, a triangle's and a
    wide ring's outlines are outlines, a figure eight and a filled disc are not."""
    pts = polygon(30, 30, 12, 4) + polygon(85, 30, 12, 3) + ring(30, 75, 14)
    eight = ring(80, 75, 8) + ring(96, 75, 8)
    o = Outlines(W, H)
    ok = o.find(fired(pts + eight), 0, 16.0, 0.75, any_shape=True)
    assert ok[o.label[30, 42]] and ok[o.label[30, 97]] and ok[o.label[75, 44]]
    assert not ok[o.label[75, 72]]                     # the eight
    s = Outlines(W, H)
    strict = s.find(fired(pts), 0, 16.0, 0.75)        # the discovery's: thin circles, half as wide
    assert not strict[s.label[30, 97]] and not strict[s.label[75, 44]]
    o = Outlines(W, H)
    ok = o.find(fired(disc(60, 50, 10)), 0, 16.0, 0.75, any_shape=True)
    assert not ok.any()


def test_trackers_on_one_square_outline_merge_at_the_end():
    from springtrack.learning.discovery import join_outlines
    from springtrack.learning.pool import Pool
    from springtrack.learning.settings import LearnParams
    pool = Pool(LearnParams(), W, H)
    sq = np.array(polygon(50, 50, 13, 4))
    for half in (sq[sq[:, 0] < 50], sq[sq[:, 0] >= 50]):
        assert pool.add(half.mean(axis=0), np.cov(half.T) + 0.25 * np.eye(2), 1000)
    pool.last[:] = fired([tuple(p) for p in sq], t=1000)
    rec = {"t": np.array([1000]), "x": pool.x[None, :].copy(), "y": pool.y[None, :].copy(),
           "act": np.ones((1, 2)), "cnt": np.ones((1, 2)), "valid": np.ones((1, 2), bool)}
    stats = {"end_outline_merged": 0}
    rec = join_outlines(pool, rec, 1000, stats)
    assert pool.n == 1 and stats["end_outline_merged"] == 1 and rec["x"].shape == (1, 1)
    assert math.hypot(pool.x[0] - 50, pool.y[0] - 50) < 1.5


def test_any_shape_takes_a_thick_ring_round_a_hole():
    """A disc that moved part of its size fires a thick ring round its silent inside: too
    thick for the radial test, an outline by its hole (no pixel within 0.35 of its median
    radius from its centroid); a filled disc has none."""
    thick = [(x, y) for x in range(W) for y in range(H)
             if 6.0 <= math.hypot(x - 50, y - 50) <= 12.0]
    o = Outlines(W, H)
    ok = o.find(fired(thick), 0, 16.0, 0.75, any_shape=True)
    assert ok[o.label[50, 61]]
    assert not Outlines(W, H).find(fired(thick), 0, 16.0, 0.75).any()
