"""Learning a rigid scene of distinct parts filmed by a hand-held camera
(springtrack.sim.screen's ``shapes_handheld``: eight dark shapes on a bright wall, the
image shifting, rolling and zooming), from 30 ms and the defaults, as `track
--learn-first-ms 30` does; scored by the scene's own image motion
(springtrack.metrics.rigid_motion_error), beside standing still.  docs/learning.md
("A rigid scene, a hand-held camera")."""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from springtrack import Tracker
from springtrack.learning.learner import learn_model
from springtrack.learning.settings import LearnParams
from springtrack.metrics import rigid_motion_error
from springtrack.sim import screen
from springtrack.sim.screen.pixels import ScreenConfig

SECONDS = 0.5
LEARN_US = 30_000
# the camera sees the wall move continuously: a fast refresh, not a 100 Hz screen's steps
CONFIG = ScreenConfig(refresh_hz=1000.0)


@functools.lru_cache(maxsize=None)
def window(speed: float):
    """(scene, its events)."""
    sc = screen.make_scene("shapes_handheld", seed=0, speed=speed)
    return sc, screen.simulate_all(sc, SECONDS, seed=0, config=CONFIG)[0]


def learned(speed: float, **learn_params):
    sc, ev = window(speed)
    cut = int(np.searchsorted(ev["t"], LEARN_US))
    params = LearnParams(**learn_params) if learn_params else None
    return learn_model(ev[:cut], width=CONFIG.width, height=CONFIG.height, params=params)


@functools.lru_cache(maxsize=None)
def learned_and_tracked(speed: float):
    """(scene, learned model, its track of the rest of the stream)."""
    sc, ev = window(speed)
    model = learned(speed).model
    cut = int(np.searchsorted(ev["t"], LEARN_US))
    return sc, model, Tracker(model).run(ev[cut:], 1000)


def centre_offsets(sc, model):
    """(8,) each shape's distance (px) to its nearest tracker when the learning ends."""
    xy = np.array([(t.x, t.y) for t in model.trackers])
    c = sc.truth(LEARN_US * 1e-6)
    return np.hypot(xy[:, None, 0] - c[None, :, 0], xy[:, None, 1] - c[None, :, 1]).min(axis=0)


def layout_length(sc):
    """The diagonal of the shapes' centres' bounding box at t_s (px)."""
    def length(t_s):
        xy = sc.truth(t_s)
        return math.hypot(*(xy.max(axis=0) - xy.min(axis=0)))
    return length


@pytest.mark.slow
@pytest.mark.parametrize("speed,limit", [(60.0, 1.2), (150.0, 1.2)])
def test_a_model_learned_from_30_ms_follows_the_scene(speed, limit):
    """The learned trackers move with the wall: mean error under ``limit`` % of the
    layout's diagonal and under a third of standing still's (measured on 0.5 s: 60 px/s
    0.65 % against 3.90 %, 150 px/s 0.75 % against 9.85 %)."""
    sc, model, track = learned_and_tracked(speed)
    assert 8 <= len(model.trackers) <= 40
    err = rigid_motion_error(track, sc.transform, layout_length(sc))
    assert err.mean_pct < limit, (err.mean_pct, err.still_mean_pct)
    assert err.mean_pct < err.still_mean_pct / 3, (err.mean_pct, err.still_mean_pct)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="elongated shapes keep learned trackers on their "
                   "edges, a median 4.2 px from the shapes' centres: a part-centred truth "
                   "scores the model 2-3 % where it follows the scene within 1-2 % "
                   "(docs/learning.md)")
def test_each_shape_has_a_tracker_near_its_centre():
    """Each shape's nearest learned tracker within 3 px of its centre (median over the
    shapes) when the learning ends."""
    sc, model, _ = learned_and_tracked(150.0)
    d = centre_offsets(sc, model)
    assert float(np.median(d)) < 3.0, np.round(d, 1)


@pytest.mark.slow
def test_the_merges_at_the_end_put_trackers_on_the_shapes():
    """At the discovery's end, pieces on one closed outline of any shape
    (discovery.join_outlines) and the two edges of one shape (learning.edges) merged bring
    trackers nearer the shapes' centres (measured at 150 px/s: 3 outline and 2 edge
    merges, 20 trackers, a shape's nearest a median 4.2 px from its centre; without the
    edge merge 22 and 4.8 px; without either, nor the discovery's outline merge, 30 and
    6.8 px)."""
    sc, _ = window(150.0)
    on, off = learned(150.0), learned(150.0, edge_polarity=0.0)
    assert on.lifecycle["end_outline_merged"] >= 1 and on.lifecycle["edge_merged"] >= 1
    assert off.lifecycle["edge_merged"] == 0
    assert len(on.model.trackers) < len(off.model.trackers)
    assert np.median(centre_offsets(sc, on.model)) < np.median(centre_offsets(sc, off.model)) - 0.5
