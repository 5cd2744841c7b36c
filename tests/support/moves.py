"""Moving an instance rigidly in the tests (tests/test_springtrack/test_move.py, tests/test_springtrack/mcu/test_mcu.py): a
similarity about the model's centre of mass, a stream that follows it, and a tracker run
through the move; the face of tests/test_springtrack/acquisition/test_reacquire.py jumping, which a tracker with
``acquire=True`` finds moved and moves onto its new place."""
import math

import numpy as np

import springtrack
from springtrack.acquisition.acquire import Pose, model_pose, place
from springtrack.sim.scenes import Disrupted, make_scene
from springtrack.sim.sensor import simulate_all
from springtrack.sim.synthetic import blob_stream


def similarity(model, dx, dy, deg, k):
    """(a, b, tx, ty) turning by ``deg`` and scaling by ``k`` about the model's centre of
    mass, then shifting by (dx, dy); and the model moved by it."""
    g = model_pose(model)
    c, s = k * math.cos(math.radians(deg)), k * math.sin(math.radians(deg))
    tx, ty = g.tx + dx - (c * g.tx - s * g.ty), g.ty + dy - (s * g.tx + c * g.ty)
    return (c, s, tx, ty), place(model, Pose(g.tx + dx, g.ty + dy, deg, k))


def moved_stream(model, sim, n: int, seed: int):
    """A stream of the model's parts (blob_stream) of ``n`` events cut in two halves, the
    second following the parts to their place moved by ``sim`` (events mapped, those off
    the sensor dropped)."""
    ev, _ = blob_stream(model, n, seed=seed)
    half = len(ev) // 2
    ev2 = ev[half:].copy()
    a, b, tx, ty = sim
    x, y = ev2["x"].astype(float), ev2["y"].astype(float)
    nx, ny = np.rint(a * x - b * y + tx), np.rint(b * x + a * y + ty)
    keep = (nx >= 0) & (nx < model.width) & (ny >= 0) & (ny < model.height)
    ev2 = ev2[keep]
    ev2["x"], ev2["y"] = nx[keep], ny[keep]
    return ev[:half], ev2


def run_moved(backend: str, model, params, sim, moved, ev1, ev2):
    """(track before, state at the move, track after, tracker): ``ev1``, the instance
    moved by ``sim`` onto ``moved``, then ``ev2``."""
    tr = springtrack.Tracker(model, params, backend=backend)
    t1 = tr.run(ev1, 1000)
    tr._ib.move(0, sim, moved)
    mid = tr.state()
    return t1, mid, tr.run(ev2, 1000), tr


def jump_run(backend: str, seconds: float = 0.45):
    """(tracker, track) of ``springtrack.Tracker(..., acquire=True)`` on the simulator's
    face jumping 60 px at 0.3 s (tests/test_springtrack/acquisition/test_reacquire.py's jump): found moved by the
    verification search, it is moved onto its new place, then refined and moved again."""
    sc = Disrupted(make_scene("face_occlusion", hand_first=100.0), at_s=0.3, dx=60.0)
    ev, _ = simulate_all(sc, seconds)
    tr = springtrack.Tracker(sc.initial_model(), backend=backend, acquire=True)
    return tr, tr.run(ev, 1000)
