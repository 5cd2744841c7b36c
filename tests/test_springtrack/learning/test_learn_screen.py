"""Learning on the second scene generator (springtrack.sim.screen: a screen refreshed at
100 Hz, per-pixel thresholds, refractory period, latency; docs/simulators.md), whose parts
fire through their leading and trailing edges rather than as blobs."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from springtrack import Tracker
from springtrack.learning.learner import learn_model
from springtrack.learning.settings import LearnParams
from springtrack.metrics import named_after_parts, score_track, truth_from_array
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
    return named_after_parts(model, truth, t_us)[1]


def learned_and_hand_errors(name: str, learn_us: int):
    """The rest of the scene tracked by the learned model (its trackers named after their
    parts) and the hand-made model's error over the same span, % of the object's length."""
    ev, truth = scene(name)
    model, _ = named_after_parts(learned(name, learn_us), truth, learn_us)
    ours = score_track(truth, Tracker(model).run(ev[ev["t"] >= learn_us], 1000)).mean_pct
    hand = score_track(truth, Tracker(screen.make_scene(name).initial_model()).run(ev, 1000))
    return ours, float(np.nanmean(hand.pct[hand.t_us >= learn_us]))


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
                   "hand-made model is better (3.12 -> 2.36 %, 0.98 % with the Cartesian "
                   "energy) and the learned one worse (4.83 -> 6.93 %, 6.30 % with the "
                   "edge merge): a hand pass at 4.4-6.3 s "
                   "drags five of its seven scored parts 30-40 px; the result swings "
                   "4.8-16.8 % with energy_scale and alpha_position (docs/learning.md)")
def test_face_learned_model_tracks_within_2x_the_hand_model():
    """The rest of the scene (three hand passes) tracked by the learned model: within 2x
    the hand-made model's error."""
    ours, hand = learned_and_hand_errors("face_occlusion", FACE_LEARN_US)
    assert ours < 2.0 * hand, (ours, hand)


@pytest.mark.slow
def test_grid_learns_one_tracker_per_disc():
    """A dark disc on the screen fires as two crescents (its leading edge OFF, its trailing
    edge ON) that barely move apart; the outline merge (learning.outlines) makes the pieces
    of each disc one tracker on it (measured on seeds 0-2: 9 trackers, 9 discs, at most
    2.1 px from a centre).  Uniform parts: the model tracks both edges (polarity_gain 1,
    eq. M6b) unless the user says otherwise."""
    ev, truth = scene("grid_pull")
    model = learned("grid_pull", GRID_LEARN_US)
    d = distances(model, truth, GRID_LEARN_US)
    assert len(model.trackers) == 9
    assert len(set(d.argmin(axis=1).tolist())) == 9 and d.min(axis=1).max() < 3.0
    res = learn_model(ev[ev["t"] < GRID_LEARN_US], width=304, height=240)
    assert res.lifecycle["outline_merged"] > 0           # the outline rule did it
    assert model.params["polarity_gain"] == 1.0
    given = learn_model(ev[ev["t"] < GRID_LEARN_US], width=304, height=240,
                        track_params={"polarity_gain": 0.0})
    assert given.model.params["polarity_gain"] == 0.0


@pytest.mark.slow
def test_grid_learned_model_tracks_within_1_5x_the_hand_model():
    """The rest of the scene (the turns and the pull) tracked by the learned model, its
    trackers named after their discs: within 1.5x the hand-made model's error, as on the
    project's simulator (measured on seeds 0-2: 1.29 / 1.37 / 1.27 % against 1.58 / 1.59 /
    1.60 %; tracked with one mean for both polarities, polarity_gain 0, 1.45 / 1.50 /
    1.38 %; with eq. (4)'s default alpha_2 instead of the learned one 3.2-3.5 %)."""
    ours, hand = learned_and_hand_errors("grid_pull", GRID_LEARN_US)
    assert ours < 1.5 * hand, (ours, hand)


@pytest.mark.slow
def test_grid_without_the_outline_merge_learns_the_crescents():
    """The same window with the merge off (outline_cover 0): the pool follows the
    crescents' tips (measured: 17 trackers for 9 discs, 8 covered), so the test above
    measures the merge, not an easier scene."""
    model = learned("grid_pull", GRID_LEARN_US, params=LearnParams(outline_cover=0.0))
    assert len(model.trackers) > 12


def test_outline_cover_is_a_share():
    with pytest.raises(ValueError, match="outline_cover"):
        LearnParams(outline_cover=1.5)
