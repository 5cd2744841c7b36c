"""The learner's settings, constants and results: ``LearnParams``, ``LearnResult``,
``LearnedSpring``, ``NoObjectFound`` (springtrack.learning)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from . import batch as _learn
from ..model import ShapeModel


POOL_CAPACITY = 128           # trackers alive at once during discovery
COVERED_MIN_LEVEL = 2.0       # Pool.update_level: the least level (contrast thresholds)
LEVEL_EVERY = 10              # levels (Pool.update_level, BirthField.update_noise) are
                              # measured every this many batches
POINT_SIGMA = 1.05            # a tracker narrower than this sigma_min_px both ways: a point
MASS_RANGE = (0.5, 2.0)       # masses: event share over the median, bounded
MIN_SAMPLES = 10              # batches a pair must share for a spring
CONTRAST_MARGIN = 0.05        # contrast_sign: ON-first fraction this far from 1/2 decides
CONTRAST_MIN_EVENTS = 2       # contrast_sign: pixels with at least this many events
MIN_EVENTS = 2000             # a learning window with fewer events holds no object
WEAK_PASSES = 4               # the weak-part rule's passes at most (again only while one
                              # part holds half the events)
TIME_FIELDS = ("batch_us", "activity_tau_us", "life_tau_us", "smooth_us")
MOTION_SIGMAS_PER_MS = 1.0    # the motion model's threshold, part sizes (sigma) per ms
MIN_BATCH_US = 20             # the shortest lifecycle step a scaled window gets
MAX_PARTS = 64                # the most trackers a learned model gets by default (one
                              # instance of the kernels: limits.MAX_TRACKERS)
PERSIST_GRACES = 2.0          # a part that lived this many grace periods persisted
PERSIST_MIN = 0.5             # parts persisting less (median) are "no stable object"
COHERENCE_MIN = 0.25          # fewer co-active neighbour pairs: "no stable object"
LAYOUT_RIGID = 0.3            # a layout rigidity below this is said (parts slide)
F = {name: k for k, name in enumerate(_learn.FIELDS)}


class NoObjectFound(ValueError):
    """The events hold no object the learner could model (noise, or too few events)."""
    exit_code = 3                     # ``springtrack learn``'s exit status for it


@dataclass(frozen=True)
class LearnParams:
    """The learner's parameters (docs/learning.md); units in the names."""
    # the free pool, eqs. (2)-(6)
    alpha_position: float = 0.03       # alpha_1 of the pool: weight of an event in the mean
    alpha_covariance: float = 0.01     # alpha_2 of the pool: weight in the covariance
    p_threshold: float = 0.1           # delta_p: the gate exp(-d^2/2) > delta_p
    activity_tau_us: float = 10_000.0  # tau of eq. (6); also the decay of birth counts
    sigma_min_px: float = 2.0          # bounds on a part's standard deviations
    sigma_max_px: float = 16.0
    batch_us: int = 1000               # lifecycle and sampling period
    # lifecycle
    birth_cell_px: int = 4
    birth_events: float = 8.0          # unassigned events in a 3x3 block of cells ...
    birth_contrast: float = 5.0        # ... and this many times the background block
    merge_overlap: float = 0.25        # shared fraction of the smaller tracker's events
    merge_gap_px: float = 1.5          # neighbours joined by covered pixels, no gap this long
    outline_cover: float = 0.75        # merge pieces on one outline of recent pixels that
                                       # surrounds its centre in this share of directions
                                       # (learning.outlines; 0: off)
    edge_polarity: float = 0.75        # merge a uniform part's two edges, arcs bending
                                       # toward each other whose recent events are each
                                       # this share one polarity (learning.edges; 0: off)
    death_share: float = 0.05          # of the pool's median recent event count
    keep_share: float = 0.4            # a part takes this share of the median's events
    idle_share: float = 0.1            # ... and is awake (awake()) at the end: this share
                                       #     of the pool's median
    life_tau_us: float = 50_000.0      # memory of recent counts; grace period after birth
    # springs
    min_coactivation: float = 0.5
    min_rigidity: float = 0.2
    rigidity_scale: float = 0.5        # deformation (in part sizes) of rigidity 1/2
    cartesian_turn_deg: float = 10.0
    lag_fraction: float = 0.1          # alpha_1 (tracking): eq. (3)'s lag, in part sizes
    covariance_ratio: float = 400.0    # alpha_2 (tracking) = alpha_1 / this: eq. (4) averages
                                       # this many times the events eq. (3) does (the paper's
                                       # grid, 0.02 / 5e-5; its face 0.2 / 2e-4 = 1000)
    stiffness_gain: float = 0.1        # stiffness = gain * alpha_1 (tracking) * rigidity
    energy_quantile: float = 0.99      # s of eqs. (21)-(22): this quantile of E_ij / mean E,
    energy_scale_max: float = 4.5      # ... at most this (and at least the default 2.5)
    smooth_us: int = 20_000            # averaging of directions for the turn measure
    # the motion model (eqs. M1-M9) written into the model when its parts move faster
    # than this many part sizes (sigma) per millisecond (0: never)
    motion_sigmas_per_ms: float = MOTION_SIGMAS_PER_MS

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"learn: {f.name} must be a finite number, got {v!r}")
            if v < 0:
                raise ValueError(f"learn: {f.name} must not be negative, got {v!r}")
        if not 0 < self.alpha_position <= 1 or not 0 < self.alpha_covariance <= 1:
            raise ValueError("learn: alpha_position and alpha_covariance must be in (0, 1]")
        if not 0 < self.p_threshold < 1:
            raise ValueError("learn: p_threshold must be in (0, 1)")
        if self.outline_cover > 1:
            raise ValueError("learn: outline_cover is a share of directions, in [0, 1] (0: off)")
        if self.edge_polarity and not 0.5 < self.edge_polarity <= 1:
            raise ValueError("learn: edge_polarity is a share of events, in (0.5, 1] (0: off)")
        if not 0 < self.sigma_min_px < self.sigma_max_px:
            raise ValueError("learn: need 0 < sigma_min_px < sigma_max_px")
        for name in ("batch_us", "birth_cell_px", "activity_tau_us", "life_tau_us", "smooth_us",
                     "lag_fraction", "covariance_ratio"):
            if getattr(self, name) <= 0:
                raise ValueError(f"learn: {name} must be positive")

    @property
    def gate_d2(self) -> float:
        return -2.0 * math.log(self.p_threshold)

    @property
    def reference_window_us(self) -> float:
        """The shortest window the time constants are meant for: two grace periods
        (a part born in the window's first half outlives its grace period)."""
        return 2.0 * self.life_tau_us

    def for_window(self, window_us: float) -> "LearnParams":
        """These parameters for a learning window of ``window_us``: the lifecycle's time
        constants (``batch_us``, ``activity_tau_us``, ``life_tau_us``, ``smooth_us``)
        scaled by k = window_us / reference_window_us when the window is shorter than
        that, so that a part born in the window's first half outlives its grace period
        and the window still holds ``reference_window_us / batch_us`` lifecycle steps;
        a longer window keeps them.  Returns ``self`` when nothing changes."""
        k = min(1.0, max(window_us, 1.0) / self.reference_window_us)
        if k >= 1.0:
            return self
        new = {name: getattr(self, name) * k for name in TIME_FIELDS}
        new["batch_us"] = max(MIN_BATCH_US, int(round(new["batch_us"])))
        return replace(self, **new)


