"""The optimal bounding ellipsoid: hand cases against closed forms and a brute-force minimum-area search,
and random problems against the LP hull and sampled feasible points."""

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from h4bench.ident import Box, InconsistentDataError
from h4bench.ident.estimators.ellipsoid import ellipsoid, strip_update
from tests.ident.estimators import oracles


def _inside(E, pts, tol=1e-9):
    c = np.asarray(E["center"])
    S = np.asarray(E["shape"])
    d = pts - c
    return np.einsum("ij,ij->i", d, np.linalg.solve(S, d.T).T) <= 1.0 + tol


@pytest.mark.parametrize("n, h", [(2, 0.5), (3, 0.3), (14, 0.2)])
def test_symmetric_slab_closed_form(n, h):
    # unit ball cut by |t| <= h < 1/sqrt(n): the minimum-volume ellipsoid has semi-axis sqrt(n) h along the cut
    # and sqrt(n (1 - h^2) / (n - 1)) across (the ellipsoid through the corners; Groetschel, Lovasz &
    # Schrijver, Geometric Algorithms and Combinatorial Optimization, 1988, sec. 3.1)
    w = np.zeros(n)
    w[0] = 1.0
    c, P, cut = strip_update(np.zeros(n), np.eye(n), w, -h, h)
    assert cut
    np.testing.assert_allclose(c, 0.0, atol=1e-15)
    expected = np.full(n, n * (1 - h * h) / (n - 1))
    expected[0] = n * h * h
    np.testing.assert_allclose(P, np.diag(expected), rtol=1e-12, atol=1e-15)


def test_symmetric_slab_too_wide_does_not_cut():
    n = 4
    c, P, cut = strip_update(np.zeros(n), np.eye(n), np.eye(n)[0], -0.6, 0.6)  # 0.6 > 1/sqrt(4)
    assert not cut
    np.testing.assert_array_equal(P, np.eye(n))


@pytest.mark.parametrize("l, h", [(-0.3, 0.8), (0.2, 0.9), (-1.0, 0.1), (-0.95, -0.4)])
def test_disc_cut_by_slab_matches_brute_force_minimum_area(l, h):
    # the disc's intersection with l <= x <= h; by symmetry the minimum-area ellipsoid is axis-aligned with
    # centre (x0, 0): for given x0 and semi-axis a along x, the smallest semi-axis b across that contains the
    # boundary (sampled densely), then minimise a b over (x0, a) by nested 1-D searches
    s = np.linspace(0.0, 1.0, 4001)
    xa = np.arccos(np.clip(h, -1, 1))
    xb = np.arccos(np.clip(l, -1, 1))
    ang = xa + (xb - xa) * s
    bx = np.concatenate([np.cos(ang), np.full(s.size, l), np.full(s.size, h)])
    by = np.concatenate([np.sin(ang), np.sin(xb) * s, np.sin(xa) * s])

    def b_of(x0, a):
        q = 1.0 - ((bx - x0) / a) ** 2
        if np.any(q <= 0):
            return np.inf
        return float(np.sqrt(np.max(by**2 / q)))

    def best_a(x0):
        half = max(x0 - l, h - x0)
        r = minimize_scalar(lambda a: a * b_of(x0, a), bounds=(half * 1.0000001, 20 * half + 2), method="bounded",
                            options={"xatol": 1e-10})
        return r.fun

    r = minimize_scalar(best_a, bounds=(l, h), method="bounded", options={"xatol": 1e-10})
    area_oracle = r.fun
    c, P, cut = strip_update(np.zeros(2), np.eye(2), np.array([1.0, 0.0]), l, h)
    assert cut
    area = np.sqrt(np.linalg.det(P))
    assert abs(c[1]) < 1e-15 and abs(P[0, 1]) < 1e-15
    assert area == pytest.approx(area_oracle, rel=2e-4)
    assert c[0] == pytest.approx(r.x, abs=2e-3)
    # it contains the cut disc's boundary
    assert np.all(_inside({"center": c, "shape": P}, np.c_[bx, by]))


def test_one_dimensional_is_the_exact_interval():
    W = np.array([[2.0], [1.0], [-1.0]])
    y = np.array([1.0, 0.2, 0.1])
    b = np.array([0.5, 0.4, 0.3])
    # rows 1-2: [0.25, 0.75] ∩ [-0.2, 0.6] = [0.25, 0.6]; row 3 (-theta in [-0.2, 0.4]) adds [-0.4, 0.2]: empty
    box = ellipsoid(W[:2], y[:2], b[:2], Box([-2.0], [2.0]))
    np.testing.assert_allclose([box.lower[0], box.upper[0]], [0.25, 0.6], rtol=1e-12)
    with pytest.raises(InconsistentDataError):
        ellipsoid(W, y, b, Box([-2.0], [2.0]))


@pytest.mark.parametrize("seed, p, N", [(0, 2, 50), (1, 3, 400), (2, 4, 2000), (3, 6, 800)])
def test_contains_exact_hull_and_feasible_points(seed, p, N):
    rng = np.random.default_rng(seed)
    W, y, b, prior, theta = oracles.problem(rng, p, N)
    box = ellipsoid(W, y, b, prior)
    assert oracles.encloses_exact_hull(box, W, y, b, prior)
    pts = oracles.feasible_points(rng, W, y, b, prior)
    assert np.all(_inside(box.info["set"], pts))
    assert np.all(_inside(box.info["set"], theta[None, :]))
    assert box.info["cuts"] > 0
    assert np.all(box.width < prior.width)  # it does shrink on these problems
    S = np.asarray(box.info["set"]["shape"])
    assert np.all(np.linalg.eigvalsh(0.5 * (S + S.T)) > 0)


def test_initial_ellipsoid_contains_prior_corners():
    # no row cuts (huge bounds): the box is the prior and the ellipsoid contains every corner of the prior
    rng = np.random.default_rng(4)
    p = 4
    W = rng.normal(size=(10, p))
    prior = Box(-rng.uniform(1, 2, p), rng.uniform(1, 2, p))
    box = ellipsoid(W, np.zeros(10), np.full(10, 1e6), prior)
    assert box.info["cuts"] == 0
    np.testing.assert_array_equal(box.lower, prior.lower)
    corners = np.array(np.meshgrid(*zip(prior.lower, prior.upper))).reshape(p, -1).T
    assert np.all(_inside(box.info["set"], corners))


def test_attributes():
    assert ellipsoid.kind == "guaranteed" and ellipsoid.rigorous is False
    assert "Fogel" in ellipsoid.citation and ellipsoid.description


def test_critical_bounds_keep_the_truth():
    # not a proof (rigorous = False): a regression check of the shape inflation on cases where the truth lies
    # on the boundary of every strip (bounds = exact residuals rounded up)
    for seed in range(30):
        rng = np.random.default_rng(seed)
        W, y, b, theta = oracles.critical_case(rng, 2 + seed % 3, 40)
        box = ellipsoid(W, y, b, Box(theta - 0.05, theta + 0.05))
        assert box.contains(theta).all(), seed
        assert np.all(_inside(box.info["set"], theta[None, :], tol=0.0))
