"""The learner's pool of free trackers (springtrack/learning/pool.py), exact values: a split
keeps its parent's moments."""
import math

import numpy as np
import pytest

from springtrack.learning.pool import Pool
from springtrack.learning.settings import LearnParams


@pytest.mark.parametrize("cov", [[[36.0, 12.0], [12.0, 16.0]], [[9.0, 0.0], [0.0, 49.0]],
                                 [[25.0, -20.0], [-20.0, 25.0]]])
def test_a_split_keeps_the_parents_mean_and_covariance(cov):
    """The halves sit at mu +- sqrt(lambda)/2 v along the major axis (lambda, v its largest
    eigenpair), each with cov - lambda/4 v v^T, so that the equal mixture of the two has
    the parent's mean and covariance exactly: the halves' spread plus their offset."""
    pool = Pool(LearnParams(), 304, 240)
    mu, cov = np.array([100.0, 80.0]), np.array(cov)
    assert pool.add(mu, cov, 1000, act=2.0)
    pool.book["recent"][0], pool.book["total"][0] = 8.0, 40.0
    assert pool.split(0, 1000)
    assert pool.n == 2
    (m1, c1), (m2, c2) = pool.gaussian(0), pool.gaussian(1)
    lam, vecs = np.linalg.eigh(cov)
    v = vecs[:, -1]
    off = 0.5 * math.sqrt(lam[-1]) * v
    half = cov - 0.25 * lam[-1] * np.outer(v, v)
    assert {tuple(np.round(m1 - mu, 9)), tuple(np.round(m2 - mu, 9))} == \
        {tuple(np.round(off, 9)), tuple(np.round(-off, 9))}
    np.testing.assert_allclose(c1, half, rtol=0, atol=1e-9)
    np.testing.assert_allclose(c2, half, rtol=0, atol=1e-9)
    np.testing.assert_allclose((m1 + m2) / 2, mu, rtol=0, atol=1e-9)
    mixture = (c1 + c2) / 2 + np.outer(m1 - m2, m1 - m2) / 4
    np.testing.assert_allclose(mixture, cov, rtol=0, atol=1e-9)
    # the activity and the event counts are shared out, not copied
    np.testing.assert_allclose(pool.activity(1000), [1.0, 1.0], rtol=1e-12)
    assert list(pool.book["recent"][:2]) == [4.0, 4.0] and list(pool.book["total"][:2]) == [20.0, 20.0]


def test_a_full_pool_does_not_split():
    pool = Pool(LearnParams(), 304, 240, capacity=1)
    assert pool.add(np.array([50.0, 50.0]), np.diag([16.0, 4.0]), 0)
    assert not pool.split(0, 0) and pool.n == 1
