"""The discovery pass over the learning window: batches through the pool, the record of
each tracker (``History``), and the choice of the final set (``trackers=N``)."""
from __future__ import annotations

import contextlib
import math
import warnings

import numpy as np

from .edges import bends, facing_pairs
from .outlines import Outlines
from .pool import BirthField, Pool, contrast_sign, union_series
from .settings import F, LEVEL_EVERY
from .springs import relative_neighbours


# ---- the passes -------------------------------------------------------------------------
SERIES = ("x", "y", "act", "cnt", "valid")     # a tracker's samples in History.series

# Empty batches in a row after which the rest of a pause is skipped: the pool's decay is
# exact over any time step (Pool.decay), so a long pause costs no more than this many
# batches (and History rows): time and memory follow the events, not the time span.
MAX_IDLE_BATCHES = 1000


def _batches(ev: np.ndarray, t0: int, t1: int, step: int):
    """(t_end, slice) per batch of ``step`` µs covering [t0, t1], the batch ends on the
    grid t0 + k step; after ``MAX_IDLE_BATCHES`` empty batches in a row the grid jumps to
    the batch of the next event."""
    t = ev["t"]
    n = len(t)
    te, lo, idle = t0 + step, 0, 0
    while te <= t1 + step:
        hi = int(np.searchsorted(t, te, side="left"))
        yield te, slice(lo, hi)
        idle = idle + 1 if hi == lo else 0
        lo = hi
        if idle >= MAX_IDLE_BATCHES:
            if hi >= n:
                return
            te = t0 + step * ((int(t[hi]) - t0) // step)    # the next event's batch is next
            idle = 0
        te += step


class History:
    """What the pool did, batch by batch: each tracker's identity (uid), position,
    activity (eq. 6) and events taken, sampled after the batch ran and before the
    lifecycle acted on it; with the pool's ``lineage`` (merges), a merged tracker's past
    is its pieces' (see :meth:`series`)."""

    def __init__(self):
        self.rows = []

    def record(self, t: int, pool: Pool, cnt: np.ndarray) -> None:
        n = pool.n
        self.rows.append((t, pool.book["uid"][:n].astype(np.int64), pool.x.copy(),
                          pool.y.copy(), pool.activity(t), cnt[:n].astype(float)))

    def series(self, uids, lineage: dict) -> dict:
        """The samples of the trackers ``uids`` (N,): ``t`` (T,), ``x``, ``y``, ``act``,
        ``cnt`` (T, N) and ``valid`` (T, N) (elsewhere x, y are NaN, act and cnt 0).
        Before a tracker got its identity by merging two (``lineage``: uid -> (uid_a,
        w_a, uid_b, w_b)), its samples are those of the union of both pieces
        (:func:`union_series`)."""
        T = len(self.rows)
        where = {}                                    # uid -> (rows, places in them)
        for r, row in enumerate(self.rows):
            for i, u in enumerate(row[1].tolist()):
                where.setdefault(u, ([], []))
                where[u][0].append(r)
                where[u][1].append(i)
        done = {}

        def own(u):
            x, y = np.full(T, np.nan), np.full(T, np.nan)
            act, cnt, ok = np.zeros(T), np.zeros(T), np.zeros(T, bool)
            for r, i in zip(*where.get(u, ((), ()))):
                row = self.rows[r]
                x[r], y[r], act[r], cnt[r], ok[r] = row[2][i], row[3][i], row[4][i], row[5][i], True
            return x, y, act, cnt, ok

        def get(u):
            if u in done:
                return done[u]
            mine = own(u)
            if u in lineage:
                ua, wa, ub, wb = lineage[u]
                first = int(np.argmax(mine[4])) if mine[4].any() else T
                union = union_series(get(ua), wa, get(ub), wb, first)
                mine = tuple(np.where(mine[4], m, un) for m, un in zip(mine, union))
            done[u] = mine
            return done[u]

        cols = [get(int(u)) for u in uids]
        out = {"t": np.array([r[0] for r in self.rows], np.int64)}
        for k, name in enumerate(SERIES):
            out[name] = (np.stack([c[k] for c in cols], axis=1) if cols else
                         np.zeros((T, 0), bool if name == "valid" else float))
        return out


def _discover(pool: Pool, ev: np.ndarray, t0: int, t1: int, stats: dict) -> History:
    """Pass 1: the pool with births, merges and deaths, every ``batch_us``; returns its
    history."""
    lp = pool.lp
    births = BirthField(lp, pool.width, pool.height)
    outlines = Outlines(pool.width, pool.height)
    pool.contrast = contrast_sign(ev, pool.width, pool.height)
    prev = t0
    history = History()
    for k, (te, sl) in enumerate(_batches(ev, t0, t1, lp.batch_us)):
        batch = ev[sl]
        pool.decay(te - prev)
        births.decay(te - prev)
        prev = te
        cnt = np.zeros(pool.n)
        if len(batch):
            w = pool.run(batch)
            births.add(batch[w == -1])
            cnt = np.bincount(w[w >= 0], minlength=pool.n)
        history.record(te, pool, cnt)
        if k % LEVEL_EVERY == 0:
            pool.update_level()
            births.update_noise()
            if len(batch) and lp.outline_cover > 0:
                # the parts' outlines among the pixels that fired over the trackers' memory
                ok = outlines.find(pool.last, te - int(lp.life_tau_us), lp.sigma_max_px,
                                   lp.outline_cover)
                pool.book["outline"][:pool.n] = outlines.of_trackers(ok, batch, w, pool.x, pool.y)
        while pool.n > 1:
            pair = _merge_candidate(pool)
            if pair is None:
                break
            i, j, outline = pair
            pool.merge(i, j, te)
            stats["merged"] += 1
            stats["outline_merged"] += outline
        dead = _dying(pool, births, te)
        if dead.any():
            stats["died"] += int(dead.sum())
            pool.keep(~dead)
        for mu, cov in births.births():
            if pool.add(mu, cov, te):
                stats["born"] += 1
            else:
                stats["birth_refused_full"] += 1
    return history


def _merge_candidate(pool: Pool):
    """The pair to merge now (i, j, whether by the outline rule), or None, with its union
    no wider than a part may be:
    trackers that share their events and one holds the other's mean (duplicates on one
    cloud), the most sharing first; or neighbours joined by covered pixels (two edges,
    or two pieces, of one part: Pool.gaps), the nearest first; or two pieces on one
    part's outline (learning.outlines), the nearest first."""
    lp = pool.lp
    n = pool.n
    share = pool.overlap_score()
    dup = (share >= lp.merge_overlap) & pool.nested()
    for flat in np.argsort(-share, axis=None, kind="stable"):
        i, j = divmod(int(flat), n)
        if not dup[i, j]:
            break
        if pool.union_fits(i, j):
            return i, j, False
    if pool.contrast and n > 1:
        d = np.hypot(pool.x[:, None] - pool.x[None, :], pool.y[:, None] - pool.y[None, :])
        i, j = relative_neighbours(d, within=2.0 * lp.sigma_max_px)
        joined = pool.gaps(i, j) < lp.merge_gap_px
        i, j = i[joined], j[joined]
        for k in np.argsort(d[i, j], kind="stable"):
            if pool.union_fits(i[k], j[k]):
                return int(i[k]), int(j[k]), False
    on = pool.book["outline"][:n]
    if (on > 0).sum() > 1:
        same = (on[:, None] == on[None, :]) & (on[:, None] > 0)
        i, j = np.nonzero(np.triu(same, 1))
        d = np.hypot(pool.x[i] - pool.x[j], pool.y[i] - pool.y[j])
        for k in np.argsort(d, kind="stable"):
            if pool.union_fits(i[k], j[k]):
                return int(i[k]), int(j[k]), True
    return None


def join_edges(pool: Pool, rec: dict, t: int, stats: dict) -> dict:
    """The discovery's end: the pairs of trackers that are the two edges of one uniform
    part (learning.edges, over the pixels of the last ``life_tau_us``) merged, the
    nearest first, each into the union of both; returns the samples ``rec`` of the new set
    (a merged pair's those of the union, :func:`union_series`)."""
    if pool.lp.edge_polarity <= 0 or pool.n < 2:
        return rec
    rec = dict(rec)
    bends(pool, t - int(pool.lp.life_tau_us))
    while True:
        pair = next(((a, b) for a, b in zip(*(v.tolist() for v in facing_pairs(pool)[:2]))
                     if pool.union_fits(a, b)), None)
        if pair is None:
            return rec
        i, j = pair
        rec = _merge_in(pool, rec, i, j, t)
        stats["edge_merged"] += 1


def join_outlines(pool: Pool, rec: dict, t: int, stats: dict) -> dict:
    """The discovery's end: the trackers on one outline of the last ``life_tau_us``'s
    pixels merged, the nearest first, an outline here any closed curve that keeps one
    radius per direction and as wide as a part may be (Outlines.find's ``any_shape``; the
    discovery's outline merge takes thin circles half as wide, whose pieces join while
    the pool runs); returns the samples ``rec`` of the new set."""
    lp = pool.lp
    if lp.outline_cover <= 0 or pool.n < 2:
        return rec
    outlines = Outlines(pool.width, pool.height)
    ok = outlines.find(pool.last, t - int(lp.life_tau_us), lp.sigma_max_px, lp.outline_cover,
                       any_shape=True)
    on = outlines.of_pixels(ok, pool)
    rec = dict(rec)
    while True:
        same = (on[:, None] == on[None, :]) & (on[:, None] > 0)
        i, j = np.nonzero(np.triu(same, 1))
        d = np.hypot(pool.x[i] - pool.x[j], pool.y[i] - pool.y[j])
        pair = next(((int(i[k]), int(j[k])) for k in np.argsort(d, kind="stable")
                     if pool.union_fits(i[k], j[k])), None)
        if pair is None:
            return rec
        a, b = pair
        rec = _merge_in(pool, rec, a, b, t)
        on = np.delete(on, b)
        stats["end_outline_merged"] += 1


def _merge_in(pool: Pool, rec: dict, i: int, j: int, t: int) -> dict:
    """Tracker i becomes the union of i and j (Pool.merge) and its samples ``rec`` those
    of the union (:func:`union_series`); returns ``rec`` without j's."""
    wi, wj = pool.recent[i] + 1e-9, pool.recent[j] + 1e-9
    pool.merge(i, j, t)                 # its bend reset: join_edges pairs the union no more
    cols = [tuple(rec[f][:, k] for f in SERIES) for k in (i, j)]
    for f, v in zip(SERIES, union_series(cols[0], wi, cols[1], wj, len(rec["t"]))):
        rec[f][:, i] = v
    return _keep_cols(rec, np.arange(pool.n + 1) != j)


def _dying(pool: Pool, births: "BirthField", t: int) -> np.ndarray:
    """(n,) trackers older than life_tau_us whose recent count is below death_share of
    the pool's median, or below birth_contrast times what the background would give."""
    lp = pool.lp
    n = pool.n
    dead = np.zeros(n, bool)
    old = (t - pool.book["born"][:n]) > lp.life_tau_us
    if not old.any():
        return dead
    recent = pool.recent[:n]
    med = float(np.median(recent[old]))
    st = pool.st
    det = st[F["sxx"], :n] * st[F["syy"], :n] - st[F["sxy"], :n] ** 2
    gate_area = math.pi * lp.gate_d2 * np.sqrt(det)
    noise = births.noise_px * gate_area * lp.life_tau_us / lp.activity_tau_us
    return old & ((recent < lp.death_share * med) | (recent < lp.birth_contrast * noise))


@contextlib.contextmanager
def quiet_nan():
    """numpy's nan-statistics without their warnings on all-NaN slices (a tracker with no
    sample there: the result is NaN, which the callers handle)."""
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def event_rates(rec: dict) -> np.ndarray:
    """(N,) events per batch of each tracker while it had its present identity."""
    return rec["cnt"].sum(axis=0) / np.maximum(rec["valid"].sum(axis=0), 1)


def event_shares(rec: dict) -> np.ndarray:
    """(N,) each tracker's events over the median tracker's in the same batches (while
    it had its present identity): rates compared at the same times, as the parts'
    speed, hence their event rate, changes over the window."""
    cnt = np.where(rec["valid"], rec["cnt"], np.nan)
    with quiet_nan():
        med = np.nanmedian(cnt, axis=1, keepdims=True)
    # a batch whose median tracker took no event is judged against one event (events are
    # whole: "fewer than the median" cannot be told below one), so a share is finite and
    # a tracker's events in such a batch count against something
    ref = np.where(rec["valid"], np.maximum(np.nan_to_num(med), 1.0), 0.0)
    held = np.where(rec["valid"], rec["cnt"], 0.0).sum(axis=0)
    return np.divide(held, ref.sum(axis=0), out=np.zeros(len(held)), where=ref.sum(axis=0) > 0)


def dominant(counts: np.ndarray) -> bool:
    """Whether one part holds at least half of all events (a single object and the faint
    trails it leaves)."""
    c = np.maximum(np.asarray(counts, float), 0.0)
    return bool(len(c)) and c.sum() > 0 and c.max() >= 0.5 * c.sum()


def reference_value(values: np.ndarray, counts: np.ndarray) -> float:
    """What a part's ``values`` are judged against: the plain median over the parts, or,
    when one part is :func:`dominant`, that part's value, where the plain median would
    be a trail's."""
    if not len(values):
        return 0.0
    if dominant(counts):
        return float(values[int(np.argmax(counts))])
    return float(np.median(values))


def awake(rec: dict, tau_us: float, batch_us: int) -> np.ndarray:
    """(N,) each tracker's activity (eq. 6) over the last ``tau_us`` of the samples, over
    its mean activity: near 1 while it follows its part, near 0 once the part has left
    it behind."""
    k = max(1, int(round(tau_us / batch_us)))
    act = np.where(rec["valid"], rec["act"], np.nan)
    with quiet_nan():
        now = np.nan_to_num(np.nanmean(act[-k:], axis=0))
        usual = np.nan_to_num(np.nanmean(act, axis=0))
    return now / np.maximum(usual, 1e-12)


def _keep_cols(rec: dict, mask: np.ndarray) -> dict:
    """The samples ``rec`` of the trackers where ``mask`` is true."""
    return {k: (v if k == "t" else v[:, mask]) for k, v in rec.items()}


def _to_count(pool: Pool, rec: dict, n_target: int, t: int, stats: dict) -> dict:
    """Drop the weakest tracker while it takes less than ``keep_share`` of the median's
    events, else merge the nearest pair (Bhattacharyya), until n_target; split the widest
    until n_target.  Returns the samples ``rec`` of the new set: a merged pair's those of
    the union (:func:`union_series`), a split tracker's its parent's, shifted."""
    rec = dict(rec)
    while pool.n > n_target:
        share = event_shares(rec)
        k = int(np.argmin(share))
        if share[k] < pool.lp.keep_share:
            mask = np.arange(pool.n) != k
            pool.keep(mask)
            rec = _keep_cols(rec, mask)
            stats["dropped_to_n"] += 1
            continue
        i, j = _closest_pair(pool)
        rec = _merge_in(pool, rec, i, j, t)
        stats["merged_to_n"] += 1
    while pool.n < n_target:
        st = pool.st
        n = pool.n
        i = int(np.argmax(st[F["sxx"], :n] + st[F["syy"], :n]))
        before = pool.gaussian(i)[0]
        if not pool.split(i, t):
            break
        off = pool.gaussian(i)[0] - before
        new = {f: rec[f][:, i:i + 1].copy() for f in SERIES}
        for k, f in enumerate(("x", "y")):         # i moved by off, the new half by -off
            rec[f][:, i] += off[k]
            new[f] -= off[k]
        for f in ("act", "cnt"):
            rec[f][:, i] *= 0.5
            new[f] *= 0.5
        rec = {k: (v if k == "t" else np.concatenate([v, new[k]], axis=1)) for k, v in rec.items()}
        stats["split_to_n"] += 1
    return rec


def bhattacharyya(mx, my, sxx, sxy, syy) -> np.ndarray:
    """(N, N) Bhattacharyya distances between N 2-D Gaussians (means mx, my; covariances
    [[sxx, sxy], [sxy, syy]]), every pair at once."""
    # D_B = 1/8 d^T C^-1 d + 1/2 ln(det C / sqrt(det C_i det C_j)), C = (C_i + C_j) / 2
    a = 0.5 * (sxx[:, None] + sxx[None, :])
    b = 0.5 * (sxy[:, None] + sxy[None, :])
    c = 0.5 * (syy[:, None] + syy[None, :])
    dx = mx[None, :] - mx[:, None]
    dy = my[None, :] - my[:, None]
    det = a * c - b * b                       # C^-1 = [[c, -b], [-b, a]] / det
    det_own = sxx * syy - sxy * sxy
    with np.errstate(divide="ignore", invalid="ignore"):
        quad = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
        return 0.125 * quad + 0.5 * np.log(det / np.sqrt(det_own[:, None] * det_own[None, :]))


def _closest_pair(pool: Pool):
    """The pair i < j with the smallest Bhattacharyya distance (the first in (i, j)
    order among equals)."""
    n = pool.n
    st = pool.st
    db = bhattacharyya(*(st[F[f], :n] for f in ("mx", "my", "sxx", "sxy", "syy")))
    db = np.where(np.triu(np.ones((n, n), bool), 1) & ~np.isnan(db), db, np.inf)
    flat = int(np.argmin(db))
    if not np.isfinite(db.flat[flat]):
        return 0, 1
    return divmod(flat, n)
