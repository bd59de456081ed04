"""The q-relaxed hull (ident.estimators.outliers) against a brute-force oracle over row subsets.

Oracle: the hull of S_q is the union, over every set R of exactly q discarded rows (discarding fewer never
gives more), of the hulls of the remaining rows, each computed by scipy.optimize.linprog (all rows at once, no
constraint generation, no safe bounds: independent of ident.estimators.hull). On tiny problems (m <= 13 rows, p <= 3,
q <= 3: at most 286 subsets) the exact method must equal it within LP tolerance and contain it; the fast
groups method must contain it. Certain outliers are checked against the oracle too: a certain row must miss
the feasible set of every subset.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench import ident
from h4bench.ident.estimators.outliers import OutlierBudgetError, detect_outliers, relaxed_hull
from tests.conftest import bounded_noise_problem


def lp_hull(W, y, b, lo, hi):
    """(lower, upper) of {theta in [lo, hi] : |y - W theta| <= b} by 2p linprog calls, or None if empty."""
    A = np.vstack([W, -W])
    rhs = np.concatenate([y + b, b - y])
    bounds = list(zip(lo, hi))
    out_lo, out_hi = [], []
    for i in range(W.shape[1]):
        c = np.zeros(W.shape[1])
        c[i] = 1.0
        r1 = linprog(c, A_ub=A, b_ub=rhs, bounds=bounds, method="highs")
        if r1.status == 2:
            return None
        r2 = linprog(-c, A_ub=A, b_ub=rhs, bounds=bounds, method="highs")
        out_lo.append(r1.fun)
        out_hi.append(-r2.fun)
    return np.array(out_lo), np.array(out_hi)


def brute_force(W, y, b, lo, hi, q):
    """Hull of S_q as the union of LP hulls over all subsets of q discarded rows; also the feasible subsets."""
    m, p = W.shape
    L, U = np.full(p, np.inf), np.full(p, -np.inf)
    feasible = []
    for R in itertools.combinations(range(m), q):
        keep = np.setdiff1d(np.arange(m), R)
        res = lp_hull(W[keep], y[keep], b[keep], lo, hi)
        if res is None:
            continue
        feasible.append(keep)
        L, U = np.minimum(L, res[0]), np.maximum(U, res[1])
    return L, U, feasible


def tiny_problem(seed: int):
    """3 families: gross outliers (detectable), mild outliers (1-2.5 bounds: not certain), q above the count."""
    rng = np.random.default_rng(seed)
    p = int(rng.integers(2, 4))
    m = int(rng.integers(8, 14))
    q = int(rng.integers(1, 4))
    W = rng.standard_normal((m, p)) * rng.uniform(0.3, 3.0, p)
    theta = rng.uniform(0.5, 1.5, p)
    b = rng.uniform(0.5, 1.5, m) if seed % 2 else np.ones(m)
    y = W @ theta + rng.uniform(-1, 1, m) * b
    kind = seed % 3
    n_bad = q if kind == 0 else max(q - 1, 1)
    bad = rng.choice(m, n_bad, replace=False)
    size = rng.uniform(2.5, 6.0, n_bad) if kind == 0 else rng.uniform(1.0, 2.5, n_bad)
    y[bad] += rng.choice([-1.0, 1.0], n_bad) * size * b[bad]
    lo, hi = np.zeros(p), 3.0 * np.ones(p)
    return W, y, b, lo, hi, q, theta


@pytest.mark.parametrize("seed", range(15))
def test_exact_equals_brute_force_and_groups_contain_it(seed):
    W, y, b, lo, hi, q, theta = tiny_problem(seed)
    L, U, feasible = brute_force(W, y, b, lo, hi, q)
    assert feasible, "the oracle problem must be consistent with q outliers"
    ex = relaxed_hull(W, y, b, (lo, hi), q, method="exact")
    gr = relaxed_hull(W, y, b, (lo, hi), q, method="groups")
    scale = hi - lo
    # outer: rigorous endpoints may only be outside the exact hull (the oracle's own LP error is ~1e-9)
    assert np.all(ex.lower <= L + 1e-9 * scale) and np.all(ex.upper >= U - 1e-9 * scale)
    assert np.all(gr.lower <= L + 1e-9 * scale) and np.all(gr.upper >= U - 1e-9 * scale)
    # exact: equal within the LP tolerance and the search's pruning tolerance (1e-7 of the width)
    assert ex.info["exact"]
    np.testing.assert_allclose(ex.lower, L, atol=1e-6 * scale.max())
    np.testing.assert_allclose(ex.upper, U, atol=1e-6 * scale.max())
    assert np.all(gr.width >= ex.width - 1e-9)


@pytest.mark.parametrize("seed", [0, 3, 7])
def test_certain_outliers_miss_every_feasible_subset(seed):
    """A certain row must be violated by every theta of S_q: its strip misses the set of each feasible subset."""
    W, y, b, lo, hi, q, _ = tiny_problem(seed)
    _, _, feasible = brute_force(W, y, b, lo, hi, q)
    box = relaxed_hull(W, y, b, (lo, hi), q, method="exact")
    certain = box.info["certain_rows"]
    for k in certain:
        for keep in feasible:
            rows = np.union1d(keep, [k])
            assert lp_hull(W[rows], y[rows], b[rows], lo, hi) is None, (k, keep)
    assert set(certain) <= set(box.info["suspected_rows"])


def test_gross_outliers_are_certain_and_the_truth_is_enclosed():
    rng = np.random.default_rng(42)
    m, p = 200, 4
    W, theta, y = bounded_noise_problem(rng, m, p)
    bad = np.array([5, 50, 120])
    y[bad] += np.array([8.0, -9.0, 7.0])
    with pytest.raises(ident.InconsistentDataError):
        ident.estimate(W, y, 1.0, (np.zeros(p), 3 * np.ones(p)))
    box = relaxed_hull(W, y, 1.0, (np.zeros(p), 3 * np.ones(p)), 4)
    assert box.contains(theta).all()
    assert set(bad.tolist()) <= set(box.info["certain_rows"])
    rows = detect_outliers(W, y, 1.0, box)
    assert set(bad.tolist()) <= set(rows.certain.tolist())


def test_highs_milp_agrees_with_the_certified_search():
    """HiGHS's own MILP solver (an independent branch and bound) on the same formulation gives the same values."""
    W, y, b, lo, hi, q, _ = tiny_problem(4)
    box = relaxed_hull(W, y, b, (lo, hi), q, method="exact", highs_milp=True)
    L, U, _ = brute_force(W, y, b, lo, hi, q)
    if "milp_objective" not in box.info:  # every row decided by the reductions: nothing left for a MILP
        pytest.skip("no undecided rows")
    p = W.shape[1]
    milp = np.array(box.info["milp_objective"], dtype=float)
    np.testing.assert_allclose(milp[:p], L, atol=1e-6)
    np.testing.assert_allclose(milp[p:], U, atol=1e-6)


