"""The paper's tracking error (section IV-A, IV-B) against a ground-truth CSV.

Definitions (Valeiras et al. 2015, section IV):

* error of one tracker at time t: Euclidean distance (px) between the tracker's mean and
  the true image position of its part (tracker id == part id);
* error at time t: the mean over the scored parts, as a percentage of the object's length
  L(t); the system is characterised by the temporal mean of that percentage.

Scored parts and length, computed from the truth at the matched time:

* grid (ids ``r{row}c{col}``, all 9 scored): L = grid side = mean of the six end-to-end
  distances, r{i}c0 -> r{i}c2 for the 3 rows and r0c{j} -> r2c{j} for the 3 columns
  (= 2 x spacing at rest);
* face (ids of ``face26``, only the 7 internal parts scored): L = vertical length of the
  mask, max(y) - min(y) over all 26 parts in image coordinates (``face_length="mask"``,
  the paper's Fig. 20 caption; = the face height when upright), or over the 7 internal
  parts only (``face_length="internal"``, brows to mouth, about 0.48 of the face height,
  which gives about twice the percentage).

A rigid scene's image motion scores any track, a learned model's too
(:func:`rigid_motion_error`: each tracker against where the scene's motion takes the point
it sat on at the first sample, beside standing still).

Time matching: truth is sampled every 1 ms; each track sample time is matched to the
nearest truth time (ties to the earlier one).  Track samples farther than ``max_gap_us``
(default 1000 us) from any truth time are not scored and are counted, as are parts
whose tracker position is missing (NaN) at a sample.
"""
from __future__ import annotations

import csv
import dataclasses
from dataclasses import dataclass

import numpy as np

from .model import FACE_INTERNAL, ShapeModel

GRID_IDS = [f"r{r}c{c}" for r in range(3) for c in range(3)]
GRID_SIDES = ([(f"r{i}c0", f"r{i}c2") for i in range(3)]
              + [(f"r0c{j}", f"r2c{j}") for j in range(3)])
FACE_LENGTHS = ("mask", "internal")


@dataclass
class Truth:
    t_us: np.ndarray        # (T,) int64, increasing
    ids: list               # K part ids
    xy: np.ndarray          # (T, K, 2) float64


@dataclass
class ErrorSeries:
    kind: str               # "grid" | "face"
    t_us: np.ndarray        # (n,) scored track sample times
    parts: list             # P scored part ids
    err_px: np.ndarray      # (n, P) distance tracker-part, NaN where missing
    length: np.ndarray      # (n,) object length, px
    pct: np.ndarray         # (n,) mean error over parts, % of length
    unmatched: int = 0      # track samples with no truth within max_gap_us
    missing: int = 0        # (sample, part) pairs without a tracker position

    @property
    def mean_pct(self) -> float:
        return float(np.nanmean(self.pct)) if len(self.pct) else float("nan")


