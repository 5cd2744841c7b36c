"""The face with hand occlusions (the paper's Figs. 20-21) on the second scene generator,
with the defaults plus the paper's value for the face (s = 2.5): the hand's first pass
(3-5 s, across the lower half of the face) does not drag the structure.

The criteria read the Cartesian energy by default (each connection's offset from its rest
offset in the fitted frame): the hand drags the chin's outline trackers along the
outline, which keeps their lengths (Euclidean energy) but not their offsets.  With
``energy_kind = "euclidean"`` the whole structure followed the hand and came back two
seconds after it had gone (measured on this cut: internal parts 7.95 px mean over 3-7 s,
one at 13.5 px; the defaults 1.31 / 1.89 px; docs/parameters.md, "The energy that feeds
the criteria").
"""
import numpy as np
import pytest

from springtrack import Tracker
from springtrack.metrics import score_track, truth_from_array
from springtrack.sim.generators import generator


@pytest.mark.slow
def test_the_hand_does_not_drag_the_face():
    gen = generator("screen")
    scene = gen.make_scene("face_occlusion", seed=0)
    ev, tr = zip(*gen.simulate(scene, 7.0, 0))
    ev, truth = np.concatenate(ev), truth_from_array(np.concatenate(tr))
    es = score_track(truth, Tracker(scene.initial_model(), params=dict(energy_scale=2.5))
                     .run(ev, sample_us=1000))
    during = es.err_px[es.t_us >= 3_000_000]                  # the pass and after it
    assert len(during) > 3500
    assert np.nanmean(during) < 2.0, np.nanmean(during)
    assert np.nanmax(np.nanmean(during, axis=0)) < 3.0, np.nanmean(during, axis=0)
