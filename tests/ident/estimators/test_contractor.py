"""The forward-backward interval contractor: outer enclosure of the exact hull (LP oracle), known fixed
points, an exact-rational re-implementation, rigour at critical bounds, inconsistency."""

from fractions import Fraction

import numpy as np
import pytest

from h4bench.ident import Box, InconsistentDataError
from h4bench.ident.estimators.contractor import contract, contractor
from tests.ident.estimators import oracles


@pytest.mark.parametrize("seed, p, N, hw", [(0, 2, 50, 1.0), (1, 3, 300, 0.3), (2, 4, 2000, 0.2), (3, 6, 500, 0.1)])
def test_contains_exact_hull_and_feasible_points(seed, p, N, hw):
    rng = np.random.default_rng(seed)
    W, y, b, prior, theta = oracles.problem(rng, p, N, prior_halfwidth=hw)
    box = contractor(W, y, b, prior)
    assert oracles.encloses_exact_hull(box, W, y, b, prior)
    pts = oracles.feasible_points(rng, W, y, b, prior, vertices=5, walk=100)
    assert all(box.contains(x).all() for x in pts)
    assert box.contains(theta).all()
    assert np.all(box.width <= prior.width)


def test_contracts_where_rows_are_sparse():
    # a permuted diagonal system: row k involves one parameter, so one sweep gives the exact box
    # ((y - b) / w, (y + b) / w) ∩ prior, computed here by hand
    rng = np.random.default_rng(5)
    p = 5
    perm = rng.permutation(p)
    w = rng.uniform(0.5, 2.0, p) * rng.choice([-1.0, 1.0], p)
    W = np.zeros((p, p))
    W[np.arange(p), perm] = w
    theta = rng.normal(size=p)
    y = W @ theta
    b = np.full(p, 0.01)
    prior = Box(theta - 1.0, theta + 1.0)
    box = contractor(W, y, b, prior)
    a = (y - b) / w
    c = (y + b) / w
    lo = np.empty(p)
    hi = np.empty(p)
    lo[perm] = np.minimum(a, c)
    hi[perm] = np.maximum(a, c)
    np.testing.assert_allclose(box.lower, lo, rtol=0, atol=1e-14)
    np.testing.assert_allclose(box.upper, hi, rtol=0, atol=1e-14)
    assert np.all(box.lower <= lo) and np.all(box.upper >= hi)  # rounded outward


def test_projection_fixed_point_is_not_the_hull():
    # |t1 + t2| <= 1, |t1 - t2| <= 1 in [-10, 10]^2: each row's projection on t1 is [-1, 1] - [-10, 10] =
    # [-11, 11], wider than the prior, so the prior is the contractor's fixed point (the hull is [-1, 1]^2)
    W = np.array([[1.0, 1.0], [1.0, -1.0]])
    box = contractor(W, np.zeros(2), np.ones(2), Box([-10.0, -10.0], [10.0, 10.0]))
    np.testing.assert_array_equal(box.lower, [-10.0, -10.0])
    np.testing.assert_array_equal(box.upper, [10.0, 10.0])
    # with a prior of [-1.5, 1.5]^2 the projection [-1, 1] - [-1.5, 1.5] = [-2.5, 2.5] does not contract either,
    # but [-0.8, 0.8] x [-10, 10] contracts t2 to [-1.8, 1.8] in one sweep, then stops
    box = contractor(W, np.zeros(2), np.ones(2), Box([-0.8, -10.0], [0.8, 10.0]))
    np.testing.assert_allclose(box.upper, [0.8, 1.8], rtol=1e-14)
    np.testing.assert_allclose(box.lower, [-0.8, -1.8], rtol=1e-14)


