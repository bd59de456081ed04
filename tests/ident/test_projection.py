"""Projections of the feasible polytope (:mod:`ident.estimators.projection`) against independent feasible points.

The oracles: scipy's linprog (HiGHS through scipy, not the project's model) for the Chebyshev centre and for
LP vertices with random costs, hit-and-run random points from that centre (Smith 1984), the hull's intervals
(:func:`ident.estimate`, method ``hull``), and brute-force enumerations for the zonogon and the ellipse.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench import ident
from h4bench.ident.estimators import projection as P
from h4bench.ident.estimators.support import SupportLP


def _problem(seed, m=300, p=5):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.5, 1.5, p)
    W = rng.standard_normal((m, p)) * 10.0 ** rng.uniform(-1, 1, p)
    W[:, 1] = W[:, 0] * 0.9 + 0.1 * W[:, 1]  # two coupled parameters
    b = rng.uniform(0.2, 0.5, m)
    y = W @ theta + rng.uniform(-1, 1, m) * b
    lo, hi = np.zeros(p), 3.0 * np.ones(p)
    return W, y, b, lo, hi, theta, rng


def _inequalities(W, y, b, lo, hi):
    p = W.shape[1]
    A = np.vstack([W, -W, np.eye(p), -np.eye(p)])
    rhs = np.concatenate([y + b, b - y, hi, -lo])
    return A, rhs


def _feasible_points(W, y, b, lo, hi, rng, n_walk=300, n_lp=20):
    """Hit-and-run points from the Chebyshev centre and LP vertices of random costs (scipy's linprog)."""
    A, rhs = _inequalities(W, y, b, lo, hi)
    p = W.shape[1]
    norms = np.linalg.norm(A, axis=1)
    res = linprog(np.r_[np.zeros(p), -1.0], A_ub=np.hstack([A, norms[:, None]]), b_ub=rhs,
                  bounds=[(None, None)] * p + [(0, None)], method="highs")
    assert res.status == 0 and res.x[-1] > 0  # a non-empty interior
    x = res.x[:p]
    pts = [x.copy()]
    for _ in range(n_walk):
        d = rng.standard_normal(p)
        ad, slack = A @ d, rhs - A @ x
        tmax = np.min(slack[ad > 0] / ad[ad > 0])
        tmin = np.max(slack[ad < 0] / ad[ad < 0])
        x = x + rng.uniform(tmin, tmax) * d
        pts.append(x.copy())
    for _ in range(n_lp):
        r = linprog(rng.standard_normal(p), A_ub=A, b_ub=rhs, bounds=list(zip(lo, hi)), method="highs")
        assert r.status == 0
        pts.append(r.x)
    return np.array(pts)


def _inside(poly_v, pts, tol):
    """Each point of pts (k, 2) inside the ccw convex polygon poly_v up to tol (distance)."""
    e = np.roll(poly_v, -1, axis=0) - poly_v
    n = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.linalg.norm(e, axis=1)[:, None]
    d = np.einsum("kvd,vd->kv", pts[:, None, :] - poly_v[None], n)
    return d.max(axis=1) <= tol


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("refine", [0, 3])
def test_polygon_contains_independent_feasible_points_and_axis_extents_are_the_hull(seed, refine):
    W, y, b, lo, hi, theta, rng = _problem(seed)
    hull = ident.estimate(W, y, b, ident.Box(lo, hi), method="hull")
    polys, info = P.projections(W, y, b, hull, pairs=[(0, 1), (2, 4)], directions=16, refine=refine)
    pts = _feasible_points(W, y, b, lo, hi, rng)
    for poly in polys:
        i, j = poly.indices
        v = poly.vertices
        assert P.polygon_area(v) > 0  # counter-clockwise
        scale = np.array([hi[i] - lo[i], hi[j] - lo[j]])
        assert _inside(v / scale, pts[:, [i, j]] / scale, 1e-12).all()
        assert _inside(v / scale, np.array([theta[[i, j]]]) / scale, 1e-12).all()  # the truth is feasible
        # every supporting half-plane holds at every feasible point (rigorous offsets)
        assert np.all(pts[:, [i, j]] @ poly.normals.T <= poly.support + 1e-12 * np.abs(poly.support).max())
        # the axis extents are the hull's intervals within the hull's tolerance
        tol = 1e-7 * scale
        assert v[:, 0].min() == pytest.approx(hull.lower[i], abs=tol[0])
        assert v[:, 0].max() == pytest.approx(hull.upper[i], abs=tol[0])
        assert v[:, 1].min() == pytest.approx(hull.lower[j], abs=tol[1])
        assert v[:, 1].max() == pytest.approx(hull.upper[j], abs=tol[1])
        assert poly.to_json()["directions"] == poly.directions >= 16
    assert info["lp_failures"] == 0


def test_refinement_converges_to_the_exact_projection():
    W, y, b, lo, hi, _, rng = _problem(7)
    hull = ident.estimate(W, y, b, ident.Box(lo, hi), method="hull")
    coarse, _ = P.projections(W, y, b, hull, pairs=[(0, 1)], directions=8)
    fine, _ = P.projections(W, y, b, hull, pairs=[(0, 1)], directions=8, refine=8)
    a_coarse, a_fine = P.polygon_area(coarse[0].vertices), P.polygon_area(fine[0].vertices)
    inner = P.polygon_area(P.convex_hull(fine[0].inner))
    assert a_fine <= a_coarse and fine[0].gap < coarse[0].gap
    assert fine[0].gap < 1e-4 and inner == pytest.approx(a_fine, rel=1e-3)  # outer and inner polygons meet
    # the exact projection contains the LP vertices of random costs (scipy), so the inner polygon is not too small
    pts = _feasible_points(W, y, b, lo, hi, rng, n_walk=0, n_lp=30)[:, [0, 1]]
    scale = np.array([hi[0] - lo[0], hi[1] - lo[1]])
    assert _inside(P.convex_hull(fine[0].inner) / scale, pts / scale, 1e-4).all()


def test_most_coupled_pair_is_the_constructed_one():
    W, y, b, lo, hi, _, _ = _problem(3)
    hull = ident.estimate(W, y, b, ident.Box(lo, hi), method="hull")
    polys, info = P.projections(W, y, b, hull, count=2, names=list("abcde"))
    assert polys[0].parameters == ("a", "b")  # column 1 = 0.9 column 0 + noise: the thin diagonal
    assert list(info["scores"])[0] == "a:b" and 0 < info["scores"]["a:b"] <= 1


def test_zonogon_is_the_hull_of_the_projected_vertices():
    rng = np.random.default_rng(1)
    c, G = rng.standard_normal(4), rng.standard_normal((4, 6))
    v = P.zonogon(c, G, 1, 3)
    corners = np.array([c + G @ np.array(s) for s in itertools.product((-1, 1), repeat=6)])[:, [1, 3]]
    hull = P.convex_hull(corners)
    assert P.polygon_area(v) == pytest.approx(P.polygon_area(hull), rel=1e-12)
    assert _inside(v, corners, 1e-9).all()


def test_ellipse_support_matches_the_ellipsoid():
    rng = np.random.default_rng(2)
    A = rng.standard_normal((5, 5))
    Pm, c = A @ A.T + 0.1 * np.eye(5), rng.standard_normal(5)
    pts = P.ellipse_points(c, Pm, 0, 2, n=2001)
    for u in rng.standard_normal((5, 2)):
        full = np.zeros(5)
        full[[0, 2]] = u
        exact = full @ c + np.sqrt(full @ Pm @ full)  # max of u . x over the ellipsoid
        assert (pts @ u).max() == pytest.approx(exact, rel=1e-5)


def test_bad_arguments():
    W, y, b, lo, hi, _, _ = _problem(0, m=50)
    eng = SupportLP(W, y, b, lo, hi)
    with pytest.raises(ValueError, match="directions"):
        P.project_pair(eng, 0, 1, directions=10)
    with pytest.raises(ValueError, match="different"):
        P.project_pair(eng, 1, 1)


def test_coupling_scores_separate_coupled_from_independent_pairs():
    """Rows on (theta1, theta2) and rows on (theta3, theta4) only: the set is a product, so its projection onto
    (theta1, theta3) is a rectangle (score 0), while theta1 and theta2 share one strongly correlated column."""
    rng = np.random.default_rng(4)
    m = 200
    a = rng.standard_normal((m, 1))
    A = np.hstack([a, 0.95 * a + 0.05 * rng.standard_normal((m, 1))])
    B = rng.standard_normal((m, 2))
    W = np.block([[A, np.zeros((m, 2))], [np.zeros((m, 2)), B]])
    theta = np.array([1.0, 1.2, 0.8, 1.1])
    b = np.full(2 * m, 0.3)
    y = W @ theta + rng.uniform(-1, 1, 2 * m) * b
    hull = ident.estimate(W, y, b, ident.Box(np.zeros(4), 3 * np.ones(4)), method="hull")
    eng = SupportLP(W, y, b, hull.lower, hull.upper)
    full = P.coupling_scores(eng)
    assert full[0, 2] == pytest.approx(0.0, abs=1e-6) and full[1, 3] == pytest.approx(0.0, abs=1e-6)
    assert full[0, 1] > 0.3 and full[0, 1] == full[1, 0]
    screened = P.coupling_scores(eng, candidates=2)
    assert P.most_coupled_pairs(screened, 1) == P.most_coupled_pairs(full, 1) == [(0, 1)]
    assert np.count_nonzero(np.triu(screened, 1)) <= 2


def test_support_lp_on_a_working_set_equals_linprog_on_all_rows():
    """3000 rows: the working set stays a fraction of them, the bounds are outer and tight against scipy."""
    W, y, b, lo, hi, theta, rng = _problem(11, m=3000, p=6)
    eng = SupportLP(W, y, b, lo, hi, initial_rows=50)
    A, rhs = _inequalities(W, y, b, lo, hi)
    for c in rng.standard_normal((6, 6)):
        mu, x = eng.minimize(c)
        ref = linprog(c, A_ub=A, b_ub=rhs, bounds=list(zip(lo, hi)), method="highs")
        assert ref.status == 0
        scale = np.abs(c) @ (hi - lo)
        assert mu <= ref.fun + 1e-12 * scale  # a lower bound of the minimum over all rows
        assert mu == pytest.approx(ref.fun, abs=1e-7 * scale)
        assert mu <= c @ theta  # the truth is feasible
    assert eng.idx.size < W.shape[0] // 2 and eng.failures == 0
