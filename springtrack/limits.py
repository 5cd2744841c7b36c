"""What every tracker backend can run: the kernels' capacities, and the limits a model and
its parameters must respect (derived in docs/algorithm.md, "Limits", and
docs/fixed_point.md).

One validation: :class:`springtrack.model.ShapeModel` and :class:`springtrack.params.Params`
call :func:`check_model` and :func:`check_params` when they are built, and the fixed-point
kernel's conversion (:mod:`springtrack.fixed.q`) calls the same two functions before it
converts anything; so a model or a parameter set that is accepted runs on every backend.
The capacities are mirrored by ``cdef enum`` in ``kernel/kernel.pxd`` and ``fixed/csrc/fixed_step.h``
(checked at import).
"""
from __future__ import annotations

import re

import numpy as np

from .gate import covariance_gain
from .wire import INFO_NAME_BUDGET, Nack, info_name_bytes

MAX_TRACKERS = 64
MAX_CONNECTIONS = 128
# Several model instances in one tracker (springtrack.instances, docs/acquisition.md): at
# most MAX_INSTANCES instances and MAX_SET_TRACKERS / MAX_SET_CONNECTIONS in all.
MAX_INSTANCES = 16
MAX_SET_TRACKERS = 256
MAX_SET_CONNECTIONS = 512

# Positions: the fixed kernel keeps them in Q.32 px of an int64, saturated at +-2^13 px
# (fixed/csrc/fixed_step.h FX_POS_LIM); every kernel keeps them inside that range.
POS_LIMIT_PX = 8192
# Sensor side: a sensor must fit that coordinate range.
MAX_SENSOR_PX = POS_LIMIT_PX
# sigma_max_px: the fixed kernel's covariances (Q.40 px^2 in an int64) and the products of
# its Mahalanobis distance are sized for sigma <= 64 px (docs/fixed_point.md).
SIGMA_MAX_PX = 64.0
# A model's initial covariance: every kernel clamps sigma into [sigma_min_px,
# sigma_max_px] when it loads the model; values beyond 1024 px (variance 2^20 px^2, a
# quarter of the fixed format's int64 range) are refused rather than clamped.
MODEL_SIGMA_MAX_PX = 1024.0
# Masses: 1/m is a Q7.24 uint32 in the fixed kernel (1/m < 128) and its centre-of-mass
# weights m / max(m) a Q.24 fraction (>= 2^-20 of the largest); [2^-6, 2^14] keeps both
# with a factor 2 to spare below and the 2^20 ratio above.
MASS_MIN = 2.0 ** -6
MASS_MAX = 2.0 ** 14
# Stiffness: a Q2.30 gain <= 1 in the fixed kernel.
STIFFNESS_MAX = 1.0
# The spring load of a tracker, (1/m_i) sum over its connections of kappa_k (see
# :func:`spring_loads`), at most this: the Jacobi spring update then cannot overshoot
# (docs/algorithm.md, "Limits": Gershgorin's bound on the linearised update).
SPRING_LOAD_MAX = 0.5
# eq. (4)'s gain on the bias-corrected sample, alpha_covariance / covariance_bias, is a
# Q.31 gain <= 1 in the fixed kernel: an event never weighs more than the whole estimate.
COV_GAIN_MAX = 1.0

# Tracker ids name CSV columns and telemetry fields: a safe character set, nothing a
# spreadsheet reads as a formula (no leading '=', '+', '-', '@'), no separators.
TRACKER_ID_CHARS = "letters, digits, '_', '.' and '-' (not first)"
TRACKER_ID_MAX = 32
TRACKER_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,%d}" % (TRACKER_ID_MAX - 1))

SPRING_BITS = {"euclidean": 1, "torsional": 2, "cartesian": 4}


class LimitError(ValueError):
    """A model or parameter value outside what every backend can run; the message names it."""


class NameTooLong(LimitError):
    """A model name INFO cannot carry in one frame; ``code``: the host link's NACK code."""
    code = Nack.TOO_LONG


