"""Learning a shape model from events: free trackers, then springs from co-activation.

    >>> import springtrack
    >>> model = springtrack.learn(events)                  # doctest: +SKIP
    >>> model = springtrack.learn(events, trackers=9)      # exactly 9 parts  # doctest: +SKIP

The paper's closing proposal ("the pool of trackers would then connect based on their
temporal coactivations"), in one pass over the learning window (docs/learning.md):

1. **A pool of free Gaussian trackers** (eqs. 2-6, no springs; per-event loop in
   ``_learn.pyx``) with a lifecycle every ``batch_us``:

   * *birth*: events no tracker takes (outside every gate, eq. 2) are counted, decayed
     with ``activity_tau_us``, in cells of ``birth_cell_px``; where a 3x3 block of cells
     holds ``birth_events`` of them and ``birth_contrast`` times the noise (the median
     block), a tracker is born with their mean and covariance;
   * *merge* (the union no wider than ``sigma_max_px``): duplicates (a share
     ``merge_overlap`` of the smaller one's events in both gates, one holding the other's
     mean), and the leading and trailing edges of one part, joined by pixels the part
     covers (:meth:`Pool.gaps`);
   * *death*: a tracker older than ``life_tau_us`` whose recent events fall below
     ``death_share`` of the pool's median, or below ``birth_contrast`` times the noise.

   The pass records each tracker's position, activity and events (:class:`History`).
2. **The final set**: established trackers with an extent, without the weak pieces and
   those their part left behind; ``trackers=N`` drops, merges or splits to N.
3. **Springs** between neighbours (the relative neighbourhood graph of the final
   positions and each tracker's three nearest) that were co-active (normalised inner
   product of their activity traces at least ``min_coactivation``) and kept their
   relative position in the object's frame (:func:`rigidity`); Cartesian where neither
   the pair nor the object turned by ``cartesian_turn_deg``, Euclidean + torsional
   otherwise.  Rest lengths and angles are those of the final positions (the model
   derives them from its positions, which are the positions at the window's end);
   stiffness ``stiffness_gain * alpha_1 * rigidity``; masses the trackers' event shares.
4. **Tracking parameters** learned from the same record: alpha_position
   (:func:`motion_alpha`), energy_scale (:func:`energy_scale`), energy_kind.

Deterministic: the same events and parameters give the same model.  Input without an
object raises :class:`NoObjectFound`.
"""
from __future__ import annotations

import contextlib
import math
import time
import warnings
from dataclasses import dataclass, field, fields

import numpy as np

from . import _learn
from .events import as_events
from .limits import MAX_CONNECTIONS, spring_scale
from .model import SPRING_BIT, Connection, ShapeModel, TrackerSpec
from .params import Params

POOL_CAPACITY = 128           # trackers alive at once during discovery
COVERED_MIN_LEVEL = 2.0       # Pool.update_level: the least level (contrast thresholds)
LEVEL_EVERY = 10              # levels (Pool.update_level, BirthField.update_noise) are
                              # measured every this many batches
POINT_SIGMA = 1.05            # a tracker narrower than this sigma_min_px both ways: a point
MASS_RANGE = (0.5, 2.0)       # masses: event share over the median, bounded
MIN_SAMPLES = 10              # batches a pair must share for a spring
CONTRAST_MARGIN = 0.05        # contrast_sign: ON-first fraction this far from 1/2 decides
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
    stiffness_gain: float = 0.1        # stiffness = gain * alpha_1 (tracking) * rigidity
    energy_quantile: float = 0.99      # s of eqs. (21)-(22): this quantile of E_ij / mean E,
    energy_scale_max: float = 4.5      # ... at most this (and at least the default 2.5)
    smooth_us: int = 20_000            # averaging of directions for the turn measure

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
        if not 0 < self.sigma_min_px < self.sigma_max_px:
            raise ValueError("learn: need 0 < sigma_min_px < sigma_max_px")
        for name in ("batch_us", "birth_cell_px", "activity_tau_us", "life_tau_us", "smooth_us",
                     "lag_fraction"):
            if getattr(self, name) <= 0:
                raise ValueError(f"learn: {name} must be positive")

    @property
    def gate_d2(self) -> float:
        return -2.0 * math.log(self.p_threshold)


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


# ---- the pool ---------------------------------------------------------------------------
# per-tracker bookkeeping next to the state array (all of length POOL_CAPACITY)
BOOK = ("recent", "total", "born", "uid")


