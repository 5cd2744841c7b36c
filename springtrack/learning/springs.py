"""Springs from co-activation: neighbours (relative neighbourhood graph), co-activity,
the object's frame and each pair's rigidity."""
from __future__ import annotations

import math

import numpy as np

from .settings import LearnParams, LearnedSpring, MIN_SAMPLES


# ---- springs ----------------------------------------------------------------------------
def relative_neighbours(d: np.ndarray, within: float = math.inf, slack: float = 0.0):
    """Pairs (i, j), i < j, of the relative neighbourhood graph of points with distances
    ``d`` (n, n) that are nearer than ``within``: i-j unless some k is nearer to both
    (max(d_ik, d_jk) < (1 - slack) d_ij).  Local, planar, connected (without ``within``),
    and without a square's diagonals.  Returns two index arrays."""
    i, j = np.nonzero(np.triu(d < within, 1))
    far = np.maximum(d[i], d[j])                           # [pair, k] = max(d_ik, d_jk)
    keep = ~(far < (1.0 - slack) * d[i, j][:, None]).any(axis=1)
    return i[keep], j[keep]


def neighbour_pairs(x: np.ndarray, y: np.ndarray, k: int = 3, slack: float = 0.05) -> list:
    """Pairs (i < j) of neighbours among the points (x, y): the relative neighbourhood
    graph (connected, local), and each point's ``k`` nearest."""
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    i, j = relative_neighbours(d, slack=slack)
    pairs = set(zip(i.tolist(), j.tolist()))
    order = np.argsort(d, axis=1, kind="stable")[:, 1:k + 1]
    for a in range(len(x)):
        for b in order[a].tolist():
            pairs.add((min(a, b), max(a, b)))
    return sorted(pairs)


