"""The zonotope estimator: random problems against the LP hull and sampled feasible points (zonotope
membership by an LP), the order reduction's containment, and hand cases."""

import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench.ident import Box, InconsistentDataError
from h4bench.ident.estimators.zonotope import _reduce, parallelotope, zonotope, zonotope_at
from tests.ident.estimators import oracles


def _in_zonotope(Z, x, tol=1e-9):
    """x in c + G xi with |xi|_inf <= 1 + tol (an LP feasibility problem)."""
    c = np.asarray(Z["center"])
    G = np.asarray(Z["generators"])
    m = G.shape[1]
    res = linprog(np.zeros(m), A_eq=G, b_eq=x - c, bounds=[(-1 - tol, 1 + tol)] * m, method="highs")
    return res.status == 0


@pytest.mark.parametrize("seed, p, N, order", [(0, 2, 50, 3), (1, 3, 400, 2), (2, 4, 2000, 3), (3, 6, 600, 3)])
def test_contains_exact_hull_and_feasible_points(seed, p, N, order):
    rng = np.random.default_rng(seed)
    W, y, b, prior, theta = oracles.problem(rng, p, N)
    box = zonotope(W, y, b, prior, order=order)
    assert oracles.encloses_exact_hull(box, W, y, b, prior)
    Z = box.info["set"]
    assert np.asarray(Z["generators"]).shape[1] <= (order + 1) * p
    pts = oracles.feasible_points(rng, W, y, b, prior, vertices=10, walk=60)
    assert all(_in_zonotope(Z, x) for x in pts)
    assert _in_zonotope(Z, theta)
    assert np.all(box.width < prior.width)


def test_reduction_contains_the_original():
    # every vertex candidate c + G xi (xi random signs) of the original lies in the reduced zonotope
    rng = np.random.default_rng(7)
    G = rng.normal(size=(3, 15))
    R = _reduce(G, 3)
    assert R.shape == (3, 6)
    Z = {"center": np.zeros(3), "generators": R}
    for _ in range(40):
        x = G @ rng.choice([-1.0, 1.0], 15)
        assert _in_zonotope(Z, x)
    np.testing.assert_allclose(np.abs(R).sum(1), np.abs(G).sum(1), rtol=1e-12)  # same interval hull


def test_axis_strip_in_two_dimensions():
    # one row theta1 in [0.2, 0.4] inside the prior [-1, 1]^2: the zonotope contains [0.2, 0.4] x [-1, 1]
    # and its box along theta1 is no wider than the prior
    box = zonotope(np.array([[1.0, 0.0]]), np.array([0.3]), np.array([0.1]), Box([-1.0, -1.0], [1.0, 1.0]))
    for x in ([0.2, -1.0], [0.2, 1.0], [0.4, -1.0], [0.4, 1.0]):
        assert _in_zonotope(box.info["set"], np.array(x))
    assert box.upper[0] < 1.0 and box.lower[0] > -1.0
    # the F-radius update on an axis-aligned box and strip: lambda = (G G^T w) / (w^T G G^T w + b^2) = e1/(1+0.01),
    # centre 0.3 / 1.01, generators diag(0.01/1.01, 1) and 0.1 e1 / 1.01: half-width (0.01 + 0.1) / 1.01
    assert box.upper[0] == pytest.approx(0.3 / 1.01 + 0.11 / 1.01, rel=1e-12)


def test_strip_missing_raises_and_non_cutting_rows_are_skipped():
    prior = Box([-1.0, -1.0], [1.0, 1.0])
    with pytest.raises(InconsistentDataError):
        zonotope(np.array([[1.0, 1.0]]), np.array([5.0]), np.array([0.1]), prior)
    box = zonotope(np.array([[1.0, 1.0]]), np.array([0.0]), np.array([3.0]), prior)
    assert box.info["cuts"] == 0
    np.testing.assert_array_equal(box.lower, prior.lower)


def test_factory_and_attributes():
    f = zonotope_at(2)
    assert f.kind == "guaranteed" and f.rigorous is False and "Alamo" in f.citation
    rng = np.random.default_rng(1)
    W, y, b, prior, _ = oracles.problem(rng, 3, 100)
    a, z = f(W, y, b, prior), zonotope(W, y, b, prior, order=2)
    np.testing.assert_array_equal(a.lower, z.lower)
    np.testing.assert_array_equal(a.upper, z.upper)
    assert not np.array_equal(zonotope(W, y, b, prior, order=1).lower, z.lower)
    with pytest.raises(ValueError, match="order"):
        zonotope_at(0)
    assert zonotope.kind == "guaranteed" and zonotope.rigorous is False