def position_box(width: int, height: int) -> tuple[int, int, int, int]:
    """(x_lo, x_hi, y_lo, y_hi), whole px: where a tracker may be, x_lo <= x < x_hi and
    y_lo <= y < y_hi, in a model and after every spring update.  One sensor size beyond
    each border (a model half out of view, as acquisition places one at the sensor's edge,
    is valid), within the kernels' range: |x| < POS_LIMIT_PX - 1, so that a position the
    fixed kernel saturated lies outside.  Whole px, so that the fixed kernel tests the
    integer part of its Q.32 means only.  A kernel whose state leaves the box resets it
    to the model (counted)."""
    lim = POS_LIMIT_PX - 1
    return (-min(width, lim), min(2 * width, lim), -min(height, lim), min(2 * height, lim))


def spring_kappa(kinds) -> np.ndarray:
    """kappa_k / a_k per connection from its kind bits (1 Euclidean, 2 torsional, 4
    Cartesian): the largest stiffness the connection has in any one direction, in units of
    its stiffness.  Linearised, a Euclidean spring pulls along the connection, a torsional
    one across it (eq. 16 moves an end by l a dtheta, i.e. by a times its offset across),
    a Cartesian one in every direction: 1 for Euclidean and/or torsional, plus 1 for
    Cartesian."""
    kinds = np.asarray(kinds, np.int64)
    return ((kinds & 3) != 0).astype(float) + ((kinds & 4) != 0)


def spring_loads(n: int, ca, cb, kinds, stiffness, mass) -> np.ndarray:
    """rho_i = (1 / m_i) sum over tracker i's connections k of kappa_k a_k, shape (n,)."""
    k = spring_kappa(kinds) * np.asarray(stiffness, float)
    s = np.zeros(n)
    np.add.at(s, np.asarray(ca, np.int64), k)
    np.add.at(s, np.asarray(cb, np.int64), k)
    return s / np.asarray(mass, float)


def spring_scale(n: int, ca, cb, kinds, stiffness, mass, load: float = SPRING_LOAD_MAX) -> float:
    """The factor (<= 1) by which all stiffnesses must be multiplied so that no tracker's
    spring load exceeds ``load`` (a relative 1e-12 below it: the scaled loads, rounded,
    stay within it)."""
    top = spring_loads(n, ca, cb, kinds, stiffness, mass).max() if len(ca) else 0.0
    return min(1.0, load / top * (1.0 - 1e-12)) if top > 0 else 1.0


def _first(bad) -> int:
    return int(np.flatnonzero(bad)[0])


def check_name(name) -> None:
    """A model name: non-empty text without control characters that INFO can carry."""
    if not isinstance(name, str) or not name:
        raise LimitError("name must be a non-empty string")
    if any(ord(c) < 0x20 or 0x7F <= ord(c) < 0xA0 for c in name):
        raise LimitError(f"name {name[:40]!r} contains a control character")
    size = info_name_bytes(name)
    if size > INFO_NAME_BUDGET:
        raise NameTooLong(f"name of {len(name)} characters takes {size} bytes in INFO; at most "
                         f"{INFO_NAME_BUDGET} fit one frame with the rest of INFO "
                         f"(springtrack.wire.INFO_NAME_BUDGET)")


