"""Learning on the second scene generator (springtrack.sim.screen: a screen refreshed at
100 Hz, per-pixel thresholds, refractory period, latency; docs/simulators.md), whose parts
fire through their leading and trailing edges rather than as blobs."""
from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from springtrack import Tracker
from springtrack.learning.learner import learn_model
from springtrack.learning.settings import LearnParams
from springtrack.metrics import score_track, truth_from_array
from springtrack.model import ShapeModel
from springtrack.sim import screen

FACE_LEARN_US = 800_000
GRID_LEARN_US = 1_000_000


@functools.lru_cache(maxsize=None)
def scene(name: str):
    ev, tr = screen.simulate_all(name, seed=0)
    return ev, truth_from_array(tr)


@functools.lru_cache(maxsize=None)
def learned(name: str, learn_us: int, **learn_params):
    ev, _ = scene(name)
    return learn_model(ev[ev["t"] < learn_us], width=304, height=240, **learn_params).model


def distances(model, truth, t_us):
    """(T, P) distances of each tracker to each true part at t_us."""
    k = min(int(np.searchsorted(truth.t_us, t_us)), len(truth.t_us) - 1)
    gt = truth.xy[k]
    xy = np.array([(t.x, t.y) for t in model.trackers])
    return np.hypot(xy[:, None, 0] - gt[None, :, 0], xy[:, None, 1] - gt[None, :, 1])


def renamed(model, truth, t_us) -> ShapeModel:
    """Each part's id given to its nearest tracker (nearest pairs first)."""
    d = distances(model, truth, t_us)
    names, used = {}, set()
    for i in np.argsort(d.min(axis=1)):
        part = truth.ids[int(d[i].argmin())]
        if part not in used:
            names[model.trackers[i].id] = part
            used.add(part)
    trackers = [dataclasses.replace(t, id=names.get(t.id, t.id)) for t in model.trackers]
    conns = [dataclasses.replace(c, a=names.get(c.a, c.a), b=names.get(c.b, c.b))
             for c in model.connections]
    return ShapeModel(model.name, model.width, model.height, trackers, conns, model.params)


@pytest.mark.slow
def test_face_parts_are_learned_near_the_parts():
    """0.8 s of the screen face: every tracker within 10 px of a part (a feature is about
    10 px across), and at least 22 of the 26 parts with a tracker nearest to them
    (measured: 32 trackers, at most 8.1 px, 23 parts)."""
    _, truth = scene("face_occlusion")
    d = distances(learned("face_occlusion", FACE_LEARN_US), truth, FACE_LEARN_US)
    assert d.min(axis=1).max() < 10.0
    assert len(set(d.argmin(axis=1).tolist())) >= 22


@pytest.mark.slow
def test_face_keeps_the_occlusion_criteria_on():
    """The screen face's trackers slide along the parts' edges as the motion turns (by
    1.4 of their size, within their gates): one shape, so eqs. (21)-(22) stay on
    (energy_scale at most energy_scale_max), which the hand passes need."""
    model = learned("face_occlusion", FACE_LEARN_US)
    assert model.params["energy_scale"] <= LearnParams().energy_scale_max


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="a regression: since the frame's weighted refits the "
                   "hand-made model is better (3.12 -> 2.36 %) and the learned one worse "
                   "(4.83 -> 6.93 %): a hand pass at 4.4-6.3 s drags five of its seven "
                   "scored parts 30-40 px; the result swings 4.8-16.8 % with energy_scale "
                   "and alpha_position (docs/learning.md)")
def test_face_learned_model_tracks_within_2x_the_hand_model():
    """The rest of the scene (three hand passes) tracked by the learned model: within 2x
    the hand-made model's error."""
    ev, truth = scene("face_occlusion")
    model = renamed(learned("face_occlusion", FACE_LEARN_US), truth, FACE_LEARN_US)
    ours = score_track(truth, Tracker(model).run(ev[ev["t"] >= FACE_LEARN_US], 1000)).mean_pct
    hand = score_track(truth, Tracker(screen.make_scene("face_occlusion").initial_model())
                       .run(ev, 1000))
    hand_pct = float(np.nanmean(hand.pct[hand.t_us >= FACE_LEARN_US]))
    assert ours < 2.0 * hand_pct, (ours, hand_pct)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="a dark disc on the screen fires as two crescents (its "
                   "leading edge OFF, its trailing edge ON); the pool learns the crescents' "
                   "tips, 2 px wide, not the disc: 17 trackers for 9 discs, 8 discs covered; "
                   "the outline merge that joins them (next test) is off by default, as it "
                   "merges touching parts on the project's face (docs/learning.md)")
def test_grid_learns_one_tracker_per_disc():
    _, truth = scene("grid_pull")
    model = learned("grid_pull", GRID_LEARN_US)
    d = distances(model, truth, GRID_LEARN_US)
    assert len(model.trackers) == 9
    assert len(set(d.argmin(axis=1).tolist())) == 9 and d.min(axis=1).max() < 5.0


@pytest.mark.slow
def test_grid_learns_one_tracker_per_disc_from_closed_outlines():
    """With the closed-outline merge on (outline_cover 0.75, off by default): the pieces of
    each disc's outline become one tracker on the disc (measured on seeds 0-2: 9 trackers,
    9 discs, at most 2.1 px from a centre)."""
    _, truth = scene("grid_pull")
    model = learned("grid_pull", GRID_LEARN_US, params=LearnParams(outline_cover=0.75))
    d = distances(model, truth, GRID_LEARN_US)
    assert len(model.trackers) == 9
    assert len(set(d.argmin(axis=1).tolist())) == 9 and d.min(axis=1).max() < 3.0


def test_outline_cover_is_a_share():
    with pytest.raises(ValueError, match="outline_cover"):
        LearnParams(outline_cover=1.5)