def test_node_budget_keeps_the_box_outer():
    W, y, b, lo, hi, q, _ = tiny_problem(1)
    L, U, _ = brute_force(W, y, b, lo, hi, q)
    box = relaxed_hull(W, y, b, (lo, hi), q, method="exact", max_nodes=1)
    assert np.all(box.lower <= L + 1e-9) and np.all(box.upper >= U - 1e-9)
    if "certified" in box.info:
        assert not box.info["exact"] or all(box.info["certified"])


@pytest.mark.parametrize("groups", [None, 2, (3,), (2, 5, 7)])
def test_group_counts_are_all_outer(groups):
    W, y, b, lo, hi, _, _ = tiny_problem(2)
    q = 1
    L, U, _ = brute_force(W, y, b, lo, hi, q)
    box = relaxed_hull(W, y, b, (lo, hi), q, method="groups", groups=groups)
    assert np.all(box.lower <= L + 1e-9) and np.all(box.upper >= U - 1e-9)


def test_q_zero_is_the_plain_hull():
    rng = np.random.default_rng(3)
    W = rng.standard_normal((60, 3))
    y = W @ np.ones(3) + rng.uniform(-1, 1, 60)
    prior = (np.zeros(3), 3 * np.ones(3))
    plain = ident.estimate(W, y, 1.0, prior)
    box = relaxed_hull(W, y, 1.0, prior, 0)
    np.testing.assert_allclose(box.lower, plain.lower, atol=1e-12)
    np.testing.assert_allclose(box.upper, plain.upper, atol=1e-12)
    assert box.info["exact"]