def check_model(width: int, height: int, arr: dict, ids=None) -> None:
    """The numeric limits of a model (``ShapeModel.arrays()``: x, y, mass, sxx, sxy, syy,
    ca, cb, kinds, stiffness) on a ``width`` x ``height`` sensor; raises LimitError naming
    the first entry outside them.  ``ids`` (tracker ids) only improve the messages."""
    def who(i: int) -> str:
        return f"trackers[{i}]" + (f" ({ids[i]!r})" if ids is not None else "")

    for key, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) \
                or not 1 <= v <= MAX_SENSOR_PX:
            raise LimitError(f"sensor.{key} must be an integer in [1, {MAX_SENSOR_PX}], "
                             f"got {v!r}")
    n, nc = len(arr["x"]), len(arr["ca"])
    if not 1 <= n <= MAX_TRACKERS:
        raise LimitError(f"{n} trackers: a model has 1 to {MAX_TRACKERS} (kernel capacity)")
    if nc > MAX_CONNECTIONS:
        raise LimitError(f"{nc} connections exceed the kernel capacity of {MAX_CONNECTIONS}")
    x_lo, x_hi, y_lo, y_hi = position_box(width, height)
    for key, lo, hi in (("x", x_lo, x_hi), ("y", y_lo, y_hi)):
        v = np.asarray(arr[key], float)
        bad = ~((v >= lo) & (v < hi))                        # NaN is bad too
        if bad.any():
            i = _first(bad)
            raise LimitError(f"{who(i)}: {key}={float(v[i])!r} px is outside [{lo}, {hi}), one "
                             f"sensor size around the {width}x{height} sensor")
    m = np.asarray(arr["mass"], float)
    bad = ~((m >= MASS_MIN) & (m <= MASS_MAX))
    if bad.any():
        i = _first(bad)
        raise LimitError(f"{who(i)}: mass {float(m[i])!r} is outside [{MASS_MIN:g}, {MASS_MAX:g}]")
    var_max = MODEL_SIGMA_MAX_PX * MODEL_SIGMA_MAX_PX
    sxx, sxy, syy = (np.asarray(arr[k], float) for k in ("sxx", "sxy", "syy"))
    bad = ~((sxx <= var_max) & (syy <= var_max) & np.isfinite(sxy))
    if bad.any():
        i = _first(bad)
        raise LimitError(f"{who(i)}: sigma [{float(sxx[i])!r}, {float(sxy[i])!r}, {float(syy[i])!r}] px^2 exceeds "
                         f"{var_max:g} px^2 (sigma {MODEL_SIGMA_MAX_PX:g} px); trackers are "
                         f"kept within sigma_max_px <= {SIGMA_MAX_PX:g} px anyway")
    if nc:
        a = np.asarray(arr["stiffness"], float)
        bad = ~((a >= 0.0) & (a <= STIFFNESS_MAX))
        if bad.any():
            k = _first(bad)
            raise LimitError(f"connections[{k}]: stiffness {float(a[k])!r} is outside [0, "
                             f"{STIFFNESS_MAX:g}]")
        load = spring_loads(n, arr["ca"], arr["cb"], arr["kinds"], a, m)
        if load.max() > SPRING_LOAD_MAX:
            i = int(np.argmax(load))
            raise LimitError(
                f"{who(i)}: spring load {load[i]:.4g} exceeds {SPRING_LOAD_MAX:g}: the sum over "
                f"its connections of stiffness (twice with a Cartesian spring) divided by its "
                f"mass {m[i]:g} must stay <= {SPRING_LOAD_MAX:g}, or a spring update "
                f"overshoots (docs/algorithm.md, Limits); lower those stiffnesses or raise "
                f"the mass")


def check_params(p) -> None:
    """The limits of a parameter set beyond each parameter's own range (``params.SPECS``):
    raises LimitError naming the parameters."""
    if p.sigma_max_px > SIGMA_MAX_PX:
        raise LimitError(f"sigma_max_px={p.sigma_max_px} exceeds {SIGMA_MAX_PX:g} px")
    g = covariance_gain(p)
    if not g <= COV_GAIN_MAX:
        raise LimitError(
            f"alpha_covariance={p.alpha_covariance!r} is too large for alpha_position="
            f"{p.alpha_position!r} and p_threshold={p.p_threshold!r}: eq. (4) would weigh one "
            f"event's bias-corrected sample {g:.4g} times (at most {COV_GAIN_MAX:g}); keep "
            f"alpha_covariance <= {p.alpha_covariance / g * COV_GAIN_MAX!r}")

