"""The screen generator's renderer: opaque anti-aliased ellipses painted in order on a flat
background, then blurred by the optics.

A shape is a row ``x, y, m00, m01, m10, m11, value``: the ellipse ``{c + M u : |u| <= 1}``
(``M`` maps the unit disc onto it, so a disc of radius r is ``M = r I``) filled with the
linear intensity ``value``.  Each pixel's coverage is the area-sampling approximation
``clip(0.5 - d, 0, 1)``, ``d`` the signed distance (px) of the pixel centre to the
ellipse's rim, to first order: ``d = (rho - 1) / |grad rho|`` with ``rho = |M^-1 (p - c)|``.
Later shapes cover earlier ones (painter's order): an occluder is a shape drawn last.
"""
from __future__ import annotations

import math

import numpy as np

SHAPE_COLUMNS = 7


def shape(x: float, y: float, m, value: float) -> list:
    """One shape row from a centre, a 2x2 matrix (or a radius) and an intensity."""
    m = np.asarray(m, float) * (np.eye(2) if np.ndim(m) == 0 else 1.0)
    return [x, y, m[0, 0], m[0, 1], m[1, 0], m[1, 1], value]


def paint(img: np.ndarray, shapes: np.ndarray) -> None:
    """Paint ``shapes`` (n, 7) onto ``img`` (H, W float64, linear intensity) in order."""
    h, w = img.shape
    for x, y, a, b, c, d, value in shapes:
        det = a * d - b * c
        if not abs(det) > 1e-12:
            continue                                     # a degenerate (edge-on) ellipse
        # bounding box of c + M u, |u| <= 1: half-widths |row of M|, plus the AA margin
        hx, hy = math.hypot(a, b) + 1.0, math.hypot(c, d) + 1.0
        x0, x1 = max(0, int(math.floor(x - hx))), min(w, int(math.ceil(x + hx)) + 1)
        y0, y1 = max(0, int(math.floor(y - hy))), min(h, int(math.ceil(y + hy)) + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        px = np.arange(x0, x1, dtype=float)[None, :] - x
        py = np.arange(y0, y1, dtype=float)[:, None] - y
        # u = M^-1 (p - c)
        ux = (d * px - b * py) / det
        uy = (-c * px + a * py) / det
        rho = np.sqrt(ux * ux + uy * uy)
        # grad rho = M^-T u / rho
        gx = (d * ux - c * uy) / det
        gy = (-b * ux + a * uy) / det
        gn = np.sqrt(gx * gx + gy * gy)
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = np.where(rho > 1e-9, (rho - 1.0) * rho / np.maximum(gn, 1e-12), -1.0)
        cov = np.clip(0.5 - dist, 0.0, 1.0)
        sub = img[y0:y1, x0:x1]
        sub += cov * (value - sub)


def gaussian_taps(sigma_px: float) -> np.ndarray:
    """Normalised 1-D Gaussian kernel of standard deviation ``sigma_px`` (3 sigma wide)."""
    r = max(1, int(math.ceil(3.0 * sigma_px)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma_px) ** 2)
    return k / k.sum()


def blur(img: np.ndarray, taps: np.ndarray | None) -> np.ndarray:
    """Separable convolution with ``taps`` along both axes, edges replicated (the optics'
    point-spread function); ``None`` returns ``img``."""
    if taps is None:
        return img
    r = len(taps) // 2
    h, w = img.shape
    p = np.pad(img, ((0, 0), (r, r)), mode="edge")
    tmp = sum(t * p[:, k:k + w] for k, t in enumerate(taps))
    p = np.pad(tmp, ((r, r), (0, 0)), mode="edge")
    return sum(t * p[k:k + h, :] for k, t in enumerate(taps))


def render(shapes: np.ndarray, background: float, width: int, height: int,
           taps: np.ndarray | None) -> np.ndarray:
    """The image (H, W) the sensor receives: background, shapes painted, optics blur."""
    img = np.full((height, width), float(background))
    if len(shapes):
        paint(img, np.asarray(shapes, float).reshape(-1, SHAPE_COLUMNS))
    return blur(img, taps)
