"""Tracker parameters: names, units, defaults and valid ranges.

Defaults reproduce the paper's face experiment (section IV-B): alpha1 = 0.2,
alpha2 = 2e-4, delta_p = 0.1, s = 2.5, springs every 55 events, Euclidean energy; eq. (22)
and the Cartesian springs work in the structure's own (similarity) frame, which holds
under turns and changes of scale (docs/tuning.md); pull_frame = cartesian_frame = "image"
is the paper's exact rule.  See docs/algorithm.md for how each parameter enters the
equations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, asdict
from pathlib import Path
from typing import Mapping

from . import limits as _limits
from .wire import Nack

ENERGY_KINDS = ("euclidean", "torsional", "cartesian")
# Frames of eq. (22)'s pull and of the Cartesian springs' rest offsets (eqs. 18-20):
# "image" holds the rest offsets fixed in the image (the paper); "similarity" turns and
# scales them with the similarity fitted to the trackers at each spring update.
FRAMES = ("image", "similarity")


@dataclass(frozen=True)
class ParamSpec:
    name: str
    kind: type
    default: object
    lo: float | None
    hi: float | None
    unit: str
    doc: str
    choices: tuple[str, ...] = ()      # the allowed values of a str parameter


SPECS: dict[str, ParamSpec] = {s.name: s for s in [
    ParamSpec("alpha_position", float, 0.2, 0.0, 1.0, "",
              "alpha1, eq. (3): weight of a new event in the tracker mean"),
    ParamSpec("alpha_covariance", float, 2e-4, 0.0, 1.0, "",
              "alpha2, eq. (4): weight of a new event in the tracker covariance"),
    ParamSpec("p_threshold", float, 0.1, 1e-6, 0.999, "",
              "delta_p, eq. (2): accept an event if exp(-d^2/2) > delta_p"),
    ParamSpec("activity_tau_us", float, 10_000.0, 1.0, 1e9, "us",
              "tau, eq. (6): time constant of the activity decay"),
    ParamSpec("activity_threshold", float, 5.0, 0.0, 1e9, "",
              "A_up: a tracker is active while its activity exceeds this"),
    ParamSpec("energy_scale", float, 2.5, 0.0, 1e12, "",
              "s, eqs. (21)-(22): energy threshold as a multiple of the mean energy"),
    ParamSpec("energy_gain", float, 0.5, 0.0, 1.0, "",
              "alpha_en, eq. (22): pull toward the equilibrium position about G"),
    ParamSpec("spring_period", int, 55, 1, 1_000_000, "events",
              "springs and energy criteria are applied every this many events"),
    ParamSpec("energy_kind", str, "cartesian", None, None, "",
              "energy feeding eqs. (21)-(22): cartesian (each connection's offset from its "
              "rest offset in the cartesian_frame, every spring kind) | euclidean (its length) "
              "| torsional (its angle)", ENERGY_KINDS),
    ParamSpec("pull_frame", str, "similarity", None, None, "",
              "frame of eq. (22)'s rest offsets: similarity (fitted to the trackers at each "
              "spring update) | image (the paper)", FRAMES),
    ParamSpec("cartesian_frame", str, "similarity", None, None, "",
              "frame of the Cartesian springs' rest offsets, eqs. (18)-(20): similarity | "
              "image (the paper)", FRAMES),
    ParamSpec("motion_tau_us", float, 0.0, 0.0, 1e7, "us",
              "tau_m, eq. (M3): time over which a part's velocity may change by its size "
              "(a tracker's Kalman filter of position and velocity); 0: no velocity, the "
              "gain is alpha1 (the paper's eq. 3)"),
    ParamSpec("prediction_horizon_us", float, 500.0, 0.0, 1e6, "us",
              "H, eq. (M1): a mean is carried along its velocity at most this long after "
              "the tracker's last event"),
    ParamSpec("polarity_gain", float, 0.0, 0.0, 1.0, "",
              "c_h, eqs. (M6)/(M6b): weight of the half offset between a part's ON and OFF "
              "edges (relative to the mean's gain; without a velocity, of the share of it "
              "the tracker's balance of polarities supports); 0: one mean for both "
              "polarities (the paper's eq. 3)"),
    ParamSpec("sigma_min_px", float, 0.5, 0.05, 64.0, "px",
              "lower bound on a tracker's standard deviation along x and y"),
    ParamSpec("sigma_max_px", float, 64.0, 0.5, _limits.SIGMA_MAX_PX, "px",
              "upper bound on a tracker's standard deviation along x and y"),
]}


class ParamError(ValueError):
    """A parameter has an unknown name, a wrong type or an out-of-range value; ``code`` is
    the host link's NACK code for it (this class: a value out of range)."""
    code = Nack.OUT_OF_RANGE


