"""The structure's own frame in ``springtrack experiments``: the paper's Figs. 14-16 in both
frames of eq. (22) and the Cartesian springs (``pull_frame`` and ``cartesian_frame``, both
"image" or both "similarity"), side by side, and every scene -- the paper's four and
grid_spin, grid_scale -- with only the paper's per-experiment values, in both frames.

:func:`cases` adds the runs this needs beyond the figures' own (which run in the default
frame): the sweeps of Figs. 14-16 in the other frame, and the scene table in both.
:func:`section` writes the markdown and the plots.
"""
from __future__ import annotations

import numpy as np

FRAMES = {"image": dict(pull_frame="image", cartesian_frame="image"),
          "similarity": dict(pull_frame="similarity", cartesian_frame="similarity")}
SWEPT = ("fig14", "table1", "fig16")
# The scene table: scene, spring kinds, stiffness alpha and s as the paper gives them for
# that experiment (alpha1, alpha2 are the presets': 0.02 / 5e-5 grid, 0.2 / 2e-4 face), and
# the paper's figure the row is held to: its best grid error (2.74 %, Fig. 14) where it
# gives none for that motion, 2 % for the grid turning in the image plane, its face error.
SCENE_RUNS = [
    ("grid_rot_y", "cartesian", 0.004, 4.5, 2.74),     # Fig. 11: alpha 0.004
    ("grid_pull", "cartesian", 0.001, 4.5, 2.74),      # Fig. 14, Table I
    ("grid_pull", "euclidean+torsional", 0.001, 4.0, 2.74),
    ("grid_inplane", "euclidean+torsional", 0.001, 4.0, 2.0),   # Fig. 16
    ("grid_inplane", "cartesian", 0.001, 4.5, 2.0),
    ("grid_spin", "euclidean+torsional", 0.001, 4.0, 2.0),
    ("grid_spin", "cartesian", 0.001, 4.5, 2.0),
    ("grid_scale", "cartesian", 0.001, 4.5, 2.74),
    ("grid_scale", "euclidean+torsional", 0.001, 4.0, 2.74),
    ("face_occlusion", "euclidean+torsional", 0.02, 2.5, 5.42),   # IV-B, the face26 preset
]


def default_frame() -> str | None:
    """The frame springtrack.params' defaults select, or None if they mix the two."""
    from springtrack.params import Params
    p = Params()
    return next((name for name, f in FRAMES.items()
                 if (p.pull_frame, p.cartesian_frame) == (f["pull_frame"], f["cartesian_frame"])),
                None)


def exp_name(exp: str, frame: str) -> str:
    """The results' name of experiment ``exp`` run in ``frame``: the figures' own name in
    the default frame, ``exp@frame`` otherwise."""
    return exp if frame == default_frame() else f"{exp}@{frame}"


def cases(plan, base: list[dict]) -> list[dict]:
    """The runs to add to ``base`` (the figures' cases of :func:`experiments.cases`)."""
    from .experiments import KINDS
    out = []
    for c in base:
        if c["exp"] in SWEPT:
            out += [dict(c, exp=exp_name(c["exp"], name), frame=name,
                         params=dict(c.get("params", {}), **f))
                    for name, f in FRAMES.items() if exp_name(c["exp"], name) != c["exp"]]
    for scene, kind, alpha, s, _ in SCENE_RUNS:
        face = scene.startswith("face")
        model = {} if face else dict(stiffness=alpha, springs=KINDS[kind])
        for fs in (plan.face_seeds if face else (0,)):
            out += [dict(exp="scenes", scene=scene, seed=plan.seed + fs, kind=kind, alpha=alpha,
                         s=s, frame=name, model=model, params=dict(f, energy_scale=s))
                    for name, f in FRAMES.items()]
    return out


def scene_errors(results, scene, kind, frame) -> list[float]:
    from .experiments import _sel
    return [r["mean_pct"] for r in sorted(_sel(results, exp="scenes", scene=scene, kind=kind,
                                               frame=frame), key=lambda r: r["seed"])]


