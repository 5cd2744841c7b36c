"""The pool of free Gaussian trackers between batches (births, merges, deaths; the
per-event loop is springtrack/learning/batch.pyx), and the field of unassigned events
where trackers are born."""
from __future__ import annotations

import math

import numpy as np

from . import batch as _learn
from .settings import CONTRAST_MARGIN, CONTRAST_MIN_EVENTS, COVERED_MIN_LEVEL, F, LearnParams, POOL_CAPACITY


# ---- the pool ---------------------------------------------------------------------------
# per-tracker bookkeeping next to the state array (all of length POOL_CAPACITY)
BOOK = ("recent", "on", "total", "born", "uid", "outline", "arc_x", "arc_y", "arc_r")


class Pool:
    """Free Gaussian trackers (eqs. 2-6) in a state array, with their bookkeeping (``book``:
    ``recent`` event counts decayed with ``life_tau_us``, ``total`` events since birth,
    ``on`` the ON events among ``recent``, ``born`` (µs), ``uid`` (a new one at each
    birth, merge or split; ``lineage`` records the pieces of a merge), ``outline`` (the
    part's outline its events lay on at the last look, 0 none:
    springtrack.learning.outlines) and ``arc_x``, ``arc_y``, ``arc_r`` (the centre and
    radius of curvature of its recent pixels, measured at the discovery's end, radius 0
    none: springtrack.learning.edges)), the events shared by pairs
    of gates (``overlap``, decayed like ``recent``), each pixel's ON minus OFF events
    (``net``, see :meth:`gaps`) and its latest event time (``last``, µs)."""

    def __init__(self, lp: LearnParams, width: int, height: int, capacity: int = POOL_CAPACITY):
        self.lp, self.width, self.height = lp, width, height
        self.cap = capacity
        self.st = np.zeros((len(_learn.FIELDS), capacity))
        self.n = 0
        self.book = {k: np.zeros(capacity) for k in BOOK}
        self.overlap = np.zeros((capacity, capacity))
        self.net = np.zeros((height, width), np.int32)
        self.last = np.full((height, width), np.iinfo(np.int64).min, np.int64)
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
                          self.smax2, self.width, self.height, w, self.overlap, self.net,
                          self.last)
        took = w >= 0
        got = np.bincount(w[took], minlength=n)[:n]
        self.recent[:n] += got
        self.book["on"][:n] += np.bincount(w[took], ev["p"][took] > 0, minlength=n)[:n]
        self.book["total"][:n] += got
        return w

    def decay(self, dt_us: float) -> None:
        """Age the recent counts and the shared events by ``dt_us``."""
        n = self.n
        f = math.exp(-dt_us / self.lp.life_tau_us)
        self.recent[:n] *= f
        self.book["on"][:n] *= f
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

    def pixels_near(self, i: int, mask: np.ndarray):
        """(x, y) int arrays: the pixels where ``mask`` (height x width, bool) is true
        within two sigmas of tracker i's mean (eq. 2's d^2 <= 4)."""
        st = self.st
        mx, my = st[F["mx"], i], st[F["my"], i]
        half = 2.0 * math.sqrt(max(st[F["sxx"], i], st[F["syy"], i])) + 1.0  # >= 2 sigma
        h, w = mask.shape
        x0, x1 = max(0, int(mx - half)), min(w, int(mx + half) + 2)
        y0, y1 = max(0, int(my - half)), min(h, int(my + half) + 2)
        if x0 >= x1 or y0 >= y1:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        yy, xx = np.nonzero(mask[y0:y1, x0:x1])
        xx, yy = xx + x0, yy + y0
        dx, dy = xx - mx, yy - my
        d2 = st[F["ia"], i] * dx * dx + 2.0 * st[F["ib"], i] * dx * dy + st[F["ic"], i] * dy * dy
        inside = d2 <= 4.0
        return xx[inside], yy[inside]

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
        for k in ("recent", "on", "total"):
            self.book[k][i] += self.book[k][j]
        self.book["born"][i] = min(self.book["born"][i], self.book["born"][j])
        for k in ("outline", "arc_x", "arc_y", "arc_r"):
            self.book[k][i] = 0      # the union's outline: at the next look; its bend: unmeasured
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
        book = {k: 0.5 * self.book[k][i] for k in ("recent", "on", "total")}
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
    busy = np.bincount(pix, minlength=width * height)[u] >= CONTRAST_MIN_EVENTS
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
