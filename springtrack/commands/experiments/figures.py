"""The experiments' figures: one function per figure, arrays in, a PNG out.

Each function takes the numbers to draw (computed by the report's section, which also
tabulates them) and the path to write; none reads results or writes markdown.  A new
figure is a new function here and a section in ``report.py`` that calls it.
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np

DPI = 100


@contextmanager
def figure(path, **subplots):
    """``(fig, axes)`` of ``plt.subplots(**subplots)``, laid out and saved to ``path``
    at the end of the block."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(**subplots)
    try:
        yield fig, axes
        fig.tight_layout()
        fig.savefig(path, dpi=DPI)
    finally:
        plt.close(fig)


def decorate(ax, xlabel, ylabel, title=None, legend=None) -> None:
    """Axis labels, title, a legend in font size ``legend`` (None: none) and a light grid."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title is not None:
        ax.set_title(title)
    if legend is not None:
        ax.legend(fontsize=legend)
    ax.grid(True, alpha=0.3)


def max_angle(path, alphas, angles) -> None:
    """Fig. 11b: maximum tracking angle (deg) vs Cartesian stiffness alpha."""
    with figure(path, figsize=(5, 3.2)) as (fig, ax):
        ax.semilogx(alphas, angles, "o-")
        ax.set_ylim(0, 80)
        decorate(ax, "stiffness alpha (Cartesian)", "max tracking angle (deg)",
                 "Fig. 11b: grid_rot_y")


def pulled_element(path, t, blob, want, traces, insensitive, part) -> None:
    """Fig. 13a: x (px) over time (s) of the pulled element ``part``: where the blob is
    (``blob``), where it should be (``want``), its tracker per run (``traces``: (label, x)),
    and ``insensitive`` = (t, x, label) samples of the first run, or None."""
    with figure(path, figsize=(7, 3.2)) as (fig, ax):
        ax.plot(t, blob, "k-", lw=1.0, label="blob (real position)")
        ax.plot(t, want, "g--", lw=1.0, label="desired (unpulled)")
        for label, x in traces:
            ax.plot(t, x, lw=0.8, label=label)
        if insensitive is not None:
            ti, xi, label = insensitive
            ax.plot(ti, xi, "r.", ms=2, label=label)
        decorate(ax, "time (s)", f"x of {part} (px)",
                 "Fig. 13a: grid_pull, the pulled element, alpha = 0.001", legend=7)


def error_vs_s(path, s, pct, off_pct, paper) -> None:
    """Fig. 14: mean error (%) vs s; ``off_pct``: the criteria-off error or None;
    ``paper``: the paper's best (s, %)."""
    with figure(path, figsize=(5, 3.2)) as (fig, ax):
        ax.plot(s, pct, "o-", label="ours")
        if off_pct is not None:
            ax.axhline(off_pct, color="gray", ls="--", label="energy criteria off")
        ax.plot([paper[0]], [paper[1]], "r*", ms=10, label=f"paper best ({paper[1]:g} %)")
        decorate(ax, "s", "mean error (%)", "Fig. 14: grid_pull, alpha = 0.001", legend=8)


def error_vs_s_frames(path, s, by_frame, paper) -> None:
    """Fig. 14 in both frames: mean error (%) vs s, one line per frame (``by_frame``:
    frame -> errors); ``paper``: the paper's best (s, %)."""
    with figure(path, figsize=(5, 3.2)) as (fig, ax):
        for name, pct in by_frame.items():
            ax.plot(s, pct, "o-", label=f"{name} frame")
        ax.plot([paper[0]], [paper[1]], "r*", ms=10, label=f"paper best ({paper[1]:g} %)")
        decorate(ax, "s", "mean error (%)", "Fig. 14, both frames: grid_pull, alpha = 0.001",
                 legend=8)


def min_error_per_alpha(path, alphas, by_kind, title, paper=None) -> None:
    """Figs. 15 / 16: minimum mean error over s (%) vs alpha, one line per spring kind
    (``by_kind``: kind -> errors); ``paper``: the paper's best (alpha, %) or None."""
    with figure(path, figsize=(5, 3.2)) as (fig, ax):
        for kind, ys in by_kind.items():
            ax.semilogx(alphas, ys, "o-", label=kind)
        if paper is not None:
            ax.plot([paper[0]], [paper[1]], "r*", ms=10, label="paper best (Cartesian)")
        decorate(ax, "stiffness alpha", "min mean error over s (%)", title, legend=8)


def error_over_time(path, series, paper_pct, title) -> None:
    """Fig. 20: error (% of the mask length) over time (s); ``series``: (t, pct, label)."""
    with figure(path, figsize=(6, 3.2)) as (fig, ax):
        for t, pct, label in series:
            ax.plot(t, pct, lw=0.7, label=label)
        ax.axhline(paper_pct, color="r", ls="--", lw=0.8, label=f"paper mean {paper_pct:g} %")
        ax.set_ylim(0, max(30, paper_pct * 2))
        decorate(ax, "time (s)", "error (% of mask length)", title, legend=7)


def energies(path, t, smoothed, title) -> None:
    """Fig. 21: energies over time (s), each as % of its maximum (``smoothed``: name ->
    moving means)."""
    with figure(path, figsize=(6, 3.2)) as (fig, ax):
        for name, e in smoothed.items():
            ax.plot(t, 100 * e / np.nanmax(e) if np.nanmax(e) > 0 else e, lw=0.8, label=name)
        decorate(ax, "time (s)", "energy, 50 ms mean (% of max)", title, legend=8)


def spring_period(path, periods, err, ms_per_10ms) -> None:
    """Fig. 24: mean error (%) and compute time per 10 ms of events (ms) vs spring period."""
    with figure(path, ncols=2, figsize=(8, 3.2)) as (fig, (a1, a2)):
        a1.semilogx(periods, err, "o-")
        decorate(a1, "spring period (events)", "mean error (%)")
        a2.semilogx(periods, ms_per_10ms, "o-")
        decorate(a2, "spring period (events)", "compute time per 10 ms (ms)")
        fig.suptitle("Fig. 24: face_occlusion, s = 2.5")
