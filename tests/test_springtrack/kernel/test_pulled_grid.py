"""The pulled grid (the paper's Figs. 12-14) on both scene generators, with the defaults
(the similarity frame) plus the paper's per-experiment values (Cartesian springs,
stiffness 0.001, the grid3x3 preset's s = 4.5): while the disc is pulled out fully, its
tracker stays near where the disc belongs instead of following it, and the other eight
stay on their discs.

The bounds are the measured figures with a margin (docs/simulators.md, "After the frame's
refits"): a tracker that followed its disc would be 60 px (sensor) or 67 px (screen) off.
The pulled part is not within 2 px of its truth on these scenes, and cannot be in a
similarity frame: the grid turns about x and y, and the best similarity fitted to the
other eight true positions itself puts it 6.3 px (screen) / 12.8 px (sensor) away.
"""
import numpy as np
import pytest

from springtrack import Tracker
from springtrack.metrics import score_track, truth_from_array
from springtrack.sim.generators import generator

# (generator, seed) -> (pulled part's mean, max px; the largest of the others' mean px)
CASES = {
    # the sensor simulator pulls its corner r0c2 60 px diagonally out: 7.3 / 18.9, 0.50
    ("sensor", 0): (8.5, 25.0, 0.7),
    # the screen generator pulls r1c2 1.5 spacings along the grid's X axis; on this seed
    # the pulled disc used to drag the frame and its tracker with it (21.9 / 67.1 px,
    # 1.02): 3.4 / 6.7, 0.90
    ("screen", 2): (5.0, 10.0, 1.2),
}


@pytest.mark.slow
@pytest.mark.parametrize("gname,seed", list(CASES))
def test_a_pulled_part_is_let_go_and_the_others_stay_put(gname, seed):
    gen = generator(gname)
    scene = gen.make_scene("grid_pull", seed=seed)
    ev, tr = zip(*gen.simulate(scene, None, seed))
    ev, truth = np.concatenate(ev), truth_from_array(np.concatenate(tr))
    model = scene.initial_model(stiffness=0.001, springs=("cartesian",))
    track = Tracker(model).run(ev, sample_us=1000)
    es = score_track(truth, track)
    full = np.array([scene.pull_amount(t * 1e-6) for t in es.t_us]) > 0.99
    assert full.sum() > 1500                                  # 2 s held per cycle
    k = es.parts.index(scene.PULLED)
    err = es.err_px[full]
    pulled_mean, pulled_max, others_mean = CASES[gname, seed]
    assert np.nanmean(err[:, k]) < pulled_mean and np.nanmax(err[:, k]) < pulled_max
    others = np.delete(err, k, axis=1)
    assert np.nanmax(np.nanmean(others, axis=0)) < others_mean
