"""The fixed-point kernel's documented bound against the float64 kernel, and the streams
it is checked on (docs/fixed_point.md).

The bound: tracker positions within 0.05 px RMS and 0.25 px max, covariances within 1 %,
the same trackers active / sensitive at >= 99.9 % of the samples, and the paper's
tracking error (springtrack.metrics) within 0.1 percentage point.  :func:`compare` runs
both backends on one event array and returns those figures; tests/test_springtrack/fixed/test_fixed_accuracy.py
checks a reduced stream on every run, benchmarks/fixed_accuracy.py the >= 1 M event
streams whose figures go to docs/fixed_point.md.
"""
from __future__ import annotations

import numpy as np

from springtrack.metrics import Truth, tracking_error
from springtrack.model import ShapeModel, load_model
from springtrack.sim.synthetic import blob_stream, part_positions
from springtrack.tracker import Tracker

BOUNDS = dict(pos_rms_px=0.05, pos_max_px=0.25, cov_rel_max=0.01, active_agree_min=0.999,
              sensitive_agree_min=0.999, metric_diff_pp=0.1)

# structured synthetic scenes: name -> (preset, blob_stream motion).  The plain scenes
# drift and turn fast enough that after a few seconds the float tracker itself starts to
# lose the shape; the "steady" ones move slowly enough to stay tracked for millions of events.
SCENES = {
    "grid3x3": ("grid3x3", dict(noise=0.3, speed_px_s=(15.0, 8.0), rot_deg_s=10.0)),
    "face26": ("face26", dict(noise=0.3, speed_px_s=(10.0, -5.0), rot_deg_s=-8.0, wobble_px=4.0)),
    "grid3x3-steady": ("grid3x3", dict(noise=0.3, speed_px_s=(6.0, 3.0), rot_deg_s=3.0,
                                       wobble_px=3.0)),
    "face26-steady": ("face26", dict(noise=0.3, speed_px_s=(4.0, -2.0), rot_deg_s=-2.0,
                                     wobble_px=3.0)),
}


# the simulator's scenes (springtrack.sim) with the paper's per-experiment values
# (springtrack.commands.experiments.plan.SCENE_RUNS): name -> (scene, spring kinds,
# stiffness, energy_scale s); the face keeps its preset's springs
SIM_SCENES = {
    "face_occlusion": ("face_occlusion", None, None, 2.5),
    "grid_pull": ("grid_pull", ("cartesian",), 0.001, 4.5),
    "grid_inplane": ("grid_inplane", ("euclidean", "torsional"), 0.001, 4.0),
    "grid_scale": ("grid_scale", ("cartesian",), 0.001, 4.5),
}


def sim_stream(name: str, seconds: float, seed: int = 0):
    """(model, events, Truth, params) of a SIM_SCENES scene simulated for ``seconds``."""
    from springtrack.metrics import truth_from_array
    from springtrack.sim.scenes import make_scene
    from springtrack.sim.sensor import simulate_all
    scene_name, springs, stiffness, s = SIM_SCENES[name]
    scene = make_scene(scene_name, seed=seed)
    model = scene.initial_model(**({} if springs is None
                                   else dict(stiffness=stiffness, springs=springs)))
    ev, tr = simulate_all(scene, seconds, seed=seed)
    return model, ev, truth_from_array(tr), dict(energy_scale=s)


def scene_stream(scene: str, n: int, seed: int = 1):
    """(model, events) of a structured synthetic scene: the preset's parts moving smoothly,
    plus uniform noise, 300 k events/s."""
    preset, motion = SCENES[scene]
    model = load_model(preset)
    ev, _ = blob_stream(model, n, rate_hz=300_000, seed=seed, **motion)
    return model, ev


def truth_for(model: ShapeModel, scene: str, t_us: np.ndarray) -> Truth:
    """The scene's true part positions at the sample times (for the tracking error)."""
    kw = {k: v for k, v in SCENES[scene][1].items() if k != "noise"}
    xy = part_positions(model, t_us, **kw)
    return Truth(np.asarray(t_us, np.int64), model.ids, xy)