def test_more_outliers_than_q_is_reported():
    rng = np.random.default_rng(5)
    W = rng.standard_normal((40, 2))
    y = W @ np.ones(2) + rng.uniform(-1, 1, 40)
    y[[1, 2, 3, 4]] += 20.0
    with pytest.raises(OutlierBudgetError) as err:
        relaxed_hull(W, y, 1.0, (np.zeros(2), 3 * np.ones(2)), 2)
    assert isinstance(err.value, ident.InconsistentDataError)
    assert err.value.q == 2 and "q = 2" in str(err.value)


@pytest.mark.parametrize("kwargs, match", [
    ({"q": -1}, "q must be an integer with 0 <= q < m"),
    ({"q": 40}, "q must be an integer with 0 <= q < m = 40"),
    ({"q": 1.5}, "q must be an integer"),
    ({"q": True}, "q must be an integer"),
    ({"q": 2, "method": "milp"}, "method must be one of"),
    ({"q": 2, "groups": 2}, "groups must each be between q \\+ 1 = 3"),
    ({"q": 2, "groups": (3, "x")}, "groups must be"),
    ({"q": 2, "max_nodes": 0}, "max_nodes must be an integer >= 1"),
    ({"q": 2, "time_limit": -1.0}, "time_limit must be a finite number > 0"),
])
def test_bad_arguments_are_named(kwargs, match):
    rng = np.random.default_rng(0)
    W = rng.standard_normal((40, 2))
    y = W @ np.ones(2)
    with pytest.raises((ValueError, TypeError), match=match):
        relaxed_hull(W, y, 1.0, (np.zeros(2), np.ones(2) * 3), **kwargs)


def test_bad_data_are_named():
    W = np.ones((10, 2))
    with pytest.raises(ValueError, match="W must have shape"):
        relaxed_hull(np.ones(10), np.ones(10), 1.0, (np.zeros(1), np.ones(1)), 1)
    with pytest.raises(ValueError, match="y must have shape"):
        relaxed_hull(W, np.ones(9), 1.0, (np.zeros(2), np.ones(2)), 1)
    with pytest.raises(ValueError, match="bound must be finite and > 0"):
        relaxed_hull(W, np.ones(10), -1.0, (np.zeros(2), np.ones(2)), 1)
    with pytest.raises(ValueError, match="prior lower and upper must have shape"):
        relaxed_hull(W, np.ones(10), 1.0, (np.zeros(3), np.ones(3)), 1)
    with pytest.raises(ValueError, match="prior lower and upper must have shape"):
        detect_outliers(W, np.ones(10), 1.0, (np.zeros(3), np.ones(3)))


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(15, 75))
def test_exact_equals_brute_force_more_seeds(seed):
    test_exact_equals_brute_force_and_groups_contain_it(seed)


@pytest.mark.slow
def test_exact_is_inside_groups_on_a_medium_problem():
    """200 rows, p = 6, 3 outliers under q = 4: the certified search finishes and is inside the groups box."""
    rng = np.random.default_rng(200)
    m, p = 200, 6
    W, theta, y = bounded_noise_problem(rng, m, p)
    bad = rng.choice(m, 3, replace=False)
    y[bad] += rng.choice([-1, 1], 3) * rng.uniform(1.5, 4, 3)
    prior = (np.zeros(p), 3 * np.ones(p))
    groups = relaxed_hull(W, y, 1.0, prior, 4, method="groups")
    exact = relaxed_hull(W, y, 1.0, prior, 4, method="exact")
    assert exact.info["exact"] and exact.contains(theta).all()
    assert np.all(exact.lower >= groups.lower) and np.all(exact.upper <= groups.upper)
