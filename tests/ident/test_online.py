"""The online hull (ident.estimators.online.OnlineHull) against the batch hull of the same rows.

Oracle: ``ident.estimate(method="hull")`` on all rows seen so far (tested elsewhere against linprog and exact
rationals), and scipy's linprog on a small problem. Every intermediate box must contain the batch hull of the
rows seen so far, and after the last update the two must agree. Both are rigorous outer boxes of the same set,
each above the exact hull by its own safe-bound slack (measured up to 3e-9 for the batch box at 1480 rows,
LP tolerance 1e-9): containment and equality are judged at 1e-7 of the prior width. Against linprog (the exact
hull to its own tolerance) the online box must be outer to 1e-9.
"""

from __future__ import annotations


import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench import ident
from h4bench.ident.estimators.online import OnlineHull

TOL = 2e-7  # 1e-7 of the prior width (2)


def h4_like(seed: int, n_samples: int, p: int = 14):
    """Rows in time order, 4 per sample, smooth in time, columns of different scales; noise in +-1, bound 1."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) * 1e-3
    f = rng.uniform(0.3, 3.0, p)
    ph = rng.uniform(0, 2 * np.pi, p)
    scale = 10.0 ** rng.uniform(-1, 1.5, p)
    base = np.sin(2 * np.pi * f * t[:, None] + ph)
    W = (base[:, None, :] * scale * rng.uniform(0.5, 1.5, (1, 4, p))).reshape(-1, p)
    W += 0.3 * rng.standard_normal(W.shape) * scale  # keep it exciting
    theta = rng.uniform(0.5, 1.5, p)
    y = W @ theta + rng.uniform(-1, 1, W.shape[0])
    return W, y, theta


@pytest.mark.parametrize("chunk", [1, 40, 400])
def test_every_box_contains_the_batch_hull_and_the_last_equals_it(chunk):
    W, y, theta = h4_like(0, 300 if chunk == 1 else 1000, p=6 if chunk == 1 else 14)
    p = W.shape[1]
    prior = (np.zeros(p), 2.0 * np.ones(p))
    hull = OnlineHull(prior)
    previous = hull.box
    n = W.shape[0]
    check_every = max(1, (n // chunk) // 8)
    for c, s in enumerate(range(0, n, chunk)):
        e = min(n, s + chunk)
        box = hull.update(W[s:e], y[s:e], 1.0)
        assert box.contains(theta).all()
        assert np.all(box.lower >= previous.lower) and np.all(box.upper <= previous.upper)  # never grows
        previous = box
        if e >= p and (c % check_every == 0 or e == n):
            batch = ident.estimate(W[:e], y[:e], 1.0, prior)
            assert np.all(box.lower <= batch.lower + TOL) and np.all(box.upper >= batch.upper - TOL), e
    np.testing.assert_allclose(box.lower, batch.lower, atol=TOL)
    np.testing.assert_allclose(box.upper, batch.upper, atol=TOL)
    assert hull.rows_seen == n


def test_online_box_contains_the_linprog_hull():
    rng = np.random.default_rng(4)
    W = rng.standard_normal((60, 3))
    y = W @ np.array([1.0, 0.5, 1.5]) + rng.uniform(-1, 1, 60)
    hull = OnlineHull((np.zeros(3), 3 * np.ones(3)))
    for s in range(0, 60, 7):
        box = hull.update(W[s:s + 7], y[s:s + 7], np.ones(min(7, 60 - s)))
    A, rhs = np.vstack([W, -W]), np.concatenate([y + 1, 1 - y])
    for i in range(3):
        c = np.zeros(3)
        c[i] = 1
        lo = linprog(c, A_ub=A, b_ub=rhs, bounds=[(0, 3)] * 3, method="highs").fun
        hi = -linprog(-c, A_ub=A, b_ub=rhs, bounds=[(0, 3)] * 3, method="highs").fun
        assert box.lower[i] <= lo + 1e-9 and box.upper[i] >= hi - 1e-9
        assert box.lower[i] == pytest.approx(lo, abs=1e-7) and box.upper[i] == pytest.approx(hi, abs=1e-7)


def test_untouched_endpoints_are_not_resolved():
    """A row that cuts off none of the current optimal points re-solves nothing."""
    W, y, _ = h4_like(1, 500, p=4)
    hull = OnlineHull((np.zeros(4), 2 * np.ones(4)))
    hull.update(W, y, 1.0)
    before = hull.stats["lp_solves"]
    box = hull.update(np.zeros((1, 4)), np.zeros(1), 1.0)  # |0 - 0 theta| <= 1: satisfied everywhere
    assert box.info["resolved"] == [] and hull.stats["lp_solves"] == before


def test_a_block_that_contradicts_the_bound_is_rejected_and_leaves_no_trace():
    W, y, _ = h4_like(2, 200, p=4)
    prior = (np.zeros(4), 2 * np.ones(4))
    hull = OnlineHull(prior)
    hull.update(W[:400], y[:400], 1.0)
    before = hull.box
    bad_y = y[400:440].copy()
    bad_y[5] += 100.0
    with pytest.raises(ident.InconsistentDataError) as err:
        hull.update(W[400:440], bad_y, 1.0)
    assert err.value.min_bound > 1.0
    assert hull.rows_seen == 400
    np.testing.assert_array_equal(hull.box.lower, before.lower)
    np.testing.assert_array_equal(hull.box.upper, before.upper)
    # the object goes on: the next blocks are added as if the rejected one had never come
    box = hull.update(W[440:800], y[440:800], 1.0)
    keep = np.r_[0:400, 440:800]
    batch = ident.estimate(W[keep], y[keep], 1.0, prior)
    np.testing.assert_allclose(box.lower, batch.lower, atol=TOL)
    np.testing.assert_allclose(box.upper, batch.upper, atol=TOL)


def test_bad_inputs_are_named():
    hull = OnlineHull(ident.Box(np.zeros(3), np.ones(3)))
    with pytest.raises(ValueError, match=r"W_rows must have shape \(k, 3\)"):
        hull.update(np.ones((2, 4)), np.ones(2), 1.0)
    with pytest.raises(ValueError, match=r"y_rows must have shape \(2,\)"):
        hull.update(np.ones((2, 3)), np.ones(3), 1.0)
    with pytest.raises(ValueError, match="bound_rows must be a scalar or have shape"):
        hull.update(np.ones((2, 3)), np.ones(2), np.ones(3))
    with pytest.raises(ValueError, match="bound_rows must be finite and > 0"):
        hull.update(np.ones((2, 3)), np.ones(2), 0.0)
    with pytest.raises(ValueError, match="W_rows must be finite"):
        hull.update(np.full((2, 3), np.nan), np.ones(2), 1.0)
    with pytest.raises(ValueError, match="prior lower and upper must have shape"):
        OnlineHull((np.zeros(3), np.ones(3)), p=4)
    with pytest.raises(ValueError, match="p must be an integer >= 1"):
        OnlineHull((np.zeros(3), np.ones(3)), p=0)
    with pytest.raises(ValueError, match="prior must be finite"):
        OnlineHull((np.zeros(3), np.full(3, np.inf)))
    assert hull.rows_seen == 0  # nothing was added by the rejected updates


def test_endpoints_stopped_by_the_lp_budget_keep_safe_bounds(monkeypatch):
    """Every HiGHS run limited to 3 iterations: the updates still end, the fallbacks are counted, and every box
    contains the unlimited online hull's box at the same row (itself linprog's hull: the tests above)."""
    from h4bench.ident.numerics import lp
    from tests.conftest import bounded_noise_problem

    W, theta, y = bounded_noise_problem(np.random.default_rng(2), 600, 4)
    prior = (np.zeros(4), 3 * np.ones(4))

    def boxes():
        hull = OnlineHull(prior)
        return [hull.update(W[s:s + 150], y[s:s + 150], 1.0) for s in range(0, 600, 150)], hull.stats

    full, stats = boxes()
    assert stats["lp_limit_hits"] == stats["lp_fallbacks"] == 0
    monkeypatch.setattr(lp, "ITERATIONS_FLOOR", 3)
    monkeypatch.setattr(lp, "ITERATIONS_PER_LINE", 0)
    cut, stats = boxes()
    assert stats["lp_fallbacks"] >= 1 and stats["lp_retries"] >= stats["lp_fallbacks"]
    for a, b in zip(cut, full):
        assert np.all(a.lower <= b.lower) and np.all(a.upper >= b.upper) and a.contains(theta).all()