def _save(plt, fig, ax, labels, title, path) -> None:
    """Label, title, legend and grid the axes; write the figure to ``path`` and close it."""
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(title)
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def section(results, plan, img, plt) -> list[str]:
    """Markdown lines (and img/fig14_frames.png, fig15_frames.png, fig16_frames.png)."""
    from .experiments import KINDS, _s_label, _sel, min_over_s
    L = ["## Both frames: the paper's pull and springs, and the structure's own frame", "",
         "eq. (22) pulls toward `G + dG0` and Cartesian springs hold `d0` fixed in the image "
         "(the paper: frame image), or toward `G + s R dG0` and `s R d0` with the similarity "
         "fitted to the calm trackers at each spring update (frame similarity; "
         "docs/algorithm.md). Defaults: " + (f"the {default_frame()} frame" if default_frame()
                                               else "mixed frames") + ".", "",
         "### Every scene with the paper's per-experiment values only", "",
         "Only alpha1, alpha2 (the presets'), the springs' kind and stiffness alpha and s are "
         "set per row, as the paper gives them for that experiment; everything else is "
         "springtrack.params' default. The last column is the paper's figure the row is held "
         "to (its best grid error, 2.74 %, where the paper gives none for that motion; 2 % "
         "for the grid turning in the image plane; its face error).", "",
         "| scene | springs | alpha | s | image frame % | similarity frame % | paper / target % |",
         "|---|---|---|---|---|---|---|"]
    met = []
    for scene, kind, alpha, s, target in SCENE_RUNS:
        cells = []
        for frame in FRAMES:
            e = scene_errors(results, scene, kind, frame)
            cells.append(f"{np.mean(e):.2f}" + (f" ({', '.join(f'{v:.2f}' for v in e)})"
                                                if len(e) > 1 else "") if e else "")
            if frame == default_frame() and e:
                met.append(np.mean(e) <= target)
        L.append(f"| {scene} | {kind} | {alpha:g} | {s:g} | {cells[0]} | {cells[1]} | {target:g} |")
    if met:
        L += ["", f"In the default frame {sum(met)} of {len(met)} rows are at or below their "
              "figure."]
    L += [""]

    # Fig. 14 in both frames
    rows = {name: sorted(_sel(results, exp=exp_name("fig14", name)), key=lambda r: r["s"])
            for name in FRAMES}
    if all(rows.values()):
        fig, ax = plt.subplots(figsize=(5, 3.2))
        for name, rs in rows.items():
            fin = [r for r in rs if r["s"] < 1e5]
            ax.plot([r["s"] for r in fin], [r["mean_pct"] for r in fin], "o-", label=f"{name} frame")
        ax.plot([4.5], [2.74], "r*", ms=10, label="paper best (2.74 %)")
        _save(plt, fig, ax, ("s", "mean error (%)"),
              "Fig. 14, both frames: grid_pull, alpha = 0.001", img / "fig14_frames.png")
        L += ["### Fig. 14 in both frames (grid_pull, Cartesian, alpha = 0.001)", "",
              "| s | image frame % | similarity frame % |", "|---|---|---|"]
        L += [f"| {_s_label(a['s'])} | {a['mean_pct']:.2f} | {b['mean_pct']:.2f} |"
              for a, b in zip(rows["image"], rows["similarity"])]
        best = {n: min(rs, key=lambda r: (round(r["mean_pct"], 6), r["s"])) for n, rs in rows.items()}
        L += ["", "Best: " + "; ".join(f"{n} frame {b['mean_pct']:.2f} % at s = {b['s']:g}"
                                       for n, b in best.items()) + " (paper: 2.74 % at s = 4.5).",
              "", "![Fig. 14, both frames](img/fig14_frames.png)", ""]

    # Table I / Fig. 15 and Fig. 16 in both frames
    for exp, scene, fname in (("table1", "grid_pull", "fig15_frames.png"),
                              ("fig16", "grid_inplane", "fig16_frames.png")):
        if not all(_sel(results, exp=exp_name(exp, n)) for n in FRAMES):
            continue
        title = "Table I / Fig. 15" if exp == "table1" else "Fig. 16"
        L += [f"### {title} in both frames ({scene})", "",
              "Minimum error % over s in {" + ", ".join(_s_label(s) for s in plan.table_s)
              + "} (at s).", "",
              "| alpha | Cartesian, image | Cartesian, similarity | E+T, image | E+T, similarity |",
              "|---|---|---|---|---|"]
        fig, ax = plt.subplots(figsize=(5.5, 3.4))
        for kind in KINDS:
            for name in FRAMES:
                ys = [min_over_s(results, exp_name(exp, name), kind, a)[0]["mean_pct"]
                      for a in plan.alphas]
                ax.semilogx(plan.alphas, ys, "o-" if name == "image" else "s--",
                            label=f"{kind}, {name}")
        for a in plan.alphas:
            cells = []
            for kind in KINDS:
                for name in FRAMES:
                    b, _ = min_over_s(results, exp_name(exp, name), kind, a)
                    cells.append(f"{b['mean_pct']:.2f} ({_s_label(b['s'])})")
            L.append(f"| {a:g} | " + " | ".join(cells) + " |")
        _save(plt, fig, ax, ("stiffness alpha", "min mean error over s (%)"),
              f"{title}, both frames: {scene}", img / fname)
        L += ["", f"![{title}, both frames](img/{fname})", ""]
    return L