def read_truth_csv(path) -> Truth:
    """Read ``t_us,part,x,y`` rows; every time must hold the same set of parts."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if header is None or [h.strip() for h in header] != ["t_us", "part", "x", "y"]:
            raise ValueError(f"{path}: not a truth CSV (expected header t_us,part,x,y)")
        rows = list(reader)
    if not rows:
        raise ValueError(f"{path}: truth CSV has a header but no rows")
    try:
        t = np.array([int(r[0]) for r in rows], np.int64)
        names = [r[1] for r in rows]
        xy = np.array([[float(r[2]), float(r[3])] for r in rows])
    except (ValueError, IndexError, OverflowError) as e:    # OverflowError: t beyond int64
        raise ValueError(f"{path}: malformed truth row: {e}") from None
    ids = list(dict.fromkeys(names))
    times = np.unique(t)
    if len(rows) != len(times) * len(ids):
        raise ValueError(f"{path}: {len(rows)} rows for {len(times)} times x {len(ids)} parts; "
                         f"every time needs one row per part")
    col = {n: i for i, n in enumerate(ids)}
    out = np.full((len(times), len(ids), 2), np.nan)
    out[np.searchsorted(times, t), [col[n] for n in names]] = xy
    if np.isnan(out).any():
        raise ValueError(f"{path}: duplicate (t_us, part) rows")
    return Truth(times, ids, out)


def truth_from_array(truth) -> Truth:
    """A :class:`Truth` from a ``springtrack.sim.sensor.TRUTH_DTYPE`` array (time-major)."""
    ids = list(dict.fromkeys(truth["part"].tolist()))
    times = np.unique(truth["t"])
    xy = np.stack([truth["x"], truth["y"]], axis=1).reshape(len(times), len(ids), 2)
    return Truth(times, ids, xy)


def object_kind(ids) -> str:
    ids = set(ids)
    if set(GRID_IDS) <= ids:
        return "grid"
    if set(FACE_INTERNAL) <= ids:
        return "face"
    raise ValueError(f"cannot score parts {sorted(ids)[:8]}...: need the 9 grid ids "
                     f"(r0c0..r2c2) or the 7 internal face ids ({', '.join(FACE_INTERNAL)})")


def scored_parts(kind: str, ids) -> list:
    return list(GRID_IDS) if kind == "grid" else list(FACE_INTERNAL)


def object_length(kind: str, ids, xy: np.ndarray, face_length: str = "mask") -> np.ndarray:
    """(T,) object length from truth positions ``xy`` (T, K, 2); see module docstring."""
    col = {n: i for i, n in enumerate(ids)}
    if kind == "grid":
        sides = [np.hypot(*(xy[:, col[a]] - xy[:, col[b]]).T) for a, b in GRID_SIDES]
        return np.mean(sides, axis=0)
    if face_length not in FACE_LENGTHS:
        raise ValueError(f"face_length must be one of {', '.join(FACE_LENGTHS)}, got {face_length!r}")
    cols = list(range(len(ids))) if face_length == "mask" else [col[p] for p in FACE_INTERNAL]
    y = xy[:, cols, 1]
    return y.max(axis=1) - y.min(axis=1)


def match_times(truth_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the nearest truth time for each t (ties to the earlier)."""
    j = np.clip(np.searchsorted(truth_t, t, side="left"), 1, max(len(truth_t) - 1, 1))
    if len(truth_t) == 1:
        return np.zeros(len(t), np.int64)
    earlier = (t - truth_t[j - 1]) <= (truth_t[j] - t)
    return np.where(earlier, j - 1, j)


def tracking_error(truth: Truth, t_us, ids, x, y, kind: str | None = None,
                   face_length: str = "mask", max_gap_us: int = 1000) -> ErrorSeries:
    """Per-sample error of a track (times ``t_us`` (n,), tracker ``ids``, positions
    ``x``, ``y`` (n, K)) against ``truth``."""
    kind = kind or object_kind(truth.ids)
    parts = scored_parts(kind, truth.ids)
    missing_ids = [p for p in parts if p not in ids]
    if missing_ids:
        raise ValueError(f"track has no tracker for part(s) {', '.join(missing_ids)} "
                         f"(tracker ids must equal the truth's part ids)")
    t_us = np.asarray(t_us, np.int64)
    j = match_times(truth.t_us, t_us)
    ok = np.abs(truth.t_us[j] - t_us) <= max_gap_us
    j, t_sel = j[ok], t_us[ok]
    tcol = [truth.ids.index(p) for p in parts]
    kcol = [list(ids).index(p) for p in parts]
    tx = np.asarray(x, float)[ok][:, kcol]
    ty = np.asarray(y, float)[ok][:, kcol]
    gt = truth.xy[j][:, tcol]                                # (n, P, 2)
    err = np.hypot(tx - gt[..., 0], ty - gt[..., 1])
    length = object_length(kind, truth.ids, truth.xy[j], face_length)
    pct = 100.0 * _nanmean_rows(err) / length
    return ErrorSeries(kind, t_sel, parts, err, length, pct, unmatched=int((~ok).sum()),
                       missing=int(np.isnan(err).sum()))


def _nanmean_rows(a: np.ndarray) -> np.ndarray:
    n = (~np.isnan(a)).sum(axis=1)
    s = np.nansum(a, axis=1)
    return np.where(n > 0, s / np.maximum(n, 1), np.nan)


