"""The gate of eq. (2) seen from eqs. (4)-(5): what a Mahalanobis gate keeps of a blob's
covariance, and the bound on a covariance's correlation.

Shared by the specification (springtrack.reference), the kernels, the limits of a
parameter set (springtrack.limits), the placement spread and the learner; it imports
nothing of the package, so every one of them can.
"""
from __future__ import annotations

import math

RHO_MAX = 0.99           # |correlation| bound that keeps a covariance positive definite


def truncation_factor(h: float) -> float:
    """kappa(h) = E[x^2 | r^2 < h] for a standard 2-D normal: the per-axis variance kept
    by a Mahalanobis gate of squared radius h (r^2 is chi-square with 2 dof)."""
    e = math.exp(-0.5 * h)
    return (2.0 - (h + 2.0) * e) / (2.0 * (1.0 - e))


def covariance_bias(alpha_position: float, gate_d2: float) -> float:
    """Expected ratio of the gated sample covariance of eq. (5) to the true blob covariance.

    The event offset e = u - mu (pre-update mean) has covariance (1 + J) C, where
    J = a1 / (2 - a1) is the stationary variance of the mean of eq. (3) (an exponential
    moving average) in units of C.  The gate keeps |w|^2 < g with w whitened by C, so the
    expected sample is C (1 + J) kappa(g / (1 + J)).  Dividing the sample by this factor
    makes Sigma = C the fixed point of eq. (4)."""
    j = alpha_position / (2.0 - alpha_position)
    return (1.0 + j) * truncation_factor(gate_d2 / (1.0 + j))


def covariance_gain(p) -> float:
    """alpha_covariance / covariance_bias: eq. (4)'s weight of a bias-corrected sample
    (``p`` a Params)."""
    return p.alpha_covariance / covariance_bias(p.alpha_position, p.gate_d2)