def _exact_sweeps(W, y, b, lo, hi, sweeps):
    """The same Jacobi sweep in exact rational arithmetic (fractions), ``sweeps`` times."""
    N, p = W.shape
    Wq = [[Fraction(float(v)) for v in row] for row in W]
    ylo = [Fraction(float(y[k])) - Fraction(float(b[k])) for k in range(N)]
    yhi = [Fraction(float(y[k])) + Fraction(float(b[k])) for k in range(N)]
    lo = [Fraction(float(v)) for v in lo]
    hi = [Fraction(float(v)) for v in hi]
    for _ in range(sweeps):
        nlo, nhi = list(lo), list(hi)
        for k in range(N):
            tl = [min(Wq[k][j] * lo[j], Wq[k][j] * hi[j]) for j in range(p)]
            th = [max(Wq[k][j] * lo[j], Wq[k][j] * hi[j]) for j in range(p)]
            sl, sh = sum(tl), sum(th)
            for j in range(p):
                if Wq[k][j] == 0:
                    continue
                a = (ylo[k] - (sh - th[j])) / Wq[k][j]
                c = (yhi[k] - (sl - tl[j])) / Wq[k][j]
                nlo[j] = max(nlo[j], min(a, c))
                nhi[j] = min(nhi[j], max(a, c))
        lo, hi = nlo, nhi
    return np.array([float(v) for v in lo]), np.array([float(v) for v in hi]), lo, hi


def test_equals_exact_rational_reimplementation():
    rng = np.random.default_rng(11)
    W, y, b, prior, theta = oracles.problem(rng, 3, 12, prior_halfwidth=0.3)
    lo, hi, sweeps = contract(W, y, b, prior.lower, prior.upper, tol=1e-300, max_sweeps=6)
    assert sweeps == 6
    elo, ehi, qlo, qhi = _exact_sweeps(W, y, b, prior.lower, prior.upper, 6)
    assert np.any(ehi - elo < prior.width)  # the case does contract
    # outward: the float box contains the exact one (compared exactly), and is within rounding of it
    assert all(Fraction(float(lo[j])) <= qlo[j] and Fraction(float(hi[j])) >= qhi[j] for j in range(3))
    np.testing.assert_allclose(lo, elo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(hi, ehi, rtol=0, atol=1e-12)


def _naive(W, y, b, lo, hi, sweeps=50):
    """The contractor without outward rounding (for comparison only)."""
    for _ in range(sweeps):
        t1, t2 = W * lo, W * hi
        tl, th = np.minimum(t1, t2), np.maximum(t1, t2)
        sl, sh = tl.sum(1), th.sum(1)
        a = ((y - b)[:, None] - (sh[:, None] - th)) / W
        c = ((y + b)[:, None] - (sl[:, None] - tl)) / W
        lo = np.maximum(lo, np.minimum(a, c).max(0))
        hi = np.minimum(hi, np.maximum(a, c).min(0))
    return lo, hi


def test_critical_bounds_keep_the_truth():
    naive_cuts = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        W, y, b, theta = oracles.critical_case(rng, 2, 6)
        prior = Box(theta - 1e-3, theta + 1e-3)
        box = contractor(W, y, b, prior, tol=1e-12)
        assert box.contains(theta).all(), seed
        nlo, nhi = _naive(W, y, b, prior.lower.copy(), prior.upper.copy())
        naive_cuts += int(not (np.all(nlo <= theta) and np.all(theta <= nhi)))
    # the case is sharp: rounding to nearest alone loses the truth in some of these cases
    assert naive_cuts > 0


def test_inconsistent_data_raise():
    W = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    y = np.array([0.0, 1.0, 0.0])
    with pytest.raises(InconsistentDataError) as err:
        contractor(W, y, np.full(3, 0.1), Box([-5.0, -5.0], [5.0, 5.0]))
    assert err.value.min_bound == pytest.approx(0.5, rel=1e-6)


def test_attributes_and_bad_input():
    assert contractor.kind == "guaranteed" and contractor.rigorous is True
    assert "Jaulin" in contractor.citation and contractor.description
    with pytest.raises(ValueError, match="bound"):
        contractor(np.eye(2), np.zeros(2), np.array([1.0, -1.0]), Box([-1.0, -1.0], [1.0, 1.0]))
    # the one validator of the protocol: a (lower, upper) pair is a prior like the Box (default names)
    pair = contractor(np.eye(2), np.zeros(2), 1.0, ([-1.0, -1.0], [1.0, 1.0]))
    boxed = contractor(np.eye(2), np.zeros(2), 1.0, Box([-1.0, -1.0], [1.0, 1.0]))
    np.testing.assert_array_equal(pair.lower, boxed.lower)
    np.testing.assert_array_equal(pair.upper, boxed.upper)
    with pytest.raises(TypeError, match="prior"):
        contractor(np.eye(2), np.zeros(2), 1.0, "[-1, 1]")
    with pytest.raises(ValueError, match="y"):
        contractor(np.eye(2), np.zeros(3), 1.0, Box([-1.0, -1.0], [1.0, 1.0]))