@dataclass
class MotionError:
    """:func:`rigid_motion_error`'s result: per-sample errors of a track and of standing
    still (the trackers left where they were at the first sample)."""
    t_us: np.ndarray        # (n,) sample times
    err_px: np.ndarray      # (n, K) distance of each tracker from where the motion takes it
    still_px: np.ndarray    # (n, K) the same for a tracker that never moved
    length: np.ndarray      # (n,) object length, px
    pct: np.ndarray         # (n,) mean of err_px over the trackers, % of length
    still_pct: np.ndarray   # (n,) the same standing still

    @property
    def mean_pct(self) -> float:
        return float(np.nanmean(self.pct)) if len(self.pct) else float("nan")

    @property
    def still_mean_pct(self) -> float:
        return float(np.nanmean(self.still_pct)) if len(self.still_pct) else float("nan")


def rigid_motion_error(track, transform, length) -> MotionError:
    """The error of a track of a rigid scene against the scene's image motion, whatever
    the trackers sit on (a learned model's pieces of edges as well as a hand-made
    model's parts): each tracker should move as the point of the scene under it at the
    first sample does.

    ``transform(t_s)`` -> (A (2, 2), b (2,)): the scene point of rest coordinates p is
    seen at A p + b at time t_s; ``length(t_s)`` -> the object's length (px) for the
    percentage.  A tracker at m0 at the first sample t0 belongs at
    A(t) A(t0)^-1 (m0 - b(t0)) + b(t) at time t."""
    t_us = np.asarray(track.t_us, np.int64)
    x, y = np.asarray(track.x, float), np.asarray(track.y, float)
    n, k = x.shape
    err, still = np.full((n, k), np.nan), np.full((n, k), np.nan)
    lens = np.full(n, np.nan)
    if n:
        a0, b0 = transform(t_us[0] * 1e-6)
        rest = (np.column_stack([x[0], y[0]]) - b0) @ np.linalg.inv(a0).T
        for i, t in enumerate(t_us):
            a, b = transform(t * 1e-6)
            want = rest @ np.asarray(a).T + b
            err[i] = np.hypot(x[i] - want[:, 0], y[i] - want[:, 1])
            still[i] = np.hypot(x[0] - want[:, 0], y[0] - want[:, 1])
            lens[i] = length(t * 1e-6)
    return MotionError(t_us, err, still, lens, 100.0 * _nanmean_rows(err) / lens,
                       100.0 * _nanmean_rows(still) / lens)


def score_track(truth: Truth, track, **kw) -> ErrorSeries:
    """Error of a :class:`springtrack.track.Track` against ``truth``."""
    return tracking_error(truth, track.t_us, track.ids, track.x, track.y, **kw)


def named_after_parts(model: ShapeModel, truth: Truth, t_us: int):
    """A learned model scored against a simulated scene's truth: the model with each true
    part's id given to its nearest tracker at ``t_us`` (the nearest pairs first; a tracker
    no part is nearest to keeps its id), and the (trackers, parts) distances (px) there.
    A part left without a tracker makes :func:`score_track` refuse the track."""
    k = min(int(np.searchsorted(truth.t_us, t_us)), len(truth.t_us) - 1)
    gt = truth.xy[k]
    xy = np.array([(t.x, t.y) for t in model.trackers])
    d = np.hypot(xy[:, None, 0] - gt[None, :, 0], xy[:, None, 1] - gt[None, :, 1])
    names, used = {}, set()
    for i in np.argsort(d.min(axis=1)):
        part = truth.ids[int(d[i].argmin())]
        if part not in used:
            names[model.trackers[i].id] = part
            used.add(part)
    trackers = [dataclasses.replace(t, id=names.get(t.id, t.id)) for t in model.trackers]
    conns = [dataclasses.replace(c, a=names.get(c.a, c.a), b=names.get(c.b, c.b))
             for c in model.connections]
    return ShapeModel(model.name, model.width, model.height, trackers, conns, model.params), d