class UnknownParamError(ParamError):
    """No parameter has that name."""
    code = Nack.UNKNOWN_NAME


class ParamTypeError(ParamError):
    """A value of the wrong type: not a number, not a whole number for a count, not a
    string for a choice."""
    code = Nack.WRONG_TYPE


@dataclass(frozen=True)
class Params:
    alpha_position: float = SPECS["alpha_position"].default
    alpha_covariance: float = SPECS["alpha_covariance"].default
    p_threshold: float = SPECS["p_threshold"].default
    activity_tau_us: float = SPECS["activity_tau_us"].default
    activity_threshold: float = SPECS["activity_threshold"].default
    energy_scale: float = SPECS["energy_scale"].default
    energy_gain: float = SPECS["energy_gain"].default
    spring_period: int = SPECS["spring_period"].default
    energy_kind: str = SPECS["energy_kind"].default
    pull_frame: str = SPECS["pull_frame"].default
    cartesian_frame: str = SPECS["cartesian_frame"].default
    motion_tau_us: float = SPECS["motion_tau_us"].default
    prediction_horizon_us: float = SPECS["prediction_horizon_us"].default
    polarity_gain: float = SPECS["polarity_gain"].default
    sigma_min_px: float = SPECS["sigma_min_px"].default
    sigma_max_px: float = SPECS["sigma_max_px"].default

    def __post_init__(self):
        for f in fields(self):
            object.__setattr__(self, f.name, check(f.name, getattr(self, f.name)))
        if self.sigma_min_px >= self.sigma_max_px:
            raise ParamError(f"sigma_min_px ({self.sigma_min_px}) must be below "
                             f"sigma_max_px ({self.sigma_max_px})")
        try:
            _limits.check_params(self)
        except _limits.LimitError as e:
            raise ParamError(str(e)) from None

    def replace(self, **changes) -> "Params":
        return Params(**{**asdict(self), **changes})

    def as_dict(self) -> dict:
        return asdict(self)

    @property
    def energy_kind_index(self) -> int:
        return ENERGY_KINDS.index(self.energy_kind)

    @property
    def pull_similarity(self) -> bool:
        """eq. (22) pulls toward the fitted similarity's rest positions."""
        return self.pull_frame == "similarity"

    @property
    def cartesian_similarity(self) -> bool:
        """eqs. (18)-(20) use the rest offsets turned and scaled by the fitted similarity."""
        return self.cartesian_frame == "similarity"

    @property
    def gate_d2(self) -> float:
        """Mahalanobis gate: exp(-d2/2) > p_threshold  <=>  d2 < -2 ln(p_threshold)."""
        return -2.0 * math.log(self.p_threshold)


