"""What the experiments run: the paper's reference numbers, the sweep grids (:class:`Plan`)
and the list of tracker runs they make (:func:`cases`, :func:`hand_cases`).

A case is a dict: ``exp`` (the figure or table it feeds), ``scene`` and ``seed`` (the
simulated stimulus), ``model`` (``initial_model`` keywords), ``params`` (tracker parameter
overrides) and the swept values it is reported by (``alpha``, ``s``, ``kind``, ``period``,
``hand``).  Flags ask :func:`springtrack.commands.experiments.runs.run_case` for more than
the mean error: ``series`` (error and energies over time), ``trace`` (the pulled element's
tracker), ``angle`` (the maximum tracking angle).
"""
from __future__ import annotations

from dataclasses import dataclass, field

PAPER = {"grid_pull_best_pct": 2.74, "grid_pull_best_alpha": 0.001, "grid_pull_best_s": 4.5,
         "grid_pull_et_best_s": 4.0, "face_pct": 5.42, "face_s": 2.5,
         "face_ms_per_10ms": 3.36, "face_us_per_event": 2.26}
KINDS = {"cartesian": ("cartesian",), "euclidean+torsional": ("euclidean", "torsional")}
S_OFF = 1e6          # an energy scale s so large that the energy criteria never act


@dataclass
class Plan:
    """Durations and sweep grids; --quick shrinks them."""
    grid_seconds: float = 20.0
    face_seconds: float = 20.0
    rot_alphas: tuple = (0.002, 0.004, 0.008, 0.016, 0.03, 0.06, 0.12, 0.25)
    s_values: tuple = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0,
                       S_OFF)
    alphas: tuple = (0.0005, 0.001, 0.002, 0.004, 0.008, 0.016)
    table_s: tuple = (1.5, 2.0, 3.0, 4.0, 4.5, 5.0, 6.0, 8.0, S_OFF)
    face_s: tuple = (1.5, 2.0, 2.5, 3.0)
    spring_periods: tuple = (1, 5, 11, 22, 55, 110, 220, 550)
    face_seeds: tuple = (0, 1, 2)     # face runs are averaged over these scene seeds (+ seed)
    hand_sizes: tuple = (0.08, 0.12, 0.16, 0.2)   # palm radius, face heights (default 0.16)
    seed: int = 0
    scenes: dict = field(default_factory=dict)   # (scene, seed) -> (s, events, wall s), filled in

    @classmethod
    def quick(cls, seed=0):
        return cls(grid_seconds=10.0, face_seconds=12.0,
                   rot_alphas=(0.004, 0.016, 0.06, 0.25),
                   s_values=(1.5, 2.5, 3.5, 4.5, 6.0, 10.0, S_OFF),
                   alphas=(0.0005, 0.001, 0.004, 0.016), table_s=(2.0, 3.0, 4.5, 6.0, S_OFF),
                   face_s=(2.0, 2.5), spring_periods=(5, 22, 55, 220), face_seeds=(0,),
                   hand_sizes=(0.12, 0.16), seed=seed)


def cases(plan: Plan) -> list[dict]:
    """Every tracker run on a scene simulated once in the driver (see runs.run_all)."""
    out = []
    base = dict(seed=plan.seed)
    for a in plan.rot_alphas:                                           # Fig. 11b
        out.append(dict(base, exp="fig11b", scene="grid_rot_y", alpha=a, angle=True,
                        model=dict(stiffness=a, springs=KINDS["cartesian"])))
    for s in (PAPER["grid_pull_best_s"], S_OFF):                        # Fig. 13
        out.append(dict(base, exp="fig13", scene="grid_pull", alpha=0.001, s=s, trace=True,
                        model=dict(stiffness=0.001, springs=KINDS["cartesian"]),
                        params=dict(energy_scale=s)))
    for s in plan.s_values:                                             # Fig. 14
        out.append(dict(base, exp="fig14", scene="grid_pull", alpha=0.001, s=s,
                        model=dict(stiffness=0.001, springs=KINDS["cartesian"]),
                        params=dict(energy_scale=s)))
    for exp, scene in (("table1", "grid_pull"), ("fig16", "grid_inplane")):   # Table I, 15, 16
        for kind, springs in KINDS.items():
            for a in plan.alphas:
                for s in plan.table_s:
                    out.append(dict(base, exp=exp, scene=scene, kind=kind, alpha=a, s=s,
                                    model=dict(stiffness=a, springs=springs),
                                    params=dict(energy_scale=s)))
    for fs in plan.face_seeds:
        face = dict(base, scene="face_occlusion", seed=plan.seed + fs)
        for s in plan.face_s:                                           # Figs. 20-21
            out.append(dict(face, exp="face", s=s, series=True, params=dict(energy_scale=s)))
        for n in plan.spring_periods:                                   # Fig. 24
            out.append(dict(face, exp="fig24", period=n, s=PAPER["face_s"],
                            params=dict(energy_scale=PAPER["face_s"], spring_period=n)))
    return out


def hand_cases(plan: Plan) -> list[dict]:
    """Hand-size sensitivity of face_occlusion: each simulated on its worker, then tracked
    at s = 2.5 and with the criteria off."""
    return [dict(exp="hand", scene="face_occlusion", seed=plan.seed + fs, hand=h,
                 seconds=plan.face_seconds, scene_params=dict(hand_size=h))
            for h in plan.hand_sizes for fs in plan.face_seeds]
