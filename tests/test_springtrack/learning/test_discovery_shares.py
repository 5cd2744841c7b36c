"""The learner's discovery statistics (springtrack/learning/discovery.py): event shares
against the median tracker when that median is zero, and the closest pair by the
Bhattacharyya distance, all pairs at once, equal to the pair loop it replaces."""
import math

import numpy as np
import pytest

from springtrack.learning.discovery import _closest_pair, event_shares
from springtrack.learning.pool import Pool
from springtrack.learning.settings import LearnParams


def rec_of(cnt, valid=None):
    cnt = np.asarray(cnt, float)
    return {"cnt": cnt, "valid": np.ones(cnt.shape, bool) if valid is None else np.asarray(valid)}


def test_a_share_is_against_one_event_where_the_median_tracker_took_none():
    # three trackers over four batches: in the last two the median tracker took nothing
    share = event_shares(rec_of([[4, 2, 2], [4, 2, 2], [6, 0, 0], [0, 0, 0]]))
    # tracker 0: 14 events against 2 + 2 + 1 + 1; tracker 1: 4 against the same
    np.testing.assert_allclose(share, [14 / 6, 4 / 6, 4 / 6], rtol=1e-12)


def test_no_event_is_a_share_of_zero_and_every_share_is_finite():
    # the median took nothing in every batch: a share of events, not events / 1e-12
    share = event_shares(rec_of([[5, 0, 0], [3, 0, 0], [0, 0, 0]]))
    np.testing.assert_allclose(share, [8 / 3, 0.0, 0.0], rtol=1e-12)
    assert np.isfinite(share).all() and share.max() < 10


def test_batches_outside_a_trackers_identity_count_neither_way():
    valid = [[True, True], [True, False], [False, True]]
    share = event_shares(rec_of([[2, 2], [4, 9], [9, 4]], valid))
    # batch 0: median 2; batch 1: only tracker 0 (median 4); batch 2: only tracker 1 (4)
    np.testing.assert_allclose(share, [6 / 6, 6 / 6], rtol=1e-12)
    assert list(event_shares(rec_of(np.zeros((3, 2)), np.zeros((3, 2), bool)))) == [0, 0]


def closest_pair_loop(pool):
    """The pair loop the vectorised search replaces (np.linalg per pair)."""
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


def random_pool(rng, n):
    pool = Pool(LearnParams(), 304, 240)
    for _ in range(n):
        a, c = rng.uniform(2, 60, 2)
        b = rng.uniform(-0.9, 0.9) * math.sqrt(a * c)
        assert pool.add(rng.uniform(0, [304, 240]), np.array([[a, b], [b, c]]), 0)
    return pool


@pytest.mark.parametrize("seed", range(40))
def test_closest_pair_equals_the_pair_loop(seed):
    rng = np.random.default_rng(seed)
    pool = random_pool(rng, int(rng.integers(2, 60)))
    assert tuple(_closest_pair(pool)) == closest_pair_loop(pool)


def test_closest_pair_ties_go_to_the_first_pair():
    pool = Pool(LearnParams(), 304, 240)
    cov = np.array([[9.0, 0.0], [0.0, 9.0]])
    for x in (10.0, 30.0, 50.0, 70.0):          # three equal neighbour distances
        pool.add(np.array([x, 50.0]), cov, 0)
    assert tuple(_closest_pair(pool)) == closest_pair_loop(pool) == (0, 1)
