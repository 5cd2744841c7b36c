"""Acquisition: where is a shape model in a window of events?

Given a model (its trackers' positions and covariances) and tens of milliseconds of
events, :func:`acquire` finds the similarity pose -- translation, rotation, isotropic
scale -- that places the model's trackers on the events, and says whether the model is
there at all; :func:`place` returns the model so placed, ready to track.

    >>> pose = acquire("face26", events)                        # doctest: +SKIP
    >>> pose.found, pose.tx, pose.ty, pose.angle_deg, pose.scale  # doctest: +SKIP
    >>> tracker = springtrack.Tracker(place("face26", pose))   # doctest: +SKIP

Pose
    A model point p goes to ``t + s R(angle) (p - G)``, G the model's mass-weighted centre
    of mass: (tx, ty) is where G lands (px), ``angle_deg`` the rotation from the model's
    own orientation (degrees; positive turns clockwise on screen, image y pointing down),
    ``scale`` the size relative to the model.  A tracker's covariance goes to
    ``s^2 R Sigma R^T``; the springs' rest lengths, angles and offsets follow from the
    placed positions, as for any model.

Evidence
    Events are counted per pixel over the window (polarity and time ignored); a pixel
    counts at most one more than its busiest neighbour, so that an isolated hot pixel
    counts 1 while a pixel on a moving edge, whose neighbours fire too, counts whole.  A tracker k
    placed with covariance S_k collects n_k, the count in its gate d^2 < 9 (3 sigma)
    weighted 1 up to d^2 = 4 and tapering linearly in d^2 beyond, a flat top on which a
    ring or a blob of the tracker's size counts whole (events of moving parts lie on
    their edges, not in a Gaussian).  Its background is b_k = rho_k a_k, a_k the area of
    that weight (6.5 pi sqrt|S_k|) and rho_k the density of the annulus 3 to 6 sigma
    around the tracker where the model expects nothing (outside every tracker's gate;
    if less than a fifth of it is left, not used), at least the image's background
    density (the median density of cells that hold about BG_EVENTS events each): a
    tracker inside a dense patch of clutter (an occluder's edges, texture) has a dense
    surround and little excess.  The
    tracker is *supported* when its excess n_k - b_k reaches the threshold
    KAPPA b_k + Z sqrt(b_k) + N_MIN: a contrast over the local background, a
    significance of 3 Poisson standard deviations and a floor of 3 events.  The pose's
    score is the mean over trackers of log(1 + excess / threshold), OUT_OF_VIEW for a
    tracker outside the sensor: the logarithm saturates, so a pose must explain many
    parts rather than pile onto one dense spot, and a tracker off the sensor (unknown)
    counts less than a supported one but more than one on nothing.

Found
    ``confidence`` is the fraction of in-view trackers (placed mean inside the sensor)
    that are supported; the model is *found* when ``confidence >= FOUND_FRACTION`` (0.5)
    and at least ``MIN_IN_VIEW`` (0.5) of its trackers are in view.  Background alone does
    not support half of a model's trackers at once: a tracker needs an excess of at
    least 3 standard deviations over its local background, which noise reaches with a
    probability of about 1e-3 per tracker, and half of the trackers together far more
    rarely, whatever the noise rate.  Half of a model hidden (an occluder, the sensor's
    border) still leaves it found.

Search
    Coarse to fine.  (1) Coarse: the count image summed into cells of sigma_c =
    R s_min / COARSE_DIV px (R: the model's radius about G); for each tracker size
    (levels o a factor sqrt 2 apart; tracker k at scale s reads the level of its own
    size sigma_k s) a score image log(1 + excess / threshold) of the count in a gate of
    that size (its area 2 pi o^2 times the count's density blurred by
    sqrt(o^2 + sigma_c^2)) over a background that is either the global density or the
    density blurred SURROUND times wider (two searches, whose candidates are pooled:
    the first misses nothing in clean scenes, the second is not drawn to dense clutter);
    every rotation and scale of the bounds, in steps moving the outermost tracker by
    COARSE_STEP sigma_c, and every cell of the search region is scored
    (``_acquire.score_grid``).  (2) The best distinct poses (up to ``CANDIDATES`` per
    search) are refined by annealed EM (``_acquire.refine``): each tracker's flat-top
    mean of the events in its gate, the background's share removed (none if the sensor's
    edge cuts its flat top, which would bias it), with the tracker's
    covariance widened by tau^2 and tau shrinking from sigma_c to 0; then the weighted
    similarity (Umeyama 1991, closed form in 2-D) from the model's points to those means,
    weighted by each tracker's excess and a Cauchy weight of its residual, so that
    occluded, absent or distracted parts do not pull.  (3) The ``KEEP`` best after the
    annealing go on to convergence; the one of highest score is reported with its
    support and confidence.  Each refinement (the annealing, the convergence, the pose
    at ``at_us``) replaces its start only if it scores no more than SCORE_TIE below it:
    the EM fits where the events' mass is, which on a filled, textured object lies
    inward of its outline, and can shrink a right pose into a worse one.

Bounds (parameters, with defaults): ``region`` (x0, y0, x1, y1) for G, default the whole
sensor; ``angle_deg`` (-45, 45); ``scale`` (0.6, 1.6).  The returned pose lies within them.
Cost: about 14-16 ms of CPU for a face26 in 50 ms of 300 k events/s (docs/benchmarks.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..events import EVENT_DTYPE, as_events
from ..instances import ModelSet
from ..model import ModelError, ShapeModel, TrackerSpec, load_model

KAPPA = 0.5              # support: excess >= KAPPA b + Z sqrt(b) + N_MIN over the background
Z = 3.0                  # count b in the gate: a contrast, a significance (Poisson standard
N_MIN = 3.0              # deviations) and a floor (events)
FOUND_FRACTION = 0.5     # of the in-view trackers supported
CONFIDENT = 0.7          # a find below this confidence is doubtful
BOUND_TOL = 0.01         # a pose this close to a search bound (relative scale, or
                         # this fraction of the angle range) ended at the bound
MIN_IN_VIEW = 0.5        # of all trackers in view
FLAT2 = 4.0              # tracker weight 1 within d^2 <= 4 (2 sigma), then tapering
GATE2 = 9.0              # linearly in d^2 to 0 at the gate d^2 = 9 (3 sigma)
GATE_AREA = math.pi * (FLAT2 + (GATE2 - FLAT2) / 2)   # integral of that weight / sqrt|S|
SUR2 = 36.0              # local background: the annulus 9 <= d^2 < 36 (3 to 6 sigma)
SUR_AREA = math.pi * (SUR2 - GATE2)                   # its area / sqrt|S|
MIN_SURROUND = 0.2       # of it outside the other trackers' gates, or the global density
OUT_OF_VIEW = 0.25       # score of a tracker outside the sensor: unknown
BG_EVENTS = 8.0          # background cells hold this many events on average
COARSE_DIV = 6.0         # coarse resolution sigma_c = R s_min / COARSE_DIV
COARSE_STEP = 1.5        # rotation and scale steps move the outermost tracker by this x sigma_c
SURROUNDS = (0.0, 4.0)   # coarse searches: global background; local, blurred 4x wider
CANDIDATES = 6           # distinct coarse poses refined, per coarse search
TOP_N = 128              # coarse local maxima kept before choosing distinct ones
ANNEAL = (1.0, 0.6, 0.35, 0.15)   # tau / sigma_c of the first EM iterations, then 0
KEEP = 3                 # candidates refined to convergence after the annealing
MAX_ITER = 60            # EM iterations at most after the annealing
CONVERGED_PX = 0.02      # EM stops when no tracker moves more than this
CAUCHY = 2.0             # residual scale of the robust weight, in tracker sigmas
SCORE_TIE = 0.05         # a refinement lowering the score by more is not taken
MIN_EVENTS = 20          # fewer events in the window: not found without searching

DEFAULT_ANGLE_DEG = (-45.0, 45.0)
DEFAULT_SCALE = (0.6, 1.6)


@dataclass(frozen=True)
class Pose:
    """A similarity placement of a model and the evidence for it (see module docstring)."""
    tx: float                  # px, where the model's centre of mass G lands
    ty: float
    angle_deg: float           # rotation from the model's orientation, degrees
    scale: float               # size relative to the model
    score: float = float("nan")    # mean over trackers of log(1 + excess / threshold)
    confidence: float = 0.0    # fraction of in-view trackers supported
    found: bool = False        # confidence >= FOUND_FRACTION and enough trackers in view
    supported: int = 0         # trackers supported
    in_view: int = 0           # trackers whose placed mean is inside the sensor
    events: int = 0            # events of the window inside the sensor
    doubt: str = ""            # why a find is doubtful (see :func:`with_doubt`), or ""

    @property
    def doubtful(self) -> bool:
        return self.found and bool(self.doubt)

    def __str__(self) -> str:
        verdict = ("found" if not self.doubtful else f"found, DOUBTFUL ({self.doubt})") \
            if self.found else "NOT found"
        return (f"{verdict}: tx={self.tx:.1f} ty={self.ty:.1f} angle={self.angle_deg:.1f} deg "
                f"scale={self.scale:.3f} confidence={self.confidence:.2f} "
                f"({self.supported}/{self.in_view} trackers supported, score {self.score:.2f}, "
                f"{self.events} events)")


# ---- geometry -----------------------------------------------------------------------
class _Geometry:
    """The model about its centre of mass: q (K, 2) px, covariances (K, 2, 2)."""

    def __init__(self, model: ShapeModel):
        a = model.arrays()
        m = a["mass"]
        self.g = np.array([np.sum(m * a["x"]), np.sum(m * a["y"])]) / np.sum(m)
        self.q = np.column_stack([a["x"], a["y"]]) - self.g
        self.cov = np.stack([np.stack([a["sxx"], a["sxy"]], -1),
                             np.stack([a["sxy"], a["syy"]], -1)], -2)
        det = a["sxx"] * a["syy"] - a["sxy"] ** 2
        self.sigma = det ** 0.25                      # geometric mean of the axes, px
        self.k = len(m)
        # the radius that turns a rotation or scale step into a displacement
        self.radius = max(float(np.hypot(*self.q.T).max()), 2.0 * float(self.sigma.max()))

    def means(self, tx, ty, th, s):
        c, n = math.cos(th), math.sin(th)
        q = self.q
        return (tx + s * (c * q[:, 0] - n * q[:, 1]), ty + s * (n * q[:, 0] + c * q[:, 1]))

    def covs(self, th, s):
        c, n = math.cos(th), math.sin(th)
        r = np.array([[c, -n], [n, c]])
        return (s * s) * (r @ self.cov @ r.T)


def model_pose(model) -> Pose:
    """The pose of a model as written: its centre of mass, angle 0, scale 1."""
    g = _Geometry(load_model(model)).g
    return Pose(float(g[0]), float(g[1]), 0.0, 1.0)


def place(model, pose) -> ShapeModel:
    """``model`` moved to ``pose`` (anything with tx, ty, angle_deg, scale): positions
    and covariances transformed, masses, connections and params kept."""
    model = load_model(model)
    geo = _Geometry(model)
    th = math.radians(pose.angle_deg)
    x, y = geo.means(pose.tx, pose.ty, th, pose.scale)
    cov = geo.covs(th, pose.scale)
    trackers = [TrackerSpec(t.id, float(x[k]), float(y[k]),
                            (float(cov[k, 0, 0]), float(cov[k, 0, 1]), float(cov[k, 1, 1])), t.mass)
                for k, t in enumerate(model.trackers)]
    return replace(model, trackers=trackers)


def place_checked(model, pose) -> ShapeModel | None:
    """:func:`place`, or None when the pose puts a tracker where no model may hold one
    (beyond one sensor size around the sensor, springtrack.limits): a search may find
    such a pose at its scale bound, but no backend can run it."""
    try:
        return place(model, pose)
    except ModelError:
        return None


def fit_pose(model, x, y, weights=None) -> Pose:
    """The similarity pose that best maps the model's trackers onto positions ``x``, ``y``
    (K,) in the model's tracker order (weighted least squares, Umeyama 1991)."""
    geo = _Geometry(load_model(model))
    w = np.ones(geo.k) if weights is None else np.asarray(weights, float)
    xy = np.column_stack([np.asarray(x, float), np.asarray(y, float)])
    if xy.shape != (geo.k, 2) or w.shape != (geo.k,):
        raise ValueError(f"fit_pose: need {geo.k} positions and weights, one per tracker, "
                         f"got {len(xy)} positions and {w.shape[0] if w.ndim else 0} weights")
    if not (np.all(np.isfinite(xy)) and np.all(w >= 0) and w.sum() > 0):
        raise ValueError("fit_pose: positions must be finite and weights non-negative, "
                         "not all zero")
    tx, ty, th, s = _similarity(geo.q, xy, w)
    return Pose(tx, ty, math.degrees(th), s)