def compare(model: ShapeModel, events, sample_us: int = 1000, truth: Truth | None = None,
            params=None, backend: str = "fixed") -> dict:
    """Run the float64 ("cython") and the fixed backends (or ``backend``: the
    microcontroller build, "mcu:...") on ``events``; return the figures of the bound (and
    the raw counters, under "counters_fixed") as a dict."""
    tracks, counters = {}, {}
    for b, name in (("cython", "cython"), ("fixed", backend)):
        tr = Tracker(model, params=params, backend=name)
        tracks[b] = tr.run(events, sample_us=sample_us)
        counters[b] = tr.counters
    a, f = tracks["cython"], tracks["fixed"]
    out = dict(figures(a, f), events=len(events), counters_float=counters["cython"],
               counters_fixed=counters["fixed"], episodes=divergence_episodes(a, f))
    if truth is not None:
        ea = tracking_error(truth, a.t_us, a.ids, a.x, a.y).mean_pct
        ef = tracking_error(truth, f.t_us, f.ids, f.x, f.y).mean_pct
        out.update(metric_float_pct=ea, metric_fixed_pct=ef, metric_diff_pp=abs(ea - ef))
    return out


def figures(a, f) -> dict:
    """The figures of the bound for the fixed kernel's samples ``f`` against the float64
    kernel's ``a``: two tracks, or two states (TRACK_DTYPE arrays, ``Tracker.state()``)."""
    def get(v, k):
        return np.asarray(v[k] if isinstance(v, np.ndarray) else getattr(v, k))
    a_, f_ = ({k: get(v, k) for k in ("x", "y", "sxx", "sxy", "syy", "activity", "active",
                                       "sensitive")} for v in (a, f))
    d = np.hypot(a_["x"] - f_["x"], a_["y"] - f_["y"])
    cov_rel = max(float(np.max(np.abs(a_["sxx"] - f_["sxx"]) / a_["sxx"])),
                  float(np.max(np.abs(a_["syy"] - f_["syy"]) / a_["syy"])),
                  float(np.max(np.abs(a_["sxy"] - f_["sxy"]) / np.sqrt(a_["sxx"] * a_["syy"]))))
    return dict(samples=len(a), pos_rms_px=float(np.sqrt(np.mean(d ** 2))),
                pos_max_px=float(d.max()), cov_rel_max=cov_rel,
                active_agree=float(np.mean(a_["active"] == f_["active"])),
                sensitive_agree=float(np.mean(a_["sensitive"] == f_["sensitive"])),
                activity_rel_max=float(np.max(np.abs(a_["activity"] - f_["activity"])
                                              / np.maximum(a_["activity"], 1e-3))))


def divergence_episodes(a, f, threshold_px: float = 0.25) -> list[tuple[int, int, float]]:
    """(first sample, last sample, max px) of each run of samples in which some tracker of
    track ``f`` is farther than ``threshold_px`` from its float64 twin in track ``a``."""
    d = np.hypot(a.x - f.x, a.y - f.y).max(axis=1)
    over = np.flatnonzero(d > threshold_px)
    runs = np.split(over, np.flatnonzero(np.diff(over) > 1) + 1) if len(over) else []
    return [(int(r[0]), int(r[-1]), float(d[r].max())) for r in runs]


def violations(res: dict) -> list[str]:
    """The parts of the bound that ``res`` (from :func:`compare`) breaks, as messages."""
    bad = []
    for key in ("pos_rms_px", "pos_max_px", "cov_rel_max", "metric_diff_pp"):
        if key in res and not res[key] <= BOUNDS[key]:
            bad.append(f"{key} = {res[key]:.3g} > {BOUNDS[key]}")
    for key in ("active_agree", "sensitive_agree"):
        if not res[key] >= BOUNDS[key + "_min"]:
            bad.append(f"{key} = {res[key]:.5f} < {BOUNDS[key + '_min']}")
    return bad
