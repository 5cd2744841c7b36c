"""A small, real, deterministic firmware engine for the link tests (the production engine is
firmware_sim/loop.py): it runs the real ``springtrack.Tracker`` on the simulated
``face_occlusion`` events in 1 ms chunks of event time, applies queued updates only at
chunk boundaries (double buffering), and publishes one snapshot per chunk.  Event time is
paced to wall time times ``speed`` by a background thread started with :meth:`run`.

The tests at the bottom check the engine itself, so the link tests stand on it.
"""

import numpy as np
import pytest

import springtrack
from firmware_sim.engine import UpdateRejected
from springtrack.wire import Nack
from support.engine import SimEngine


# ---- the engine's own behaviour -----------------------------------------------------
def test_engine_tracks_the_scene_like_the_offline_tracker():
    eng = SimEngine()
    eng.start()
    for _ in range(300):
        eng.step()
    snaps = eng.poll_telemetry(1000)
    assert [s.t_us for s in snaps] == list(range(1000, 301_000, 1000))
    ev = eng.events[eng.events["t"] < 300_000]
    offline = springtrack.Tracker("face26")
    offline.process(ev)
    assert np.array_equal(offline.state()["x"], snaps[-1].trackers["x"])


def test_engine_updates_take_effect_at_the_next_chunk_and_are_reported():
    eng = SimEngine()
    eng.step()
    gen = eng.set_param("alpha_position", 0.05)
    assert eng.get_params()["alpha_position"] == 0.2          # queued, not yet applied
    eng.step()
    assert eng.get_params()["alpha_position"] == 0.05
    assert eng.poll_applied() == [(gen, 1000)]
    snaps = eng.poll_telemetry()
    assert [s.generation for s in snaps] == [1, gen]


@pytest.mark.parametrize("name,value,code", [("nope", 1.0, Nack.UNKNOWN_NAME),
                                             ("alpha_position", 2.0, Nack.OUT_OF_RANGE),
                                             ("alpha_position", "x", Nack.WRONG_TYPE),
                                             ("spring_period", 1.5, Nack.WRONG_TYPE),
                                             ("spring_period", float("inf"), Nack.OUT_OF_RANGE),
                                             ("alpha_position", float("nan"), Nack.OUT_OF_RANGE),
                                             ("energy_kind", "bogus", Nack.OUT_OF_RANGE),
                                             ("energy_kind", 1, Nack.WRONG_TYPE)])
def test_engine_rejects_bad_updates_without_changing_state(name, value, code):
    eng = SimEngine()
    before = (eng.generation, eng.get_params())
    with pytest.raises(UpdateRejected) as e:
        eng.set_param(name, value)
    assert e.value.code == code
    assert (eng.generation, eng.get_params()) == before