def learn_overrides(values, where: str = "") -> dict:
    """``values`` (a ``[learn]`` table, or NAME=VALUE options) checked as overrides of
    :class:`LearnParams`: a name it does not have, or a value it refuses, raises
    ValueError naming ``where`` and the valid names.  Returns a new dict."""
    ctx = f"{where}: " if where else ""
    if not isinstance(values, dict):
        raise ValueError(f"{ctx}the learner's parameters must be a table of names and values, "
                         f"got {type(values).__name__}")
    names = [f.name for f in fields(LearnParams)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ValueError(f"{ctx}unknown learner parameter(s) {', '.join(unknown)}; the learner "
                         f"has {', '.join(names)} (docs/learning.md)")
    try:
        LearnParams(**values)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{ctx}{e}") from None
    return dict(values)


def parse_assignments(items, option: str = "--learn-param") -> dict:
    """``["NAME=VALUE", ...]`` as a dict of numbers (each error names ``option``)."""
    out = {}
    for item in items or ():
        name, eq, value = item.partition("=")
        if not eq or not name.strip():
            raise ValueError(f"{option} takes NAME=VALUE (e.g. sigma_max_px=24), got {item!r}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"{option} {name.strip()}: {value!r} is not a number") from None
        out[name.strip()] = int(number) if number.is_integer() and "." not in value else number
    return out


@dataclass
class LearnedSpring:
    a: int
    b: int
    coactivation: float
    rigidity: float
    turn_deg: float
    kinds: tuple


@dataclass
class LearnResult:
    """What :func:`learn_model` found: the model and the evidence behind it."""
    model: ShapeModel
    events: int                        # events in the window
    assigned: int                      # of them taken by the final trackers (their histories)
    t_start_us: int
    t_end_us: int
    counts: np.ndarray                 # (N,) events each final tracker (or its pieces) took
    springs: list                      # LearnedSpring per connection (model order)
    candidates: list                   # every LearnedSpring considered, kept or not
    lifecycle: dict = field(default_factory=dict)
    wall_s: float = 0.0