class Pool:
    """Free Gaussian trackers (eqs. 2-6) in a state array, with their bookkeeping (``book``:
    ``recent`` event counts decayed with ``life_tau_us``, ``total`` events since birth,
    ``born`` (µs) and ``uid`` (a new one at each birth, merge or split; ``lineage``
    records the pieces of a merge)), the events shared by pairs of gates
    (``overlap``, decayed like ``recent``) and each pixel's ON minus OFF events (``net``,
    see :meth:`covered`)."""

    def __init__(self, lp: LearnParams, width: int, height: int, capacity: int = POOL_CAPACITY):
        self.lp, self.width, self.height = lp, width, height
        self.cap = capacity
        self.st = np.zeros((len(_learn.FIELDS), capacity))
        self.n = 0
        self.book = {k: np.zeros(capacity) for k in BOOK}
        self.overlap = np.zeros((capacity, capacity))
        self.net = np.zeros((height, width), np.int32)
        self.level = 0.0                  # the parts' level in ``net``: covered_level()
        self.contrast = 0                 # +1 bright parts, -1 dark, 0 unknown: contrast_sign
        self.next_uid = 0
        self.lineage = {}                 # merged uid -> (uid_a, w_a, uid_b, w_b)
        self.smin2, self.smax2 = lp.sigma_min_px ** 2, lp.sigma_max_px ** 2
        self.winner = np.empty(0, np.int32)
        self.alpha_covariance = lp.alpha_covariance   # 0 freezes the sizes (fixed passes)

    @property
    def x(self) -> np.ndarray:
        return self.st[F["mx"], :self.n]

    @property
    def y(self) -> np.ndarray:
        return self.st[F["my"], :self.n]

    @property
    def recent(self) -> np.ndarray:
        return self.book["recent"]

    def run(self, ev: np.ndarray) -> np.ndarray:
        """Eqs. (2)-(6) over a batch; returns each event's winner (-1 none, -2 outside).

        The covariance takes the spread of the events the tracker takes, as eqs. (4)-(5)
        print it (without the tracker's gate correction, see docs/learning.md): event
        clouds are edges, rings and bars, which their gate holds whole."""
        if len(self.winner) < len(ev):
            self.winner = np.empty(max(len(ev), 2 * len(self.winner)), np.int32)
        w = self.winner[:len(ev)]
        lp, n = self.lp, self.n
        a2 = self.alpha_covariance
        _learn.pool_batch(ev, self.st, n, lp.alpha_position, a2, a2, lp.gate_d2, lp.activity_tau_us, self.smin2,
                          self.smax2, self.width, self.height, w, self.overlap, self.net)
        got = np.bincount(w[w >= 0], minlength=n)[:n]
        self.recent[:n] += got
        self.book["total"][:n] += got
        return w

    def decay(self, dt_us: float) -> None:
        """Age the recent counts and the shared events by ``dt_us``."""
        n = self.n
        f = math.exp(-dt_us / self.lp.life_tau_us)
        self.recent[:n] *= f
        self.overlap[:n, :n] *= f

    def activity(self, t: int) -> np.ndarray:
        """eq. (6) evaluated at time t for every tracker."""
        st = self.st
        return st[F["act"], :self.n] * np.exp(-(t - st[F["tlast"], :self.n])
                                               / self.lp.activity_tau_us)

    def add(self, mu, cov, t, act=0.0, book=None) -> bool:
        """A new tracker N(mu, cov) at time t; ``book`` overrides its bookkeeping."""
        if self.n >= self.cap:
            return False
        i = self.n
        self.n += 1
        self.st[:, i] = 0.0
        self.set_gaussian(i, mu, cov)
        self.st[F["act"], i], self.st[F["tlast"], i] = act, t
        for k in BOOK:
            self.book[k][i] = 0.0
        self.book["born"][i] = t
        self.book["uid"][i] = self.new_uid()
        for k, v in (book or {}).items():
            self.book[k][i] = v
        self.overlap[i, :] = 0.0
        self.overlap[:, i] = 0.0
        return True

    def new_uid(self) -> int:
        self.next_uid += 1
        return self.next_uid - 1

    def keep(self, mask: np.ndarray) -> None:
        """Keep the trackers where ``mask`` (n,) is true, in their order."""
        idx = np.flatnonzero(mask)
        k = len(idx)
        self.st[:, :k] = self.st[:, idx]
        for a in self.book.values():
            a[:k] = a[idx]
        self.overlap[:k, :k] = self.overlap[np.ix_(idx, idx)]
        self.overlap[k:, :] = 0.0
        self.overlap[:, k:] = 0.0
        self.n = k

    def gaussian(self, i: int):
        st = self.st
        mu = np.array([st[F["mx"], i], st[F["my"], i]])
        cov = np.array([[st[F["sxx"], i], st[F["sxy"], i]], [st[F["sxy"], i], st[F["syy"], i]]])
        return mu, cov

    def set_gaussian(self, i: int, mu, cov) -> None:
        st = self.st
        st[F["mx"], i], st[F["my"], i] = mu
        st[F["sxx"], i], st[F["sxy"], i], st[F["syy"], i] = cov[0, 0], cov[0, 1], cov[1, 1]
        _learn.refresh(st, i, self.smin2, self.smax2)

    def union(self, i: int, j: int):
        """The moment-matched Gaussian of i and j, weighted by their recent counts."""
        mi, ci = self.gaussian(i)
        mj, cj = self.gaussian(j)
        return moment_match(mi, ci, self.recent[i] + 1e-9, mj, cj, self.recent[j] + 1e-9)

    def union_fits(self, i: int, j: int) -> bool:
        """Whether the union of i and j is no wider than a part may be (sigma_max_px)."""
        return float(np.linalg.eigvalsh(self.union(i, j)[1])[-1]) <= self.smax2

    def merge(self, i: int, j: int, t: int) -> None:
        """Tracker i becomes the union of i and j, under a new uid whose pieces the
        ``lineage`` records; j is dropped."""
        wi, wj = self.recent[i] + 1e-9, self.recent[j] + 1e-9
        mu, cov = self.union(i, j)
        act = self.activity(t)
        self.set_gaussian(i, mu, cov)
        self.st[F["act"], i], self.st[F["tlast"], i] = act[i] + act[j], t
        for k in ("recent", "total"):
            self.book[k][i] += self.book[k][j]
        self.book["born"][i] = min(self.book["born"][i], self.book["born"][j])
        parents = (int(self.book["uid"][i]), float(wi), int(self.book["uid"][j]), float(wj))
        self.book["uid"][i] = self.new_uid()
        self.lineage[int(self.book["uid"][i])] = parents
        n = self.n
        self.overlap[i, :n] += self.overlap[j, :n]
        self.overlap[:n, i] += self.overlap[:n, j]
        self.overlap[i, i] = 0.0
        mask = np.ones(n, bool)
        mask[j] = False
        self.keep(mask)

    def split(self, i: int, t: int) -> bool:
        """Replace tracker i by two halves along its major axis (moment-preserving)."""
        if self.n >= self.cap:
            return False
        mu, cov = self.gaussian(i)
        vals, vecs = np.linalg.eigh(cov)
        lam, v = vals[-1], vecs[:, -1]
        off = 0.5 * math.sqrt(lam) * v
        half = cov - 0.25 * lam * np.outer(v, v)
        act = 0.5 * self.activity(t)[i]
        book = {k: 0.5 * self.book[k][i] for k in ("recent", "total")}
        self.set_gaussian(i, mu - off, half)
        self.st[F["act"], i], self.st[F["tlast"], i] = act, t
        for k, v in book.items():
            self.book[k][i] = v
        self.book["uid"][i] = self.new_uid()
        return self.add(mu + off, half, t, act, book)

    def nested(self) -> np.ndarray:
        """(n, n): one tracker's mean lies within the other's one-sigma ellipse."""
        n = self.n
        st = self.st
        dx = self.x[:, None] - self.x[None, :]
        dy = self.y[:, None] - self.y[None, :]
        ia, ib, ic = st[F["ia"], :n], st[F["ib"], :n], st[F["ic"], :n]
        d2_in_i = ia[:, None] * dx * dx + ic[:, None] * dy * dy + 2.0 * ib[:, None] * dx * dy
        d2_in_j = ia[None, :] * dx * dx + ic[None, :] * dy * dy + 2.0 * ib[None, :] * dx * dy
        return np.minimum(d2_in_i, d2_in_j) < 1.0

    def overlap_score(self) -> np.ndarray:
        """(n, n) upper-triangular: shared events over the smaller recent count."""
        n = self.n
        r = np.maximum(self.recent[:n], 1e-9)
        return np.triu(self.overlap[:n, :n] / np.minimum.outer(r, r), 1)

    def update_level(self) -> None:
        """The parts' level in ``net``: half the 90th percentile of the contrast-signed
        counts above zero (at least COVERED_MIN_LEVEL), the threshold of :meth:`gap`."""
        if not self.contrast:
            return
        v = self.contrast * self.net
        v = v[v > 0]
        if len(v):
            self.level = max(COVERED_MIN_LEVEL, 0.75 * float(np.percentile(v, 90)))

    def gaps(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """For pairs (i, j): the longest stretch (px) of the segment between their means
        that no part covers.

        ``net`` is each pixel's change of log intensity since the window's start (ON
        minus OFF events, in contrast thresholds).  A part entering a pixel moves it by
        the part's contrast (``contrast``: up for bright parts) and leaving brings it
        back: the pixels inside a part stand near the part's contrast, those of a gap
        between parts near zero.  The leading and trailing edges of one part, which the
        free trackers follow apart, are joined by covered pixels (at least ``level`` in
        the parts' sign); two parts are not.  (Where a part sat at the window's start
        the pixels show nothing or the other sign: it must have moved by its own size.)"""
        out = np.full(len(i), math.inf)
        if self.contrast and self.level > 0 and len(i):
            x, y = self.x, self.y
            _learn.segment_gaps(self.net, x[i], y[i], x[j], y[j], self.level, self.contrast, out)
        return out


def moment_match(m1, c1, w1, m2, c2, w2):
    """The Gaussian with the mean and covariance of the mixture w1 N(m1, c1) + w2 N(m2, c2)."""
    w = w1 + w2
    mu = (w1 * m1 + w2 * m2) / w
    d1, d2 = m1 - mu, m2 - mu
    cov = (w1 * (c1 + np.outer(d1, d1)) + w2 * (c2 + np.outer(d2, d2))) / w
    return mu, cov


def union_series(a, wa: float, b, wb: float, until: int):
    """The samples (x, y, act, cnt, valid) of the union of two pieces ``a`` and ``b``
    (each such a tuple of (T,) arrays, weighted ``wa``, ``wb`` at their merge) before
    sample ``until``.  Where both existed: positions weighted, activities and events
    summed.  Where one existed alone (a piece born late, or one that lived on its own
    before the other was born): that piece, moved by its offset from the union at the
    last sample they shared, with its own activity and events: a piece of a part (an
    edge, a fragment) keeps its place on the part, so the part's history is not cut to
    the samples its pieces shared."""
    (xa, ya, aa, ca, oa), (xb, yb, ab, cb, ob) = a, b
    T = len(xa)
    before = np.arange(T) < until
    both = oa & ob & before
    w = wa + wb
    x = np.where(both, (wa * xa + wb * xb) / w, np.nan)
    y = np.where(both, (wa * ya + wb * yb) / w, np.nan)
    act = np.where(both, aa + ab, 0.0)
    cnt = np.where(both, ca + cb, 0.0)
    if both.any():
        k = int(np.flatnonzero(both)[-1])
        for px, py, pa, pc, po in (a, b):
            alone = po & ~both & before & ~np.isfinite(x)
            x = np.where(alone, px + (x[k] - px[k]), x)
            y = np.where(alone, py + (y[k] - py[k]), y)
            act = np.where(alone, pa, act)
            cnt = np.where(alone, pc, cnt)
    ok = np.isfinite(x)
    return x, y, act, cnt, ok


def contrast_sign(ev: np.ndarray, width: int, height: int) -> int:
    """+1 if the parts are brighter than their background, -1 if darker, 0 if unclear.

    A part entering a pixel makes it fire first with the part's contrast (ON for a
    bright part) and leaving it with the opposite one; over a window in which the parts
    moved, most pixels they touched have entered before they left.  The sign is that of
    the fraction of pixels (with two events or more) whose first event is ON, minus 1/2."""
    pix = ev["y"].astype(np.int64) * width + ev["x"]
    ok = (ev["x"] < width) & (ev["y"] < height)
    pix = pix[ok]
    u, first = np.unique(pix, return_index=True)
    busy = np.bincount(pix, minlength=width * height)[u] >= 2
    if not busy.any():
        return 0
    f = float(np.mean(ev["p"][ok][first[busy]] > 0))
    if abs(f - 0.5) < CONTRAST_MARGIN:
        return 0
    return 1 if f > 0.5 else -1


# ---- births -----------------------------------------------------------------------------
class BirthField:
    """Unassigned events counted in cells, decayed with tau; births where they pile up."""

    def __init__(self, lp: LearnParams, width: int, height: int):
        self.lp = lp
        c = lp.birth_cell_px
        self.c = c
        self.shape = (-(-height // c), -(-width // c))
        self.m = np.zeros((6,) + self.shape)        # count, sx, sy, sxx, sxy, syy
        self.noise_px = 0.0                          # see update_noise

    def decay(self, dt_us: float) -> None:
        self.m *= math.exp(-dt_us / self.lp.activity_tau_us)

    def add(self, ev: np.ndarray) -> None:
        if not len(ev):
            return
        x = ev["x"].astype(np.float64)
        y = ev["y"].astype(np.float64)
        cell = (ev["y"] // self.c).astype(np.int64) * self.shape[1] + ev["x"] // self.c
        size = self.shape[0] * self.shape[1]
        for k, wts in enumerate((None, x, y, x * x, x * y, y * y)):
            self.m[k] += np.bincount(cell, wts, size).reshape(self.shape)

    def block(self, m: np.ndarray) -> np.ndarray:
        """3x3 block sums of the cell array ``m``."""
        p = np.pad(m, 1)
        h, w = self.shape
        return sum(p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3))

    def update_noise(self) -> None:
        """Unassigned events per pixel (decayed count) of the median block: the noise."""
        self.noise_px = float(np.median(self.block(self.m[0]))) / (9.0 * self.c ** 2)

    def births(self):
        """Births due now: list of (mean, covariance); their cells are cleared.  A birth
        needs ``birth_events`` unassigned events in a 3x3 block of cells, and
        ``birth_contrast`` times the noise, at a local maximum."""
        lp = self.lp
        cnt = self.block(self.m[0])
        thr = max(lp.birth_events, lp.birth_contrast * self.noise_px * 9.0 * self.c ** 2)
        if cnt.max() < thr:
            return []
        p = np.pad(cnt, 1, constant_values=-1.0)
        h, w = self.shape
        neigh = np.max([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)
                        if (dy, dx) != (1, 1)], axis=0)
        out = []
        for cy, cx in np.argwhere((cnt >= thr) & (cnt > neigh) & (self.m[0] > 0)):
            sl = (slice(None), slice(max(cy - 1, 0), cy + 2), slice(max(cx - 1, 0), cx + 2))
            n, sx, sy, sxx, sxy, syy = self.m[sl].sum(axis=(1, 2))
            mx, my = sx / n, sy / n
            cov = np.array([[sxx / n - mx * mx, sxy / n - mx * my],
                            [sxy / n - mx * my, syy / n - my * my]])
            out.append((np.array([mx, my]), cov))
            self.m[sl] = 0.0
        return out


# ---- the passes -------------------------------------------------------------------------
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
        for k, name in enumerate(("x", "y", "act", "cnt", "valid")):
            out[name] = (np.stack([c[k] for c in cols], axis=1) if cols else
                         np.zeros((T, 0), bool if name == "valid" else float))
        return out


def _discover(pool: Pool, ev: np.ndarray, t0: int, t1: int, stats: dict) -> History:
    """Pass 1: the pool with births, merges and deaths, every ``batch_us``; returns its
    history."""
    lp = pool.lp
    births = BirthField(lp, pool.width, pool.height)
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
        while pool.n > 1:
            pair = _merge_candidate(pool)
            if pair is None:
                break
            pool.merge(*pair, te)
            stats["merged"] += 1
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
    """The pair to merge now, or None, with its union no wider than a part may be:
    trackers that share their events and one holds the other's mean (duplicates on one
    cloud), the most sharing first; or neighbours joined by covered pixels (two edges,
    or two pieces, of one part: Pool.gaps), the nearest first."""
    lp = pool.lp
    n = pool.n
    share = pool.overlap_score()
    dup = (share >= lp.merge_overlap) & pool.nested()
    for flat in np.argsort(-share, axis=None, kind="stable"):
        i, j = divmod(int(flat), n)
        if not dup[i, j]:
            break
        if pool.union_fits(i, j):
            return i, j
    if pool.contrast and n > 1:
        d = np.hypot(pool.x[:, None] - pool.x[None, :], pool.y[:, None] - pool.y[None, :])
        i, j = relative_neighbours(d, within=2.0 * lp.sigma_max_px)
        joined = pool.gaps(i, j) < lp.merge_gap_px
        i, j = i[joined], j[joined]
        for k in np.argsort(d[i, j], kind="stable"):
            if pool.union_fits(i[k], j[k]):
                return int(i[k]), int(j[k])
    return None


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
    ref = np.where(rec["valid"] & (med > 0), med, 0.0)
    return rec["cnt"].sum(axis=0) / np.maximum(ref.sum(axis=0), 1e-12)


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
        wi, wj = pool.recent[i] + 1e-9, pool.recent[j] + 1e-9
        pool.merge(i, j, t)
        cols = [tuple(rec[f][:, k] for f in ("x", "y", "act", "cnt", "valid")) for k in (i, j)]
        union = union_series(cols[0], wi, cols[1], wj, len(rec["t"]))
        for f, v in zip(("x", "y", "act", "cnt", "valid"), union):
            rec[f][:, i] = v
        rec = _keep_cols(rec, np.arange(pool.n + 1) != j)
        stats["merged_to_n"] += 1
    while pool.n < n_target:
        st = pool.st
        n = pool.n
        i = int(np.argmax(st[F["sxx"], :n] + st[F["syy"], :n]))
        before = pool.gaussian(i)[0]
        if not pool.split(i, t):
            break
        off = pool.gaussian(i)[0] - before
        new = {f: rec[f][:, i:i + 1].copy() for f in ("x", "y", "act", "cnt", "valid")}
        for k, f in enumerate(("x", "y")):         # i moved by off, the new half by -off
            rec[f][:, i] += off[k]
            new[f] -= off[k]
        for f in ("act", "cnt"):
            rec[f][:, i] *= 0.5
            new[f] *= 0.5
        rec = {k: (v if k == "t" else np.concatenate([v, new[k]], axis=1)) for k, v in rec.items()}
        stats["split_to_n"] += 1
    return rec


def _closest_pair(pool: Pool):
    """The pair with the smallest Bhattacharyya distance."""
    best, pair = math.inf, (0, 1)
    for i in range(pool.n):
        mi, ci = pool.gaussian(i)
        for j in range(i + 1, pool.n):
            mj, cj = pool.gaussian(j)
            c = 0.5 * (ci + cj)
            d = mj - mi
            db = 0.125 * d @ np.linalg.solve(c, d) + 0.5 * math.log(
                np.linalg.det(c) / math.sqrt(np.linalg.det(ci) * np.linalg.det(cj)))
            if db < best:
                best, pair = db, (i, j)
    return pair


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


# ---- the learner ------------------------------------------------------------------------
def learn_model(events, trackers: int | None = None, width: int | None = None,
                height: int | None = None, names=None, name: str = "learned",
                params: LearnParams | dict | None = None,
                track_params: dict | None = None) -> LearnResult:
    """Learn a shape model from ``events`` (structured t µs, x, y, p; time order).

    ``trackers``: exactly this many parts (default: the learner's choice); ``width`` x
    ``height``: the sensor (default: the events' extent); ``names``: tracker ids (default
    p00, p01, ... in reading order: top to bottom, left to right); ``params``: learner
    parameters (:class:`LearnParams` or a dict of overrides); ``track_params``: tracking
    parameters (springtrack.params names) to write into the model's ``[params]`` as
    given; alpha_position, energy_scale and energy_kind are learned unless given there
    (the stiffness scales with alpha_position).
    Raises :class:`NoObjectFound` when no part survives.
    """
    wall0 = time.perf_counter()
    lp = params if isinstance(params, LearnParams) else LearnParams(**(params or {}))
    tp = Params(**(track_params or {})).as_dict()             # validated
    tp = {k: tp[k] for k in (track_params or {})}
    ev = as_events(events)
    if trackers is not None and not 1 <= int(trackers) <= 64:
        raise ValueError(f"learn: trackers must be in [1, 64], got {trackers}")
    if len(ev) == 0:
        raise NoObjectFound("no object found: the learning window holds no events")
    if np.any(np.diff(ev["t"]) < 0):
        raise ValueError("learn: events must be in time order")
    width = int(width) if width else int(ev["x"].max()) + 1
    height = int(height) if height else int(ev["y"].max()) + 1
    t0, t1 = int(ev["t"][0]), int(ev["t"][-1])
    stats = {"born": 0, "merged": 0, "died": 0, "birth_refused_full": 0, "weak": 0,
             "dropped_to_n": 0, "merged_to_n": 0, "split_to_n": 0}
    pool = Pool(lp, width, height)
    history = _discover(pool, ev, t0, t1, stats)
    # trackers still in their grace period are not parts yet, and a part has an extent
    # (a hot pixel makes a tracker as narrow as sigma_min_px both ways)
    st = pool.st[:, :pool.n]
    point = np.maximum(st[F["sxx"]], st[F["syy"]]) <= (POINT_SIGMA * lp.sigma_min_px) ** 2
    pool.keep(((t1 - pool.book["born"][:pool.n]) > lp.life_tau_us) & ~point)
    if pool.n == 0:
        raise NoObjectFound(f"no object found: no tracker lived through {len(ev)} events "
                            f"({stats['born']} born, {stats['died']} died)")
    rec = history.series(pool.book["uid"][:pool.n], pool.lineage)
    if trackers is None:
        # pieces of parts that no merge joined take a small share of the events, and
        # trackers left behind by their part take none at the end
        wake = awake(rec, lp.activity_tau_us, lp.batch_us)
        weak = (event_shares(rec) < lp.keep_share) | (wake < lp.idle_share * np.median(wake))
        stats["weak"] = int(weak.sum())
        if weak.any() and not weak.all():
            pool.keep(~weak)
            rec = _keep_cols(rec, ~weak)
    elif pool.n != int(trackers):
        rec = _to_count(pool, rec, int(trackers), t1, stats)
    counts = rec["cnt"].sum(axis=0)
    if pool.n == 0 or counts.sum() == 0:
        raise NoObjectFound("no object found: the learned trackers took no events")
    model, springs, cands, counts = _build_model(pool, rec, counts, lp, tp, width, height,
                                                 names, name)
    return LearnResult(model, len(ev), int(counts.sum()), t0, t1, counts, springs, cands,
                       stats, time.perf_counter() - wall0)


def reading_order(x: np.ndarray, y: np.ndarray, row_px: float) -> np.ndarray:
    """Indices of the points in reading order: rows top to bottom (a new row starts
    ``row_px`` below the first point of the current one), left to right in a row."""
    by_y = np.argsort(y, kind="stable")
    row = np.zeros(len(y), int)
    start = y[by_y[0]] if len(y) else 0.0
    for k in range(1, len(by_y)):
        row[k] = row[k - 1]
        if y[by_y[k]] - start > row_px:
            row[k] += 1
            start = y[by_y[k]]
    rows = np.empty(len(y), int)
    rows[by_y] = row
    return np.lexsort((x, rows))


def activity_weights(rec: dict) -> np.ndarray:
    """(T, N) each sample's weight: the tracker's activity (eq. 6) over its largest, 0
    where it did not exist: a tracker counts where it follows its part."""
    act, valid = rec["act"], rec["valid"]
    return np.where(valid, act / np.maximum(act.max(axis=0, keepdims=True), 1e-12), 0.0)


def similarity_fit(z: np.ndarray, ref: np.ndarray, w: np.ndarray):
    """The similarity ``z ~ zbar + a (ref - rbar)`` (complex points (N,), weights (N,)):
    returns (a, zbar, rbar); a = 0 with fewer than two weighted points."""
    ws = max(float(w.sum()), 1e-300)
    zbar, rbar = (w * z).sum() / ws, (w * ref).sum() / ws
    den = float((w * np.abs(ref - rbar) ** 2).sum())
    a = (w * (z - zbar) * np.conj(ref - rbar)).sum() / den if den > 0 else 0.0
    return a, zbar, rbar


def steady_positions(rec: dict, x_end: np.ndarray, y_end: np.ndarray, size_px: float,
               rounds: int = 3):
    """The final positions (x, y) (N,), each tracker caught off its part at the window's
    end put back where the object's shape over the window places it.

    The final positions are one instant of free trackers, each with its own jitter and
    lag; a part caught a few pixels off at that instant would put a constant strain on
    the springs (their rest geometry is the model's positions) that the energy criteria,
    eqs. (21)-(22), would then misread.  The shape is the mean of the samples, each
    carried into the shape's frame by the similarity that maps the shape onto it
    (:func:`object_similarity`, activity-weighted), starting from the final positions and
    repeated ``rounds`` times (generalised Procrustes analysis); a sample counts with
    weight exp(-d^2 / (2 size_px^2)), d the RMS distance of its carried positions from
    the shape.  The shape is placed on the final positions by the similarity that maps it
    there, and a tracker farther than ``size_px`` (a part's size) from its place takes
    it; the others keep their final positions (where the parts are: a perspective view
    is not a similarity).  When most samples are no similarity of one shape (the median
    d over ``size_px``: a 3-D turn, a deforming object), the final positions stay.

    Returns (x, y, one_shape): one_shape False when the object's shape itself changed."""
    X, Y = rec["x"], rec["y"]
    w0 = activity_weights(rec)
    z = np.where(w0 > 0, X + 1j * Y, 0.0)
    end = x_end + 1j * y_end
    shape = end.copy()
    for _ in range(rounds):
        a = object_similarity(X, Y, w0, shape.real, shape.imag)              # (T,)
        ok = np.abs(a) > 0
        if not ok.any():
            return x_end, y_end, True
        ws = np.maximum(w0.sum(axis=1), 1e-300)
        zbar = (w0 * z).sum(axis=1) / ws
        rbar = (w0 * shape[None, :]).sum(axis=1) / ws
        inv = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
        est = rbar[:, None] + (z - zbar[:, None]) * inv[:, None]              # (T, N)
        d2 = (w0 * np.abs(est - shape[None, :]) ** 2).sum(axis=1) / ws
        if np.median(d2[ok]) > size_px ** 2:
            return x_end, y_end, False    # not one shape: the one at the end
        w = w0 * (ok * np.exp(-0.5 * d2 / size_px ** 2))[:, None]
        tot = w.sum(axis=0)
        shape = np.where(tot > 0, (w * est).sum(axis=0) / np.maximum(tot, 1e-300), end)
    a, zbar, rbar = similarity_fit(end, shape, np.ones(len(end)))
    if a == 0:
        return x_end, y_end, True
    placed = zbar + a * (shape - rbar)
    placed = np.where(np.abs(placed - end) > size_px, placed, end)
    return placed.real.copy(), placed.imag.copy(), True


def spring_energies(rec: dict, kept: list, stiffness: np.ndarray, kind: str, x_end,
                    y_end) -> np.ndarray:
    """(T, C) energies of the connections ``kept`` (LearnedSpring, pool indices) along the
    samples, as the tracker computes them with the final positions as its rest geometry,
    NaN where an end is missing: eq. (12) (euclidean: rest lengths l0) or eq. (20)
    (cartesian: rest offsets ``a d0`` carried by each sample's similarity ``a``,
    :func:`object_similarity`, as the tracker's similarity frame carries them)."""
    a = np.array([c.a for c in kept])
    b = np.array([c.b for c in kept])
    X, Y = rec["x"], rec["y"]
    r = (X[:, b] - X[:, a]) + 1j * (Y[:, b] - Y[:, a])
    r0 = (x_end[b] - x_end[a]) + 1j * (y_end[b] - y_end[a])
    if kind == "cartesian":
        sim = object_similarity(X, Y, activity_weights(rec), x_end, y_end)[:, None]
        return 0.5 * stiffness * np.abs(r - sim * r0) ** 2                  # eq. (20)
    dl = np.abs(r) - np.abs(r0)                                            # eq. (10)
    return 0.5 * stiffness * dl * dl                                        # eq. (12)


def motion_alpha(rec: dict, sig: np.ndarray, batch_us: int, smooth_us: int,
                 lag_fraction: float, quantile: float = 0.9, bounds=(0.005, 0.5)) -> float:
    """alpha_1 of eq. (3) for the motion seen while learning.

    Between two of its events (1/r s apart) a part moving at v px/s moves by v / r px;
    the running mean of eq. (3) takes 1/alpha_1 events to catch up, so it lags by
    v / (alpha_1 r) px.  Held to ``lag_fraction`` of the part's size sigma:
    alpha_1 = v / (lag_fraction r sigma).  Each tracker's own v (RMS speed, positions
    averaged over ``smooth_us``), r and sigma give its alpha_1; the model takes their
    ``quantile``, so that the parts that move fastest for their events (the tips of a
    turning object) are followed too."""
    step = max(1, int(round(smooth_us / batch_us)))
    T, n = rec["x"].shape
    m = T // step * step
    if m < 2 * step:
        return Params().alpha_position
    with quiet_nan():
        bx = np.nanmean(rec["x"][:m].reshape(-1, step, n), axis=1)     # NaN: no sample
        by = np.nanmean(rec["y"][:m].reshape(-1, step, n), axis=1)
        v2 = np.nanmean(np.diff(bx, axis=0) ** 2 + np.diff(by, axis=0) ** 2, axis=0)
    v = np.sqrt(v2) / (step * batch_us * 1e-6)
    r = event_rates(rec) / (batch_us * 1e-6)
    ok = np.isfinite(v) & (r > 0) & (sig > 0)
    if not ok.any():
        return Params().alpha_position
    # alpha_1 = v / (lag_fraction r sigma): eq. (3)'s lag v / (alpha_1 r) = lag_fraction sigma
    alpha = v[ok] / (lag_fraction * r[ok] * sig[ok])
    return float(np.clip(np.quantile(alpha, quantile), *bounds))


def energy_scale(energies: np.ndarray, quantile: float, floor: float,
                 ceiling: float = math.inf) -> float:
    """s of eqs. (21)-(22) such that the deformations seen while learning stay below it:
    the ``quantile`` of E_ij / mean(E) over the samples (NaN: missing), within
    [``floor``, ``ceiling``].  The ceiling keeps the criteria able to act: the window's
    clean motion says how unevenly the parts deform, not how hard an occluder will pull,
    and a few unevenly deforming pairs (an object's outline, texture) make the tail long;
    above about 5 the criteria no longer fire even on a part dragged off its place
    (docs/tuning.md), so a larger s would switch eqs. (21)-(22) off."""
    with quiet_nan():
        mean = np.nanmean(energies, axis=1, keepdims=True)
        ratio = energies / mean
    ratio = ratio[np.isfinite(ratio)]
    if not len(ratio):
        return floor
    return min(max(floor, float(np.quantile(ratio, quantile))), max(floor, ceiling))


def _build_model(pool, rec, counts, lp, track_params, width, height, names, name):
    """The ShapeModel of the pool's trackers, with springs and tracking parameters:
    ``track_params`` (a dict) as given, the others learned (alpha_position: motion_alpha;
    energy_scale: energy_scale; energy_kind: cartesian if every spring is)."""
    n = pool.n
    st = pool.st
    sig = np.sqrt(0.5 * (st[F["sxx"], :n] + st[F["syy"], :n]))
    x, y, one_shape = steady_positions(rec, pool.x.copy(), pool.y.copy(), float(np.median(sig)))
    order = reading_order(x, y, float(np.median(sig)))
    if names is not None:
        names = list(names)
        if len(names) != n:
            raise ValueError(f"learn: {len(names)} names for {n} trackers")
    ids = names or [f"p{k:02d}" for k in range(n)]
    new_of = np.empty(n, int)
    new_of[order] = np.arange(n)
    mass = np.clip(event_shares(rec), MASS_RANGE[0], MASS_RANGE[1])
    trackers = [None] * n
    for i in range(n):
        trackers[new_of[i]] = TrackerSpec(ids[new_of[i]], float(x[i]), float(y[i]),
                                          (float(st[F["sxx"], i]), float(st[F["sxy"], i]),
                                           float(st[F["syy"], i])), float(mass[i]))
    cands = _springs(rec, sig, lp, x, y)
    coactive = [c for c in cands if c.kinds and c.coactivation >= lp.min_coactivation]
    kept = [c for c in coactive if c.rigidity >= lp.min_rigidity]
    # a tracker no rigid pair holds is tied by its most rigid co-active neighbour
    held = {e for c in kept for e in (c.a, c.b)}
    for i in range(n):
        if i not in held:
            mine = [c for c in coactive if i in (c.a, c.b) and c not in kept]
            if mine:
                best = max(mine, key=lambda c: c.rigidity * c.coactivation)
                kept.append(best)
                held.update((best.a, best.b))
    kept = sorted(kept, key=lambda c: -c.rigidity * c.coactivation)[:MAX_CONNECTIONS]
    params = dict(track_params)
    if "alpha_position" not in params:
        params["alpha_position"] = round(motion_alpha(rec, sig, lp.batch_us, lp.smooth_us,
                                                             lp.lag_fraction), 4)
    stiff = np.array([lp.stiffness_gain * params["alpha_position"] * c.rigidity for c in kept])
    if kept:
        # the spring bound every model meets (springtrack.limits): all stiffnesses scaled
        # down together if a tracker's spring load would exceed it
        stiff = stiff * spring_scale(n, [c.a for c in kept], [c.b for c in kept],
                                     [sum(SPRING_BIT[s] for s in c.kinds) for c in kept],
                                     stiff, mass)
        kind = params.setdefault("energy_kind", "cartesian" if all(
            c.kinds == ("cartesian",) for c in kept) else "euclidean")
        if "energy_scale" not in params and not one_shape:
            # the object's view changed within the window (no similarity of one shape):
            # its own change of shape would read as an occlusion and eq. (22) would pull
            # the trackers back to a shape the object no longer has, so eqs. (21)-(22) are
            # off: s above the number of springs, which no E_ij can exceed (eq. 13:
            # E_ij <= sum E = n_c mean E)
            params["energy_scale"] = float(len(kept) + 1)
        elif "energy_scale" not in params:
            s = energy_scale(spring_energies(rec, kept, stiff, kind, x, y),
                             lp.energy_quantile, Params().energy_scale, lp.energy_scale_max)
            params["energy_scale"] = round(s, 3)
    for c in cands:                       # model order from here on
        c.a, c.b = sorted((int(new_of[c.a]), int(new_of[c.b])))
    pairs = sorted(zip(kept, stiff), key=lambda p: (p[0].a, p[0].b))
    kept = [c for c, _ in pairs]
    conns = [Connection(ids[c.a], ids[c.b], c.kinds, float(k)) for c, k in pairs]
    cands.sort(key=lambda c: (c.a, c.b))
    model = ShapeModel(name, width, height, sorted(trackers, key=lambda t: ids.index(t.id)),
                       conns, params, source="learned")
    return model, kept, cands, counts[order]


def learn(events, trackers: int | None = None, **kw) -> ShapeModel:
    """The learned :class:`ShapeModel` (see :func:`learn_model` for the arguments)."""
    return learn_model(events, trackers, **kw).model