@pytest.mark.parametrize("seed, p, N", [(0, 2, 50), (1, 3, 400), (2, 4, 2000), (3, 6, 600)])
def test_parallelotope_contains_exact_hull_and_feasible_points(seed, p, N):
    rng = np.random.default_rng(seed)
    W, y, b, prior, theta = oracles.problem(rng, p, N)
    box = parallelotope(W, y, b, prior)
    assert oracles.encloses_exact_hull(box, W, y, b, prior)
    Z = box.info["set"]
    assert np.asarray(Z["generators"]).shape == (p, p)
    pts = oracles.feasible_points(rng, W, y, b, prior, vertices=10, walk=60)
    assert all(_in_zonotope(Z, x) for x in pts)
    assert np.all(box.width < prior.width)


def test_parallelotope_hand_case():
    # the square [-1, 1]^2 and the strip |t1 + t2| <= 0.5: both generators have w^T g = 1, the first is replaced
    # (argmax takes the first): generators [e1 - e1, e2 - e1] = [0, (-1, 1)] then g1 = 0.5 e1, so the
    # parallelotope {(0.5 a - b, b)}: the box [-1.5, 1.5] x [-1, 1] ∩ prior = the prior (by hand), and the
    # parallelotope has area 4 * 0.5 = 2 (|det G| b / |w^T g_j| * 4 with det 1)
    box = parallelotope(np.array([[1.0, 1.0]]), np.array([0.0]), np.array([0.5]), Box([-1.0, -1.0], [1.0, 1.0]))
    G = np.asarray(box.info["set"]["generators"])
    np.testing.assert_allclose(G, [[0.5, -1.0], [0.0, 1.0]], atol=1e-15)
    assert 4 * abs(np.linalg.det(G)) == pytest.approx(2.0)
    # the cut square itself has area 4 - 2 * 1.5^2 / 2 = 1.75 (two corner triangles with legs 1.5 removed)
    assert 4 * abs(np.linalg.det(G)) >= 1.75
    assert parallelotope.kind == "guaranteed" and parallelotope.rigorous is False and "Chisci" in parallelotope.citation


@pytest.mark.parametrize("f", [zonotope, parallelotope])
def test_critical_bounds_keep_the_truth(f):
    # not a proof (rigorous = False): a regression check of the strip-widening safeguard on cases where the
    # truth lies on the boundary of every strip (bounds = exact residuals rounded up)
    for seed in range(30):
        rng = np.random.default_rng(seed)
        W, y, b, theta = oracles.critical_case(rng, 2 + seed % 3, 40)
        box = f(W, y, b, Box(theta - 0.05, theta + 0.05))
        assert box.contains(theta).all(), seed


def _row_by_row(monkeypatch, f, *args):
    """``f`` with every row visited (the batched skip test answering False: the plain sequential loop)."""
    from h4bench.ident.estimators import zonotope as zmod

    with monkeypatch.context() as m:
        m.setattr(zmod, "_parallelotope_skips", lambda Wb, *a: np.zeros(len(Wb), dtype=bool))
        return f(*args)


@pytest.mark.parametrize("seed", range(6))
def test_parallelotope_skipping_rows_in_blocks_is_the_row_by_row_result_bit_for_bit(seed, monkeypatch):
    # the oracle is the same estimator visiting every row; scales from 1e-3 to 1e3 and critical bounds (the truth
    # on every strip's edge: rows at the margin of the skip test)
    rng = np.random.default_rng(100 + seed)
    if seed % 2:
        W, y, b, theta = oracles.critical_case(rng, 3 + seed % 4, 3000)
        prior = Box(theta - 0.05, theta + 0.05)
    else:
        W, y, b, prior, _ = oracles.problem(rng, 4 + seed, 3000, noise=0.01)
        s = 10.0 ** rng.uniform(-3, 3, W.shape[1])  # W theta = (W s)(theta / s): the same problem rescaled
        W, prior = W * s, Box(prior.lower / s, prior.upper / s)
    fast = parallelotope(W, y, b, prior)
    slow = _row_by_row(monkeypatch, parallelotope, W, y, b, prior)
    assert np.array_equal(fast.lower, slow.lower) and np.array_equal(fast.upper, slow.upper)
    assert fast.info["cuts"] == slow.info["cuts"] and fast.info["set"] == slow.info["set"]
    assert fast.info["cuts"] < len(W)  # rows were skipped, some of them in blocks


def test_the_row_scan_visits_exactly_the_rows_its_test_cannot_skip():
    from h4bench.ident.estimators._common import RowScan

    rng = np.random.default_rng(5)
    N = 1000
    hard = rng.uniform(size=N) < 0.05  # rows a test never skips; every third of them "changes the set"
    tested = []

    def test(k, end):
        tested.append((k, end))
        return ~hard[k:end]

    scan = RowScan(N, test, first=4, largest=64)
    visited = []
    for k in scan:
        visited.append(k)
        if len(visited) % 3 == 0:
            scan.changed = True
    assert visited == list(np.flatnonzero(hard))
    assert tested[0] == (0, 4) and max(e - k for k, e in tested) == 64 and tested[-1][1] == N
    # after a changed row the next test starts right after it
    changed_rows = visited[2::3]
    starts = {k for k, _ in tested}
    assert all(r + 1 in starts for r in changed_rows if r + 1 < N)
