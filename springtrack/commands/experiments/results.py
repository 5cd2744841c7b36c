"""Queries on the result dicts of :func:`runs.run_case`, shared by the report's sections."""
from __future__ import annotations

import numpy as np


def select(results, **kw) -> list[dict]:
    """The results whose keys equal every ``kw``."""
    return [r for r in results if all(r.get(k) == v for k, v in kw.items())]


def is_off(s) -> bool:
    """s large enough that the energy criteria never act (plan.S_OFF)."""
    return s >= 1e5


def s_label(s) -> str:
    return "off (1e6)" if is_off(s) else f"{s:g}"


def best(rs) -> dict:
    """The lowest mean error; ties: the smallest s."""
    return min(rs, key=lambda r: (round(r["mean_pct"], 6), r["s"]))


def criteria_off(rs) -> dict | None:
    """The run with the energy criteria off, if any."""
    off = [r for r in rs if is_off(r["s"])]
    return off[0] if off else None


def min_over_s(results, exp, kind, alpha):
    """(best run over s, run with the criteria off or None) of one alpha of one kind."""
    rs = select(results, exp=exp, kind=kind, alpha=alpha)
    return best(rs), criteria_off(rs)


def mean_pct(rs) -> float:
    return float(np.mean([r["mean_pct"] for r in rs]))


def hand_split(rs) -> tuple[float, float]:
    """Mean error % during the hand passes (+1 s) and outside them, over runs ``rs``."""
    from springtrack.sim.scenes import make_scene
    ins, outs = [], []
    for r in rs:
        sc = make_scene("face_occlusion", seed=r["seed"])
        t = r["t_us"] / 1e6
        u = (t - sc.hand_first) % sc.hand_period
        hand = (t >= sc.hand_first) & (u <= sc.hand_duration + 1.0)
        ins.append(r["pct"][hand])
        outs.append(r["pct"][~hand])
    i = np.concatenate(ins) if ins else np.array([])
    o = np.concatenate(outs) if outs else np.array([])
    return (float(np.nanmean(i)) if len(i) else float("nan"),
            float(np.nanmean(o)) if len(o) else float("nan"))
