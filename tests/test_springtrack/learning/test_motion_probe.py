"""springtrack.learning.motion: when ``track --model`` switches the motion model on by
itself.  The real dot's one-tracker model is switched on and followed within 2 px
(tests/test_springtrack/kernel/test_motion.py); here the estimator, and the paper's scenes
of both generators, which stay on the paper's step."""
import numpy as np
import pytest

from springtrack.model import load_model
from springtrack.learning.motion import (MOTION_SIGMAS_PER_MS, fast_enough, probe,
                                         probe_window_us, robust_speeds, sets_motion,
                                         sizes_per_ms, tracked_sigmas)
from springtrack.sim.generators import generator


def test_robust_speeds_ignore_one_jump_and_gaps():
    """A tracker moving 3 px per 2-ms bin (1,500 px/s) with one 40-px jump (an
    acquisition's catch-up) reads 1,500 px/s; one that never moves reads 0; one with
    fewer than two bins of samples reads NaN."""
    t = np.arange(0, 40_000, 200)
    x = np.stack([1.5e-3 * t + 40.0 * (t >= 20_000), np.full(len(t), 7.0), np.zeros(len(t))], 1)
    ok = np.ones(x.shape, bool)
    ok[:, 2] = t < 1000
    v = robust_speeds(t, x, np.zeros_like(x), ok)
    assert v[0] == pytest.approx(1500.0)
    assert v[1] == 0.0
    assert np.isnan(v[2])


def test_tracked_sigmas_and_sizes_per_ms():
    sxx = np.full((5, 2), 16.0)
    syy = np.full((5, 2), 9.0)
    ok = np.ones((5, 2), bool)
    ok[:, 1] = False
    sig = tracked_sigmas(sxx, syy, ok)
    assert sig[0] == pytest.approx(np.sqrt(12.5)) and np.isnan(sig[1])
    assert sizes_per_ms(np.array([3000.0, 1e9]), sig, 0.5) == pytest.approx(3.0 / sig[0])
    assert sizes_per_ms(np.array([np.nan, np.nan]), sig) == 0.0


def test_the_rule():
    assert fast_enough(2.0, MOTION_SIGMAS_PER_MS) and not fast_enough(0.5, MOTION_SIGMAS_PER_MS)
    assert not fast_enough(100.0, 0.0)                  # 0: never
    assert sets_motion({"polarity_gain": 0.0}) and not sets_motion({}) and not sets_motion(None)


@pytest.mark.parametrize("gname", ["sensor", "screen"])
@pytest.mark.parametrize("sname", ["grid_pull", "face_occlusion"])
@pytest.mark.parametrize("acquire", [False, True], ids=["placed", "acquired"])
def test_the_papers_scenes_stay_on_the_papers_step(gname, sname, acquire):
    """Both generators' pulled grid and face, placed and acquired, seed 0: their parts cross
    well under one size per ms (measured up to 0.14 over seeds 0-2, docs/motion.md), so
    ``track`` keeps the paper's step on them."""
    gen = generator(gname)
    scene = gen.make_scene(sname, seed=0)
    ev = np.concatenate([e for e, _ in gen.simulate(scene, 0.1, 0)])
    face = sname.startswith("face")
    model = scene.initial_model(**({} if face else dict(stiffness=0.001,
                                                         springs=("cartesian",))))
    ev = ev[ev["t"] < ev["t"][0] + probe_window_us(acquire, 50.0)]
    p = probe(model, ev, acquire=acquire)
    assert p.measured, p
    assert p.sizes_per_ms < 0.3 * MOTION_SIGMAS_PER_MS, p


def test_a_learned_models_speed_is_not_probed_again(tmp_path):
    """A model the learner made carries the speed it measured ([learned] sizes_per_ms):
    ``track`` takes the learner's decision and runs no probe."""
    from springtrack.learning.motion import decided as _decided
    m = load_model("face26")
    assert not _decided([m], {}, MOTION_SIGMAS_PER_MS)
    m.learned = {"sizes_per_ms": 0.05}
    assert _decided([m], {}, MOTION_SIGMAS_PER_MS)


def test_a_fast_models_acquisition_window():
    """The window in which the parts cross ACQUIRE_SIZES of their sizes, within
    [ACQUIRE_MIN_MS, the window asked]; a part not measured keeps the window asked."""
    from springtrack.learning.motion import ACQUIRE_MIN_MS, ACQUIRE_SIZES, fast_acquire_ms
    assert fast_acquire_ms(2.0, 50.0) == pytest.approx(ACQUIRE_SIZES / 2.0)
    assert fast_acquire_ms(100.0, 50.0) == ACQUIRE_MIN_MS
    assert fast_acquire_ms(0.01, 50.0) == 50.0
    assert fast_acquire_ms(0.0, 50.0) == 50.0