def _similarity(q, m, w):
    """argmin over (t, theta, s) of sum w |m - (t + s R q)|^2; q relative to G."""
    sw = w.sum()
    qc = (w @ q) / sw
    mc = (w @ m) / sw
    dq, dm = q - qc, m - mc
    a = np.sum(w * (dq[:, 0] * dm[:, 0] + dq[:, 1] * dm[:, 1]))
    b = np.sum(w * (dq[:, 0] * dm[:, 1] - dq[:, 1] * dm[:, 0]))
    spread = float(np.sum(w * (dq ** 2).sum(1)))
    if spread <= 1e-12:
        # one tracker (or all at one point): no turn or scale to see, a translation only
        th, s = 0.0, 1.0
    else:
        th = math.atan2(b, a)
        s = math.hypot(a, b) / spread
    c, n = math.cos(th), math.sin(th)
    t = mc - s * np.array([c * qc[0] - n * qc[1], n * qc[0] + c * qc[1]])
    return float(t[0]), float(t[1]), th, s


# ---- evidence -------------------------------------------------------------------------
def count_image(events, width: int, height: int):
    """(count image (H, W) float32, hot pixels limited; events inside the sensor):
    see 'Evidence'."""
    ev = as_events(events)
    x, y = ev["x"].astype(np.int64), ev["y"].astype(np.int64)
    inside = (x < width) & (y < height)
    flat = y[inside] * width + x[inside]
    counts = np.bincount(flat, minlength=width * height).astype(np.float32)
    counts = counts.reshape(height, width)
    # a pixel counts at most one more than its busiest neighbour: an isolated hot pixel
    # counts 1, a pixel on an edge (whose neighbours fire too) counts whole
    pad = np.pad(counts, 1)
    busiest = np.zeros_like(counts)
    for dy in range(3):
        for dx in range(3):
            if dy != 1 or dx != 1:
                np.maximum(busiest, pad[dy:dy + height, dx:dx + width], out=busiest)
    np.minimum(counts, busiest + 1.0, out=counts)
    return counts, int(inside.sum())