def check(name: str, value, where: str = "") -> object:
    """Validate one parameter; return it converted to its type or raise ParamError."""
    ctx = f"{where}: " if where else ""
    spec = SPECS.get(name)
    if spec is None:
        raise UnknownParamError(f"{ctx}unknown parameter {name!r}; known: {', '.join(SPECS)}")
    if spec.kind is str:
        if not isinstance(value, str) or value not in spec.choices:
            err = ParamError if isinstance(value, str) else ParamTypeError
            raise err(f"{ctx}{name} must be one of {', '.join(spec.choices)}, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamTypeError(f"{ctx}{name} must be a number, got {type(value).__name__} {value!r}")
    try:
        finite = math.isfinite(value)
    except OverflowError:                      # an int too large for a float
        finite = False
    if not finite:
        raise ParamError(f"{ctx}{name} must be finite and in range, got {value!r}")
    if spec.kind is int:
        if float(value) != int(value):
            raise ParamTypeError(f"{ctx}{name} must be a whole number, got {value!r}")
        value = int(value)
    else:
        value = float(value)
    if (spec.lo is not None and value < spec.lo) or (spec.hi is not None and value > spec.hi):
        raise ParamError(f"{ctx}{name}={value!r} out of range [{spec.lo}, {spec.hi}] {spec.unit}".rstrip())
    return value


def from_mapping(values: Mapping, base: Params | None = None, where: str = "") -> Params:
    """Params from a dict (e.g. a TOML ``[params]`` table), over ``base`` or defaults."""
    base = base or Params()
    if not isinstance(values, Mapping):
        raise ParamTypeError(f"{where + ': ' if where else ''}parameters must be a table of "
                             f"names and values, got {type(values).__name__} {values!r:.40}")
    merged = base.as_dict()
    for k, v in values.items():
        merged[k] = check(k, v, where)
    try:
        return Params(**merged)
    except ParamError as e:
        raise type(e)(f"{where}: {e}" if where else str(e)) from None


def parse_toml(text, source, error: type = ParamError) -> dict:
    """TOML ``text`` (str or UTF-8 bytes) as a dict; text beyond the bounds of
    :mod:`springtrack.toml_bounds` (checked first, in linear time), invalid TOML or text
    that is not UTF-8 raise ``error`` naming ``source``."""
    import tomllib
    from . import toml_bounds
    try:
        return tomllib.loads(toml_bounds.check(text, str(source)))
    except toml_bounds.TomlBoundsError as e:
        raise error(str(e)) from None
    except UnicodeDecodeError as e:
        raise error(f"{source}: not valid TOML: not UTF-8 text: {e}") from None
    except (ValueError, RecursionError) as e:   # TOMLDecodeError, or an integer too long
        raise error(f"{source}: not valid TOML: {e}") from None


def read_toml(path, error: type = ParamError) -> dict:
    """A TOML file as a dict (see :func:`parse_toml`); a file that cannot be read raises
    ``error`` too."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror or e}") from None
    return parse_toml(data, path, error)


def tracking_table(data: Mapping) -> Mapping:
    """The tracking parameters of a parsed params TOML: its ``[params]`` table, or its top
    level without the learner's ``[learn]`` table (springtrack.learning.settings)."""
    if "params" in data:
        return data["params"]
    return {k: v for k, v in data.items() if k != "learn"}


def resolve(model, params=None) -> Params:
    """The parameters of ``model`` (anything with ``params``, its ``[params]`` table, and
    ``source``): defaults, then the model's [params], then ``params`` (Params, dict or
    TOML path; a Params is taken as it is)."""
    base = from_mapping(model.params, where=f"{model.source} [params]")
    if params is None:
        return base
    if isinstance(params, Params):
        return params
    if isinstance(params, dict):
        return from_mapping(params, base)
    if isinstance(params, (str, Path)):
        return from_mapping(tracking_table(read_toml(params)), base, where=str(params))
    raise TypeError(f"params must be Params, dict, a TOML path or None, not {type(params).__name__}")


def load(path) -> Params:
    """Read a params TOML file: either a top-level table of names or a ``[params]`` table."""
    return from_mapping(tracking_table(read_toml(path)), where=str(path))