def coactivation(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised inner product of two activity traces (eq. 6, sampled together): 1 for
    trackers active in proportion at the same times, 0 for never at the same time."""
    norm = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / norm if norm > 0 else 0.0


def object_similarity(x: np.ndarray, y: np.ndarray, w: np.ndarray, x_ref, y_ref) -> np.ndarray:
    """(T,) complex ``a = s e^(i phi)`` of the similarity that best maps the reference
    positions (N,) onto the point set at each sample (2-D Procrustes about the centroids,
    weights ``w`` (T, N), 0 where a point is missing; x, y are ignored there): a
    reference offset ``d0`` (complex) appears at each sample as ``a d0``.  0 where fewer
    than two points exist."""
    z = np.where(w > 0, x + 1j * y, 0.0)
    ref = x_ref + 1j * y_ref
    ws = np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    zc = z - (w * z).sum(axis=1, keepdims=True) / ws
    rc = ref[None, :] - (w * ref[None, :]).sum(axis=1, keepdims=True) / ws
    den = (w * np.abs(rc) ** 2).sum(axis=1)
    return np.where(den > 0, (w * zc * np.conj(rc)).sum(axis=1) / np.maximum(den, 1e-300), 0.0)


def object_rotation(x: np.ndarray, y: np.ndarray, w: np.ndarray, x_ref, y_ref) -> np.ndarray:
    """(T,) rotation (rad) of the point set at each sample from the reference positions:
    the angle of :func:`object_similarity`."""
    return np.angle(object_similarity(x, y, w, x_ref, y_ref))


def object_turn(X, Y, valid, pairs, x_end, y_end, smooth: int) -> float:
    """The object's in-plane turn over the samples (deg): the range of the mean change of
    direction of the pairs (i, j) from their final direction (eq. 15's mean torsional
    elongation), averaged over ``smooth`` samples.  A perspective change turns some
    directions one way and others the other way, which the mean cancels."""
    if not pairs:
        return 0.0
    a = np.array([p[0] for p in pairs])
    b = np.array([p[1] for p in pairs])
    ang = np.arctan2(Y[:, b] - Y[:, a], X[:, b] - X[:, a])
    ang0 = np.arctan2(y_end[b] - y_end[a], x_end[b] - x_end[a])
    both = valid[:, a] & valid[:, b]
    d = np.where(both, np.exp(1j * (ang - ang0)), 0.0)          # unit changes of direction
    mean = d.sum(axis=1)
    ok = both.any(axis=1)
    m = len(mean) // smooth * smooth
    if m < smooth:
        return 0.0
    sm = (mean[:m] * ok[:m]).reshape(-1, smooth).sum(axis=1)
    sm = sm[np.abs(sm) > 0]
    if not len(sm):
        return 0.0
    return float(np.degrees(np.ptp(np.unwrap(np.angle(sm)))))


def rigidity(deform_px: float, size_px: float, scale: float) -> float:
    """1 / (1 + (e / scale)^2) with e the pair's deformation in part sizes."""
    e = deform_px / max(size_px, 1e-9)
    return 1.0 / (1.0 + (e / scale) ** 2)


def _springs(rec: dict, sig: np.ndarray, lp: LearnParams, x_end, y_end):
    """The candidate springs, neighbours of the relative neighbourhood graph of the final
    positions, each with its evidence over the samples where both ends existed:
    co-activation, rigidity (the spread of the relative position in the object's frame,
    in part sizes ``sig``) and turn (the range of the direction of the relative position,
    averaged over ``smooth_us``, or the object's (:func:`object_turn`) if larger: a short
    history does not prove that nothing turned), hence its kinds."""
    act, X, Y, valid = rec["act"], rec["x"], rec["y"], rec["valid"]
    w = activity_weights(rec)
    phi = object_rotation(X, Y, w, x_end, y_end)
    c, s = np.cos(-phi), np.sin(-phi)
    nsm = max(1, int(round(lp.smooth_us / lp.batch_us)))
    pairs = neighbour_pairs(x_end, y_end)
    turned = object_turn(X, Y, valid, pairs, x_end, y_end, nsm)
    out = []
    for i, j in pairs:
        both = valid[:, i] & valid[:, j]
        wk = np.minimum(w[:, i], w[:, j])[both]
        if len(wk) < MIN_SAMPLES or wk.sum() <= 0:
            out.append(LearnedSpring(i, j, 0.0, 0.0, 0.0, ()))
            continue
        co = coactivation(act[both, i], act[both, j])
        rx, ry = (X[:, j] - X[:, i])[both], (Y[:, j] - Y[:, i])[both]
        # in the object's frame: undo each sample's rotation from the final positions
        ox, oy = c[both] * rx - s[both] * ry, s[both] * rx + c[both] * ry
        mx, my = np.average(ox, weights=wk), np.average(oy, weights=wk)
        deform = math.sqrt(np.average((ox - mx) ** 2 + (oy - my) ** 2, weights=wk))
        rig = rigidity(deform, 0.5 * (sig[i] + sig[j]), lp.rigidity_scale)
        # turn: range of the direction of the smoothed relative position
        m = len(rx) // nsm * nsm
        turn = 0.0
        if m >= nsm:
            wb = wk[:m].reshape(-1, nsm).sum(axis=1)
            bx = (rx[:m] * wk[:m]).reshape(-1, nsm).sum(axis=1)
            by = (ry[:m] * wk[:m]).reshape(-1, nsm).sum(axis=1)
            ang = np.unwrap(np.arctan2(by[wb > 0], bx[wb > 0]))
            if len(ang):
                turn = float(np.degrees(ang.max() - ang.min()))
        turn = max(turn, turned)
        kinds = ("cartesian",) if turn < lp.cartesian_turn_deg else ("euclidean", "torsional")
        out.append(LearnedSpring(i, j, co, rig, turn, kinds))
    return out


def activity_weights(rec: dict) -> np.ndarray:
    """(T, N) each sample's weight: the tracker's activity (eq. 6) over its largest, 0
    where it did not exist: a tracker counts where it follows its part."""
    act, valid = rec["act"], rec["valid"]
    return np.where(valid, act / np.maximum(act.max(axis=0, keepdims=True), 1e-12), 0.0)