def remove_claimed(img, claimed) -> None:
    """Zero the pixels of ``img`` inside the gates (d^2 < GATE2, 3 sigma) of the trackers
    ``claimed`` = (mx, my, sxx, sxy, syy) arrays: the events other instances explain."""
    h, w = img.shape
    for x, y, sxx, sxy, syy in zip(*(np.asarray(a, float) for a in claimed)):
        det = sxx * syy - sxy * sxy
        if not (np.isfinite(x) and np.isfinite(y) and det > 0):
            continue
        hx, hy = math.sqrt(GATE2 * sxx), math.sqrt(GATE2 * syy)
        x0, x1 = max(int(math.floor(x - hx)), 0), min(int(math.ceil(x + hx)), w - 1)
        y0, y1 = max(int(math.floor(y - hy)), 0), min(int(math.ceil(y + hy)), h - 1)
        if x0 > x1 or y0 > y1:
            continue
        dx = np.arange(x0, x1 + 1) - x
        dy = (np.arange(y0, y1 + 1) - y)[:, None]
        d2 = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det
        img[y0:y1 + 1, x0:x1 + 1][d2 < GATE2] = 0.0


def in_claimed_gates(u, claimed):
    """(n,) bool: which of the points ``u`` (n, 2) px lie inside the gates (d^2 < GATE2,
    3 sigma) of the trackers ``claimed`` = (mx, my, sxx, sxy, syy) arrays."""
    out = np.zeros(len(u), bool)
    for x, y, sxx, sxy, syy in zip(*(np.asarray(a, float) for a in claimed)):
        det = sxx * syy - sxy * sxy
        if not (np.isfinite(x) and np.isfinite(y) and det > 0):
            continue
        dx, dy = u[:, 0] - x, u[:, 1] - y
        out |= (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det < GATE2
    return out


def background_density(img) -> float:
    """Median event density of square cells, events/px^2: cells large enough to hold
    BG_EVENTS events at the image's mean density (at least 4x4 px, at most half the
    image's side), so that the median sees the background even when it is sparse."""
    h, w = img.shape
    mean = float(img.mean())
    if mean <= 0:
        return 0.0
    side = max(1, int(min(max(4.0, math.sqrt(BG_EVENTS / mean)), min(h, w) / 2)))
    ny, nx = h // side, w // side
    cells = img[:ny * side, :nx * side].reshape(ny, side, nx, side).sum((1, 3))
    return float(np.median(cells)) / side ** 2


def _threshold(b):
    """Support threshold on a tracker's excess over its background count ``b``."""
    return KAPPA * b + Z * np.sqrt(b) + N_MIN


class _Evidence:
    """Tracker evidence on one count image: the refinement and the judgement of a pose."""

    def __init__(self, geo: _Geometry, img, rho: float):
        self.geo, self.rho = geo, rho
        self.h, self.w = img.shape
        ys, xs = np.nonzero(img)                 # the image by rows of nonzero pixels
        self.sparse = (np.searchsorted(ys, np.arange(self.h + 1)).astype(np.int32),
                       np.append(xs, 0).astype(np.int32),      # one spare entry: never
                       np.append(img[ys, xs], 0).astype(np.float32), self.w)   # empty
        self.out = np.empty((geo.k, 3))
        self.sur = np.empty((geo.k, 2))
        self.mask = np.empty(img.shape, np.uint8)
        self.cov = np.ascontiguousarray(geo.cov.reshape(geo.k, 4)[:, [0, 1, 3]])
        self.scratch = np.empty((7, geo.k))

    def refine(self, pose, sig_c, lo, hi, max_iter):
        """Annealed EM from ``pose`` (tx, ty, theta, s) within [lo, hi] (see 'Search' (2))."""
        from .scoring import refine
        p = np.array(pose, float)
        refine(*self.sparse, self.geo.q, self.cov, self.geo.sigma, p, lo, hi,
               np.array(ANNEAL) * sig_c, max_iter, CONVERGED_PX, self.rho, FLAT2, GATE2,
               GATE_AREA, KAPPA, Z, N_MIN, CAUCHY, self.scratch)
        return tuple(p)

    def judge(self, tx, ty, th, s, events: int, at=None) -> Pose:
        """The pose with its score, support and found decision (module docstring);
        ``at``: (x, y) the trackers' means instead of the pose's (its covariances kept)."""
        from .scoring import moments, surround
        h, w = self.h, self.w
        mx, my = self.geo.means(tx, ty, th, s) if at is None else (
            np.ascontiguousarray(at[0], float), np.ascontiguousarray(at[1], float))
        cov = self.geo.covs(th, s)
        sxx, sxy, syy = cov[:, 0, 0].copy(), cov[:, 0, 1].copy(), cov[:, 1, 1].copy()
        moments(*self.sparse, mx, my, sxx, sxy, syy, FLAT2, GATE2, self.out)
        surround(*self.sparse, mx, my, sxx, sxy, syy, GATE2, SUR2, self.mask, self.sur)
        root_det = np.sqrt(sxx * syy - sxy * sxy)
        # the local density where the model expects nothing, if enough of it is seen
        seen = self.sur[:, 1] >= MIN_SURROUND * SUR_AREA * root_det
        local = np.where(seen, self.sur[:, 0] / np.maximum(self.sur[:, 1], 1.0), 0.0)
        b = GATE_AREA * root_det * np.maximum(self.rho, local)
        excess = np.maximum(self.out[:, 0] - b, 0.0)
        thr = _threshold(b)
        view = (mx >= 0) & (my >= 0) & (mx <= w - 1) & (my <= h - 1)
        sup = view & (excess >= thr)
        nv = int(view.sum())
        conf = float(sup.sum()) / nv if nv else 0.0
        found = conf >= FOUND_FRACTION and nv >= MIN_IN_VIEW * self.geo.k
        score = float(np.mean(np.where(view, np.log1p(excess / thr), OUT_OF_VIEW)))
        return Pose(tx, ty, math.degrees(th), s, score, conf, found, int(sup.sum()), nv, events)


# ---- search ---------------------------------------------------------------------------
def _blur_matrix(n: int, sigma_cells: float) -> np.ndarray:
    """(n, n) normalised Gaussian blur along one axis (zero outside the image)."""
    i = np.arange(n, dtype=np.float64)
    g = np.exp(-0.5 * ((i[:, None] - i[None, :]) / sigma_cells) ** 2)
    return g / (sigma_cells * math.sqrt(2 * math.pi))


def _density(cells, sigma_cells: float):
    """Cell sums blurred by a normalised Gaussian of ``sigma_cells``: events per cell."""
    ny, nx = cells.shape
    return _blur_matrix(ny, sigma_cells) @ cells @ _blur_matrix(nx, sigma_cells).T


def _coarse(geo: _Geometry, img, rho, region, angles, scales):
    """Best distinct poses (tx, ty, theta, s) of the coarse search, best first."""
    from .scoring import score_grid
    h, w = img.shape
    s_lo, s_hi = scales
    sig_c = max(1.0, geo.radius * s_lo / COARSE_DIV)
    c0 = max(1, int(round(sig_c)))
    ny_c, nx_c = -(-h // c0), -(-w // c0)
    cells = np.zeros((ny_c * c0, nx_c * c0), np.float64)
    cells[:h, :w] = img
    cells = cells.reshape(ny_c, c0, nx_c, c0).sum((1, 3))
    # poses: scales, then angles per scale, in steps moving the outermost tracker by sig_c
    poses = []
    s = s_lo
    while True:
        step = COARSE_STEP * sig_c / (geo.radius * s)
        n_th = max(1, int(math.ceil((angles[1] - angles[0]) / step)) + 1)
        poses += [(th, s) for th in np.linspace(angles[0], angles[1], n_th)]
        if s >= s_hi:
            break
        s = min(s * math.exp(step), s_hi)
    th_arr = np.array([p[0] for p in poses])
    s_arr = np.array([p[1] for p in poses])
    # levels: the tracker's own size sigma_k s, quantised to o_min * 2^(j/2) (o_min the
    # smallest at s_lo)
    own = geo.sigma[None, :] * s_arr[:, None]
    o_min = float(geo.sigma.min()) * s_lo
    lev = np.ascontiguousarray(np.maximum(np.rint(2.0 * np.log2(own / o_min)), 0),
                               dtype=np.int32)
    pad = int(math.ceil(geo.radius * s_hi / c0)) + 2
    # translation cells of the region (cell j's centre is j c0 + (c0 - 1) / 2)
    x0, y0, x1, y1 = region
    jx0 = max(0, int(math.ceil((x0 - (c0 - 1) / 2) / c0)))
    jy0 = max(0, int(math.ceil((y0 - (c0 - 1) / 2) / c0)))
    jx1 = min(nx_c, int(math.floor((x1 - (c0 - 1) / 2) / c0)) + 1)
    jy1 = min(ny_c, int(math.floor((y1 - (c0 - 1) / 2) / c0)) + 1)
    if jx1 <= jx0 or jy1 <= jy0:
        return [], sig_c
    wp = nx_c + 2 * pad
    c, n = np.cos(th_arr)[:, None], np.sin(th_arr)[:, None]
    ox = s_arr[:, None] * (c * geo.q[:, 0] - n * geo.q[:, 1])
    oy = s_arr[:, None] * (n * geo.q[:, 0] + c * geo.q[:, 1])
    cx = np.floor(((c0 - 1) / 2 + ox) / c0).astype(np.int64) + pad + jx0
    cy = np.floor(((c0 - 1) / 2 + oy) / c0).astype(np.int64) + pad + jy0
    off = np.ascontiguousarray(cy * wp + cx, dtype=np.int32)
    weight = np.full(geo.k, 1.0 / geo.k, np.float32)
    plane = np.empty((jy1 - jy0, jx1 - jx0), np.float32)
    rms_q = math.sqrt(float(np.mean((geo.q ** 2).sum(1)))) or 1.0
    chosen, placed = [], np.empty((0, geo.k, 2))
    for surround in SURROUNDS:
        levels = _levels(cells, c0, sig_c, o_min, int(lev.max()) + 1, pad, rho, surround)
        best_idx = np.zeros((TOP_N, 3), np.int32)
        best = np.full(TOP_N, -np.inf, np.float32)
        score_grid(levels, off, lev, weight, jy1 - jy0, jx1 - jx0, plane, best_idx, best)
        order = np.argsort(-best, kind="stable")
        order = order[np.isfinite(best[order])]
        p, y, x = best_idx[order].T
        tx, ty = (jx0 + x) * c0 + (c0 - 1) / 2, (jy0 + y) * c0 + (c0 - 1) / 2
        # each candidate's trackers placed, for the distance between two poses
        xy = np.stack([tx[:, None] + ox[p], ty[:, None] + oy[p]], -1)
        mine = np.empty((0, geo.k, 2))
        for i in range(len(order)):
            # distinct from this search's: RMS distance between the placed trackers beyond
            # max(2 sig_c, R s / 4); from the other search's: beyond sig_c
            far = max(2 * sig_c, 0.25 * rms_q * s_arr[p[i]]) ** 2
            if np.all(np.mean(((mine - xy[i]) ** 2).sum(-1), axis=1) > far) and \
                    np.all(np.mean(((placed - xy[i]) ** 2).sum(-1), axis=1) > sig_c ** 2):
                chosen.append((float(tx[i]), float(ty[i]), float(th_arr[p[i]]), float(s_arr[p[i]])))
                mine = np.concatenate([mine, xy[i:i + 1]])
                if len(mine) == CANDIDATES:
                    break
        placed = np.concatenate([placed, mine])
    return chosen, sig_c


def _levels(cells, c0: int, sig_c: float, o_min: float, n_lev: int, pad: int,
            rho: float, surround: float):
    """(n_lev, Hp, Wp) padded coarse score images: level j for trackers of own size
    o = o_min 2^(j/2), log(1 + excess / threshold) of the count expected in a tracker's
    gate of that size (its area 2 pi o^2 times the density of the cells blurred by
    sqrt(o^2 + sig_c^2)) over the background of the same area (the global density rho,
    or with ``surround`` > 0 the density blurred ``surround`` times wider when higher);
    OUT_OF_VIEW outside the sensor.  The area is the tracker's own, not the blur's: a
    gate no larger than a coarse cell would make a shrunk model's trackers collect as
    many events as full-sized ones, and pile onto the densest events."""
    ny_c, nx_c = cells.shape
    levels = np.full((n_lev, ny_c + 2 * pad, nx_c + 2 * pad), OUT_OF_VIEW, np.float32)
    for j in range(n_lev):
        o = o_min * 2.0 ** (j / 2)
        sig = math.hypot(o, sig_c)
        area = 2 * math.pi * o * o
        b = area * rho
        if surround:
            b = area * np.maximum(rho, _density(cells, sig / c0 * surround) / (c0 * c0))
        excess = np.maximum(area * _density(cells, sig / c0) / (c0 * c0) - b, 0.0)
        levels[j, pad:pad + ny_c, pad:pad + nx_c] = np.log1p(excess / _threshold(b))
    return levels


def acquire(model, events, *, region=None, angle_deg=DEFAULT_ANGLE_DEG, scale=DEFAULT_SCALE,
            width: int | None = None, height: int | None = None,
            at_us: int | None = None, claimed=None) -> Pose:
    """Find ``model`` (ShapeModel, preset name or TOML path) in ``events`` (a window of
    tens of ms, fields t, x, y, p, in time order).

    ``region``: (x0, y0, x1, y1) px where the model's centre of mass may lie (default:
    the sensor); ``angle_deg``: (lo, hi) rotation range from the model's orientation;
    ``scale``: (lo, hi) size range relative to the model; ``width``, ``height``: the
    sensor (default: the model's).  Returns the best :class:`Pose`; ``found`` says
    whether the model is there (see the module docstring for the rule).

    The pose found explains the whole window; a moving object is where it was around
    the window's middle.  ``at_us``: the pose at that time instead -- refined again on
    the quarter of the window's events nearest to it (its score, support and decision
    stay those of the whole window).  A tracker that starts on the window's first event
    wants ``at_us`` = that event's time: it does not pull a model placed a pixel or two
    off its parts back onto them.

    ``claimed``: (mx, my, sxx, sxy, syy) arrays of trackers whose events are explained
    already (other instances'): the pixels inside their 3-sigma gates do not count.
    """
    model = load_model(model)
    w, h = int(width or model.width), int(height or model.height)
    region = (0.0, 0.0, w - 1.0, h - 1.0) if region is None else tuple(map(float, region))
    angles = tuple(math.radians(float(a)) for a in angle_deg)
    scales = tuple(map(float, scale))
    if len(region) != 4 or not region[0] <= region[2] or not region[1] <= region[3]:
        raise ValueError(f"acquire: region must be (x0, y0, x1, y1) with x0 <= x1, y0 <= y1, "
                         f"got {region}")
    if len(angles) != 2 or not -math.pi <= angles[0] <= angles[1] <= math.pi:
        raise ValueError(f"acquire: angle_deg must be (lo, hi) with -180 <= lo <= hi <= 180, "
                         f"got {tuple(angle_deg)}")
    if len(scales) != 2 or not 0 < scales[0] <= scales[1] or not math.isfinite(scales[1]):
        raise ValueError(f"acquire: scale must be (lo, hi) with 0 < lo <= hi, got {tuple(scale)}")
    img, n_ev = _evidence_image(events, w, h, claimed)
    geo = _Geometry(model)
    if n_ev < MIN_EVENTS:
        g = geo.g
        return Pose(float(g[0]), float(g[1]), 0.0, 1.0, 0.0, 0.0, False, 0, 0, n_ev)
    rho = background_density(img)
    ev = _Evidence(geo, img, rho)
    cands, sig_c = _coarse(geo, img, rho, region, angles, scales)
    lo = np.array([region[0], region[1], angles[0], scales[0]])
    hi = np.array([region[2], region[3], angles[1], scales[1]])
    # the pose the model is written at joins the candidates: a model drawn on, or learned
    # from, the scene it is tracked in is often where it says; the coarse grid, whose
    # cells grow with the model's extent, can miss a wide model of small parts there
    home = (float(geo.g[0]), float(geo.g[1]), 0.0, 1.0)
    if np.all(np.array(home) >= lo) and np.all(np.array(home) <= hi) and home not in cands:
        cands = [*cands, home]
    if not cands:
        g = geo.g
        return Pose(float(g[0]), float(g[1]), 0.0, 1.0, 0.0, 0.0, False, 0, 0, n_ev)
    # every candidate through the annealing, the best few on to convergence; a refined
    # pose replaces its start only if it scores within SCORE_TIE of it, so the pose
    # returned is the best one judged, within that tie
    start = [_better(ev.judge(*c, n_ev), ev.judge(*ev.refine(c, sig_c, lo, hi,
                                                              len(ANNEAL) + 2), n_ev))
             for c in cands]
    kept = sorted(start, key=lambda p: p.score, reverse=True)[:KEEP]
    final = [_better(p, ev.judge(*ev.refine(_params(p), 0.0, lo, hi, MAX_ITER), n_ev))
             for p in kept]
    best = with_doubt(max(final, key=lambda p: p.score), angles, scales)
    if at_us is None:
        return best
    evs = as_events(events)
    near = np.argsort(np.abs(evs["t"] - int(at_us)), kind="stable")[:max(len(evs) // 4, 1)]
    img_at, _ = _evidence_image(evs[np.sort(near)], w, h, claimed)
    ev_at = _Evidence(geo, img_at, background_density(img_at))
    mid = np.array(_params(best))
    q = np.array(ev_at.refine(tuple(mid), 0.0, lo, hi, MAX_ITER))
    if ev_at.judge(*q, n_ev).score < ev_at.judge(*mid, n_ev).score - SCORE_TIE:
        return best                  # the refinement on those events lowered the score
    # the refined pose holds at the mean time of the events it saw (t_q), the window's
    # pose at the mean of all (t_m): carry the motion between them on to at_us,
    # pose(at) = q + (q - mid) (at - t_q) / (t_q - t_m)
    t_q = float(np.mean(evs["t"][near]))
    t_m = float(np.mean(evs["t"]))
    if abs(t_q - t_m) > 0:
        f = (int(at_us) - t_q) / (t_q - t_m)
        if 0 < f <= 1:
            q = np.clip(q + (q - mid) * f, lo, hi)
    tx, ty, th, s = (float(v) for v in q)
    return with_doubt(replace(best, tx=tx, ty=ty, angle_deg=math.degrees(th), scale=s,
                              doubt=""), angles, scales)


def with_doubt(pose: Pose, angles, scales) -> Pose:
    """``pose`` with its ``doubt`` said when it was found but the search ended at one of
    its bounds (the object may lie beyond it: another scale or turn than searched) or
    its confidence is below CONFIDENT (fewer than 70 % of the in-view trackers
    supported: part of the model, or another object, may have been matched)."""
    if not pose.found:
        return pose
    why = []
    for lo_hi, v, name in ((scales, pose.scale, "scale"),):
        for b in lo_hi:
            if abs(v - b) <= BOUND_TOL * b:
                why.append(f"{name} {v:.3f} at the search bound {b:g}")
    span = angles[1] - angles[0]
    if span < 2 * math.pi - 1e-9:
        a = math.radians(pose.angle_deg)
        for b in angles:
            if abs(a - b) <= BOUND_TOL * span:
                why.append(f"angle {pose.angle_deg:.1f} deg at the search bound "
                           f"{math.degrees(b):g}")
    if pose.confidence < CONFIDENT:
        why.append(f"confidence {pose.confidence:.2f} < {CONFIDENT}")
    return replace(pose, doubt="; ".join(why)) if why else pose


def _params(pose: Pose) -> tuple:
    """(tx, ty, theta, s) of a pose, as the refinement takes it."""
    return pose.tx, pose.ty, math.radians(pose.angle_deg), pose.scale


def _better(start: Pose, refined: Pose) -> Pose:
    """The refined pose unless it scores lower than its start by more than SCORE_TIE
    (the judge's flat top: a pose a few px off can score a hair higher than the EM's
    precise fit), else the start."""
    return refined if refined.score >= start.score - SCORE_TIE else start


def judge(model, events, pose, *, width: int | None = None, height: int | None = None,
          claimed=None, at=None) -> Pose:
    """``pose`` (anything with tx, ty, angle_deg, scale; e.g. :func:`fit_pose` of a
    tracker's current positions) judged on ``events`` as :func:`acquire` judges the pose
    it finds: its score, support, confidence and found decision, no search.  ``at``:
    (x, y) arrays of the trackers' positions as they are (a deformed or perspective view
    that no similarity fits), judged there with the pose's covariances."""
    model = load_model(model)
    w, h = int(width or model.width), int(height or model.height)
    img, n_ev = _evidence_image(events, w, h, claimed)
    ev = _Evidence(_Geometry(model), img, background_density(img))
    return ev.judge(float(pose.tx), float(pose.ty), math.radians(pose.angle_deg),
                    float(pose.scale), n_ev, at)


def _evidence_image(events, w: int, h: int, claimed):
    """The count image of ``events`` with the ``claimed`` gates' pixels removed, and the
    number of events inside the sensor."""
    img, n_ev = count_image(events, w, h)
    if claimed is not None:
        remove_claimed(img, claimed)
    return img, n_ev


class Acquisition:
    """Acquisition on a stream: buffers events until ``window_us`` of them are in, runs
    :func:`acquire` on that window for each instance of ``models`` (a model, or a
    ``springtrack.instances.ModelSet``: each instance found explains its events away
    before the next is searched), and when none is found slides by half a window and tries
    again.  Memory: the events of one window plus the chunk fed.

    :meth:`feed` returns ``None`` while acquiring, then, once an instance is found, every
    buffered event (the window and what followed it) for the tracker to process from the
    window's start; :attr:`poses` are the poses found (one per instance; ``found`` False
    for one not found), :attr:`pose` the first instance's.  :attr:`attempts` counts the
    windows tried, :attr:`events_dropped` the events that slid out of the window unfound
    (their times wait in :meth:`take_dropped`, for the caller's rows of the search).

    ``budget_us``: the search budget in µs of event time from the first event; once a
    window ending past it is tried in vain, or at :meth:`finish`, the search is
    :attr:`exhausted` (the instances are *not found*): later events are dropped unsearched.
    None: search until the input ends.
    """

    def __init__(self, models, window_us: int = 50_000, budget_us: int | None = None,
                 **bounds):
        window_us = int(window_us)
        if window_us <= 0:
            raise ValueError(f"acquisition window must be a positive number of µs, got {window_us}")
        if budget_us is not None and int(budget_us) <= 0:
            raise ValueError(f"acquisition budget must be a positive number of µs, got {budget_us}")
        self.models = models if isinstance(models, ModelSet) else ModelSet(models)
        self.window_us, self.bounds = window_us, bounds
        self.budget_us = None if budget_us is None else int(budget_us)
        self.poses: list = [None] * len(self.models)
        self.attempts = 0
        self.events_dropped = 0
        self.exhausted = False          # the budget is spent (or the input ended) unfound
        self._first_t: int | None = None
        self._buf: list[np.ndarray] = []
        self._dropped: list[np.ndarray] = []     # times of the events let go, not yet taken

    @property
    def model(self) -> ShapeModel:
        return self.models[0].model

    @property
    def pose(self) -> Pose | None:
        return self.poses[0]

    @property
    def done(self) -> bool:
        return any(p is not None and p.found for p in self.poses)

    def feed(self, events):
        """Add events (in time order); the buffered events once an instance is found."""
        ev = as_events(events)
        if not len(ev):
            return None
        if self.exhausted:
            self._drop(ev["t"])
            return None
        if self._first_t is None:
            self._first_t = int(ev["t"][0])
        self._buf.append(ev)
        # the buffer is joined only when it spans a window (cheap for chunks of any size)
        while self._buf and int(self._buf[-1]["t"][-1]) - int(self._buf[0]["t"][0]) \
                >= self.window_us:
            buf = self._joined()
            t0 = int(buf["t"][0])
            found = self._try(buf[:int(np.searchsorted(buf["t"], t0 + self.window_us))])
            if found is not None:
                return found
            if self.budget_us is not None and \
                    t0 + self.window_us - self._first_t >= self.budget_us:
                self.exhausted = True
                self._drop(buf["t"])
                self._buf = []
                break
            cut = max(int(np.searchsorted(buf["t"], t0 + self.window_us // 2)), 1)
            self._drop(buf["t"][:cut])
            self._buf = [buf[cut:]] if cut < len(buf) else []
        return None

    def _drop(self, t) -> None:
        """Let events go unfound (their times kept for :meth:`take_dropped`)."""
        self.events_dropped += len(t)
        self._dropped.append(np.array(t, np.int64))

    @property
    def first_kept_t(self) -> int | None:
        """The time of the first event still buffered, None when none is."""
        return int(self._buf[0]["t"][0]) if self._buf else None

    def take_dropped(self) -> np.ndarray:
        """The times of the events let go since the last call (int64, in order)."""
        out = np.concatenate(self._dropped) if self._dropped else np.empty(0, np.int64)
        self._dropped = []
        return out

    def finish(self):
        """End of input: try once on what is buffered (shorter than a window); the
        buffered events if found, else ``None`` (they are counted as dropped)."""
        if not self._buf:
            self.exhausted = not self.done
            return None
        buf = self._joined()
        found = self._try(buf)
        if found is None:
            self._drop(buf["t"])
            self._buf = []
            self.exhausted = True
        return found

    def _joined(self):
        """The buffer as one array (kept so)."""
        if len(self._buf) > 1:
            self._buf = [np.concatenate(self._buf, dtype=EVENT_DTYPE)]
        return self._buf[0]

    def _try(self, window):
        self.attempts += 1
        self.poses = acquire_all(self.models.models, window, at_us=int(window["t"][0]),
                                 **self.bounds)
        if not self.done:
            return None
        out = self._joined()
        self._buf = []
        return out


def acquire_all(models, events, claimed=None, **kw) -> list:
    """:func:`acquire` for each model in turn on the same ``events``; each one found
    claims its trackers' gates (explaining its events away) before the next search.
    ``claimed``: gates claimed from the start (as for :func:`acquire`)."""
    poses = []
    gates = [np.asarray(a, float) for a in claimed] if claimed is not None else None
    for m in models:
        pose = acquire(m, events, claimed=gates, **kw)
        poses.append(pose)
        if pose.found:
            gates = _join_gates(gates, placed_gates(m, pose))
    return poses


def placed_gates(model, pose) -> tuple:
    """(mx, my, sxx, sxy, syy) of ``model``'s trackers placed at ``pose``."""
    a = place(model, pose).arrays()
    return tuple(a[k] for k in ("x", "y", "sxx", "sxy", "syy"))


def _join_gates(a, b):
    if a is None:
        return [np.asarray(v, float) for v in b]
    return [np.concatenate([u, np.asarray(v, float)]) for u, v in zip(a, b)]
