"""The exact hull (method="hull") against independent oracles.

* scipy.optimize.linprog (HiGHS through scipy, all rows at once, no constraint generation) on 50 random
  problems of varied shape, scaling and conditioning: the box is outer and tight;
* exact rational arithmetic (python-flint): vertex enumeration on tiny problems, constructed problems whose
  optimum is a known dyadic vertex, and the Neumaier-Shcherbina bound itself.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from flint import fmpq, fmpq_mat
from scipy.optimize import linprog

from h4bench import ident
from h4bench.ident.estimators.chebyshev import chebyshev
from h4bench.ident.estimators.hull import interval_hull, safe_lower_bound, strip_bounds
from h4bench.ident.numerics import lp
from h4bench.ident.numerics.lp import LPModel
from tests.conftest import bounded_noise_problem


def q(x: float) -> fmpq:
    return fmpq(*float(x).as_integer_ratio())


# ---------------------------------------------------------------------------------------- problem zoo
def make_problem(seed: int) -> dict:
    """Random bounded-error problem; noise within 0.9 bound so the true theta is an interior point."""
    rng = np.random.default_rng(seed)
    p = int(rng.integers(1, 15))
    n = int(rng.integers(p + 1, 400))
    kind = ("gauss", "columns", "conditioned", "rows", "sparse")[seed % 5]
    W = rng.standard_normal((n, p))
    colscale = np.ones(p)
    b = np.ones(n) if rng.random() < 0.5 else rng.uniform(0.5, 2.0, n)
    if kind == "columns":  # parameters of very different magnitudes (like kg vs kg m^2)
        colscale = 10.0 ** rng.uniform(-3, 3, p)
        W = W * colscale
    elif kind == "conditioned":  # prescribed singular values down to 1e-6 of the largest
        U, _ = np.linalg.qr(rng.standard_normal((n, p)))
        V, _ = np.linalg.qr(rng.standard_normal((p, p)))
        W = (U * (np.logspace(0, -rng.uniform(0, 6), p) * np.sqrt(n))) @ V.T
    elif kind == "rows":  # rows (and their bounds) of very different magnitudes
        r = 10.0 ** rng.uniform(-2, 2, n)
        W = W * r[:, None]
        b = b * r
    elif kind == "sparse":  # many structural zeros, like the H4's per-joint friction columns
        W = W * (rng.random((n, p)) < 0.3)
        W[np.arange(p), np.arange(p)] = 1.0
    theta = rng.uniform(-1, 1, p) / colscale
    half = rng.uniform(0.5, 3.0, p) / colscale
    lo = theta - half * rng.uniform(0.2, 1.0, p)
    hi = theta + half * rng.uniform(0.2, 1.0, p)
    y = W @ theta + rng.uniform(-0.9, 0.9, n) * b
    return {"W": W, "y": y, "b": b, "lo": lo, "hi": hi, "theta": theta, "kind": kind}


def linprog_endpoints(W, y, b, lo, hi, coords=None):
    """min and max of theta_i (i in coords, default all) by scipy's linprog on all rows.

    Returns values (2, p) and argmin/argmax points (2, p, p); entries of other coordinates are NaN.
    """
    n, p = W.shape
    A = np.vstack([W, -W])
    ub = np.concatenate([y + b, -(y - b)])
    values = np.full((2, p), np.nan)
    points = np.full((2, p, p), np.nan)
    for i in range(p) if coords is None else coords:
        for k, sign in enumerate((1.0, -1.0)):
            c = np.zeros(p)
            c[i] = sign
            res = linprog(
                c, A_ub=A, b_ub=ub, bounds=list(zip(lo, hi)), method="highs",
                options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10},
            )
            assert res.status == 0, res.message
            values[k, i] = res.x[i]
            points[k, i] = res.x
    return values[0], values[1], points


def verified_feasible_point(x, P):
    """A point of S near x, checked with a rounding-error margin (independent of ident.numerics.interval).

    linprog's optimum may violate rows by its tolerance; move it towards the true theta (an interior point
    with margin 0.1 b) just enough to be strictly feasible, then verify in floats with a margin far above
    the rounding error of an p-term dot product (gamma_p < 1e-14 for p <= 14).
    """
    W, y, b, lo, hi, centre = P["W"], P["y"], P["b"], P["lo"], P["hi"], P["theta"]
    x = np.clip(x, lo, hi)
    viol = max(0.0, float(np.max((np.abs(y - W @ x) - b) / b)))
    t = min(1.0, 2.0 * (viol + 1e-9) / (viol + 0.1))
    z = x + t * (centre - x)
    z = np.clip(z, lo, hi)
    err = 1e-13 * (np.abs(y) + np.abs(W) @ np.abs(z))
    assert np.all(np.abs(y - W @ z) + err <= b), "could not build a verified feasible point"
    return z


@pytest.mark.parametrize("seed", range(50))
def test_hull_is_outer_and_tight_against_linprog(seed):
    P = make_problem(seed)
    box = ident.estimate(P["W"], P["y"], P["b"], (P["lo"], P["hi"]), method="hull")
    assert box.contains(P["theta"]).all()
    lp_lo, lp_hi, points = linprog_endpoints(P["W"], P["y"], P["b"], P["lo"], P["hi"])
    p = P["W"].shape[1]
    for i in range(p):
        # outer: verified points of S next to linprog's optima lie inside the box (exact float comparison)
        z_min = verified_feasible_point(points[0, i], P)
        z_max = verified_feasible_point(points[1, i], P)
        assert box.lower[i] <= z_min[i] and z_max[i] <= box.upper[i]
        assert box.lower[i] <= z_max[i] and z_min[i] <= box.upper[i]
    # tight: within 1e-9 relative (to the endpoint's magnitude or the hull's width) of linprog's optima
    scale = np.maximum(np.maximum(np.abs(lp_lo), np.abs(lp_hi)), lp_hi - lp_lo) + 1e-300
    assert np.all(np.abs(box.lower - lp_lo) <= 1e-9 * scale + 1e-12 * (P["hi"] - P["lo"]))
    assert np.all(np.abs(box.upper - lp_hi) <= 1e-9 * scale + 1e-12 * (P["hi"] - P["lo"]))
    assert box.info["lp_iterations"] > 0 and box.info["working_rows"] <= P["W"].shape[0]


def test_constraint_generation_on_many_rows_matches_linprog():
    """N = 6000: the working set stays small, yet the result equals the all-rows LP."""
    rng = np.random.default_rng(7)
    n, p = 6000, 14
    W, theta, y = bounded_noise_problem(rng, n, p, theta_range=(0.2, 1.8))
    box = ident.estimate(W, y, 1.0, (np.zeros(p), 2 * np.ones(p)))
    assert box.info["working_rows"] < n / 5
    idx = [0, 5, 13]  # a few coordinates keep linprog's cost down
    lp_lo, lp_hi, _ = linprog_endpoints(W, y, np.ones(n), np.zeros(p), 2 * np.ones(p), coords=idx)
    for i in idx:
        assert box.lower[i] <= lp_lo[i] + 1e-9 and lp_hi[i] - 1e-9 <= box.upper[i]
        assert abs(box.lower[i] - lp_lo[i]) < 1e-9 and abs(box.upper[i] - lp_hi[i]) < 1e-9


def test_extreme_column_scales_are_handled():
    """Columns scaled by 1e-10 and 1e8 (HiGHS drops matrix entries below 1e-9 unless the model is scaled).

    Oracle: linprog on the well-scaled problem W D, theta' = theta / D (D powers of ten), mapped back.
    """
    rng = np.random.default_rng(12)
    n, p = 300, 3
    D = np.array([1.0, 1e-10, 1e8])
    Ws = rng.standard_normal((n, p))
    theta_s = np.array([1.0, 1.0, 1.0])
    y = Ws @ theta_s + rng.uniform(-0.9, 0.9, n)
    W = Ws / D  # column j of W is column j of Ws divided by D_j; theta = theta_s * D
    theta = theta_s * D
    lo, hi = theta - D, theta + D
    box = ident.estimate(W, y, 1.0, (lo, hi), method="hull")
    s_lo, s_hi, _ = linprog_endpoints(Ws, y, np.ones(n), lo / D, hi / D)
    assert box.contains(theta).all() and box.info["lp_failures"] == []
    np.testing.assert_allclose(box.lower / D, s_lo, rtol=0, atol=1e-8)
    np.testing.assert_allclose(box.upper / D, s_hi, rtol=0, atol=1e-8)


# ------------------------------------------------------------------------------- exact (rational) oracles
def exact_solve(rows, rhs):
    M = fmpq_mat(len(rows), len(rows), [v for r in rows for v in r])
    if M.det() == 0:
        return None
    sol = M.solve(fmpq_mat(len(rows), 1, rhs))
    return [sol[i, 0] for i in range(len(rows))]


def exact_hull_by_vertices(W, y, b, lo, hi):
    """Exact hull of S by enumerating all vertices in rationals (tiny problems only)."""
    n, p = W.shape
    QW = [[q(v) for v in row] for row in W]
    # half-spaces a^T x <= c: W x <= y + b, -W x <= -(y - b), x <= hi, -x <= -lo  (all exact rationals)
    halfspaces = []
    for k in range(n):
        halfspaces.append((QW[k], q(y[k]) + q(b[k])))
        halfspaces.append(([-v for v in QW[k]], -(q(y[k]) - q(b[k]))))
    for j in range(p):
        e = [fmpq(1) if i == j else fmpq(0) for i in range(p)]
        halfspaces.append((e, q(hi[j])))
        halfspaces.append(([-v for v in e], -q(lo[j])))
    best_lo = [None] * p
    best_hi = [None] * p
    for combo in itertools.combinations(range(len(halfspaces)), p):
        x = exact_solve([halfspaces[c][0] for c in combo], [halfspaces[c][1] for c in combo])
        if x is None:
            continue
        if all(sum((a * v for a, v in zip(h, x)), fmpq(0)) <= c for h, c in halfspaces):
            for j in range(p):
                best_lo[j] = x[j] if best_lo[j] is None else min(best_lo[j], x[j])
                best_hi[j] = x[j] if best_hi[j] is None else max(best_hi[j], x[j])
    return best_lo, best_hi


@pytest.mark.parametrize("seed", range(4))
def test_endpoints_bracket_the_exact_hull_from_vertex_enumeration(seed):
    rng = np.random.default_rng(100 + seed)
    p, n = (2, 7) if seed % 2 else (3, 5)
    W = rng.standard_normal((n, p)) * 10.0 ** rng.uniform(-2, 2, p)
    theta = rng.uniform(-1, 1, p)
    b = rng.uniform(0.5, 1.5, n)
    y = W @ theta + rng.uniform(-0.9, 0.9, n) * b
    lo, hi = theta - 3.0, theta + 3.0
    box = ident.estimate(W, y, b, (lo, hi), method="hull")
    ex_lo, ex_hi = exact_hull_by_vertices(W, y, b, lo, hi)
    for j in range(p):
        assert q(box.lower[j]) <= ex_lo[j] and ex_hi[j] <= q(box.upper[j])  # outer, exactly
        assert abs(box.lower[j] - float(ex_lo[j].p) / float(ex_lo[j].q)) < 1e-9  # and tight
        assert abs(box.upper[j] - float(ex_hi[j].p) / float(ex_hi[j].q)) < 1e-9


@pytest.mark.parametrize("seed", range(30))
def test_endpoint_at_a_known_exact_vertex(seed):
    """Construct S whose min (or max) theta_i is attained at a vertex known exactly in rationals.

    p rows are made active at theta_true with signs chosen so that the KKT conditions for min (max)
    theta_i hold (e_i = sum_k lambda_k s_k W_k, lambda >= 0); the other rows and the prior are inactive.
    In floats y_act = fl(W_act theta + s) is rounded, so the exact optimum is the rational solution x* of
    W_act x = y_act - s, computed with fmpq. The box must contain x*_i exactly: an LP objective taken
    without safe rounding overshoots it by an ulp or so in a fair share of these cases.
    """
    rng = np.random.default_rng(seed)
    p = int(rng.integers(2, 9))
    i = int(rng.integers(p))
    maximise = bool(seed % 2)
    while True:
        W_act = rng.standard_normal((p, p)) * 10.0 ** rng.uniform(-1, 1, p)
        mu = exact_solve([[q(W_act[k, j]) for k in range(p)] for j in range(p)],  # W_act^T mu = e_i
                         [fmpq(1) if j == i else fmpq(0) for j in range(p)])
        if mu is not None and np.linalg.cond(W_act) < 1e3:
            break
    theta = rng.uniform(0.2, 1.8, p)
    s = np.array([1.0 if m >= 0 else -1.0 for m in mu]) * (-1.0 if maximise else 1.0)
    y_act = W_act @ theta + s  # active rows: y - W theta = s * bound, bound = 1 (up to rounding)
    x_star = exact_solve([[q(v) for v in row] for row in W_act], [q(y_act[k]) - q(s[k]) for k in range(p)])
    W_in = rng.standard_normal((30, p))
    y_in = W_in @ theta + rng.uniform(-0.9, 0.9, 30)  # strictly inside their strips
    W = np.vstack([W_act, W_in])
    y = np.concatenate([y_act, y_in])
    lo, hi = theta - 0.5, theta + 0.5
    box = ident.estimate(W, y, 1.0, (lo, hi), method="hull")
    target = float(x_star[i].p) / float(x_star[i].q)
    if maximise:
        assert x_star[i] <= q(box.upper[i]) and box.upper[i] - target < 1e-9
    else:
        assert q(box.lower[i]) <= x_star[i] and target - box.lower[i] < 1e-9


@pytest.mark.parametrize("seed", range(20))
def test_safe_lower_bound_is_below_its_exact_value(seed):
    """The float bound never exceeds the same formula evaluated in exact rationals, for any duals."""
    rng = np.random.default_rng(seed)
    m, n = int(rng.integers(1, 12)), int(rng.integers(1, 6))
    A = rng.standard_normal((m, n)) * 10.0 ** rng.uniform(-8, 8, (m, n))
    bl = rng.standard_normal(m) * 10.0 ** rng.uniform(-5, 5, m)
    bu = bl + rng.uniform(0, 3, m)
    bl[rng.random(m) < 0.2] = -np.inf
    bu[rng.random(m) < 0.2] = np.inf
    xl = rng.standard_normal(n)
    xu = xl + rng.uniform(0, 2, n)
    c = rng.standard_normal(n)
    y = rng.standard_normal(m) * 10.0 ** rng.uniform(-3, 3, m)
    mu = safe_lower_bound(A, bl, bu, xl, xu, c, y)
    # the same formula, exactly (duals that meet an infinite bound are zeroed, as documented)
    yy = [0.0 if (v > 0 and np.isneginf(bl[k])) or (v < 0 and np.isposinf(bu[k])) else v for k, v in enumerate(y)]
    exact = fmpq(0)
    for k in range(m):
        if yy[k] > 0:
            exact += q(yy[k]) * q(bl[k])
        elif yy[k] < 0:
            exact += q(yy[k]) * q(bu[k])
    for j in range(n):
        r = sum((q(A[k, j]) * q(yy[k]) for k in range(m)), fmpq(0)) - q(c[j])
        exact += min(-r * q(xl[j]), -r * q(xu[j]))
    assert q(mu) <= exact
    assert abs(mu - float(exact.p) / float(exact.q)) <= 1e-12 * (1.0 + abs(float(exact.p) / float(exact.q))) + 1e-10 * (
        np.abs(A).T @ np.abs(yy) + np.abs(c)).max() * np.abs(np.concatenate([xl, xu])).max()


def test_strip_bounds_are_outward():
    rng = np.random.default_rng(0)
    y = rng.standard_normal(200) * 10.0 ** rng.uniform(-5, 5, 200)
    b = rng.uniform(0.1, 3, 200)
    bl, bu = strip_bounds(y, b)
    for k in range(200):
        assert q(bl[k]) <= q(y[k]) - q(b[k]) and q(y[k]) + q(b[k]) <= q(bu[k])


def test_chebyshev_brackets_linprogs_minimax():
    rng = np.random.default_rng(3)
    n, p = 500, 6
    W = rng.standard_normal((n, p))
    y = W @ rng.uniform(0, 1, p) + rng.uniform(-2, 2, n)
    lo, hi = np.zeros(p), np.ones(p)
    ch = chebyshev(W, y, np.ones(n), lo, hi)
    # naive LP: variables (theta, t), minimise t with -t <= y - W theta <= t on all rows
    A = np.block([[W, -np.ones((n, 1))], [-W, -np.ones((n, 1))]])
    res = linprog(np.r_[np.zeros(p), 1.0], A_ub=A, b_ub=np.r_[y, -y], bounds=list(zip(lo, hi)) + [(0, None)],
                  method="highs")
    assert ch.lower <= res.fun + 1e-9 and res.fun - 1e-9 <= ch.upper
    assert ch.upper - ch.lower < 1e-9 * res.fun
    assert np.max(np.abs(y - W @ ch.theta)) <= ch.upper


def test_interval_hull_reports_infeasible_working_set():
    rng = np.random.default_rng(1)
    W = rng.standard_normal((50, 3))
    y = W @ np.ones(3)
    y[0] += 10.0  # one row 10 away with bound 1: empty
    bl, bu = strip_bounds(y, np.ones(50))
    res = interval_hull(W, bl, bu, np.zeros(3), 2 * np.ones(3))
    assert res.status == "infeasible"


# ------------------------------------------------------------------------------------ per-solve budgets
def _budget_problem():
    """1500 rows, 8 parameters, bound 1, prior [0, 3]^8 (the truth inside), and the least-squares centre."""
    rng = np.random.default_rng(5)
    W, theta, y = bounded_noise_problem(rng, 1500, 8)
    lo, hi = np.zeros(8), 3.0 * np.ones(8)
    P = {"W": W, "y": y, "b": np.ones(1500), "lo": lo, "hi": hi, "theta": theta}
    return P, np.linalg.lstsq(W, y, rcond=None)[0]


@pytest.fixture(scope="module")
def budget_problem():
    P, center = _budget_problem()
    lp_lo, lp_hi, points = linprog_endpoints(P["W"], P["y"], P["b"], P["lo"], P["hi"])
    # verified points of S next to linprog's optima: the exact hull's endpoints lie beyond them
    z = np.array([[verified_feasible_point(points[k, i], P)[i] for i in range(8)] for k in (0, 1)])
    return P, center, z


def _assert_outer(res, P, z):
    """The box contains the exact hull (verified points of S at linprog's optima) and lies in the prior."""
    assert np.all(res.lower <= z[0]) and np.all(res.upper >= z[1])
    assert np.all(res.lower >= P["lo"]) and np.all(res.upper <= P["hi"])


@pytest.mark.parametrize("limit", [1, 20])
def test_lps_stopped_by_their_budget_fall_back_to_safe_endpoints(budget_problem, limit):
    """An iteration limit of 1 (every LP stops) or 20 (a few cold solves stop): not stuck, counted, the box
    still contains the exact hull; the endpoints that did not fall back are the unlimited run's."""
    P, center, z = budget_problem
    bl, bu = strip_bounds(P["y"], P["b"])
    full = interval_hull(P["W"], bl, bu, P["lo"], P["hi"], center=center)
    assert full.info["lp_limit_hits"] == full.info["lp_fallbacks"] == 0 and full.info["converged"]
    res = interval_hull(P["W"], bl, bu, P["lo"], P["hi"], center=center, lp_budget={"iteration_limit": limit})
    info = res.info
    fell = np.array(info["lp_fallback_endpoints"], dtype=int)
    assert fell.size == info["lp_fallbacks"] >= 1 and not info["converged"]
    assert info["lp_retries"] >= info["lp_fallbacks"] and info["lp_limit_hits"] >= 2 * info["lp_fallbacks"]
    _assert_outer(res, P, z)
    _assert_outer(full, P, z)
    ends = np.r_[res.lower, -res.upper]
    full_ends = np.r_[full.lower, -full.upper]
    kept = np.setdiff1d(np.arange(16), fell)
    np.testing.assert_allclose(ends[kept], full_ends[kept], rtol=0, atol=1e-9)
    assert np.all(ends[fell] <= full_ends[fell])  # a fallback is coarser, never narrower
    if limit == 1:
        assert fell.size == 16 and info["lp_iterations"] <= 2 * info["lp_solves"]
    else:  # the dual simplex stopped at 20 iterations holds informative duals: better than the prior
        assert np.any(ends[fell] > np.r_[P["lo"], -P["hi"]][fell])


def test_an_lp_stopped_after_earlier_solves_keeps_their_duals(budget_problem, monkeypatch):
    """Every run after the 6th stops at 1 iteration: the LPs solved before keep their endpoints; an LP whose
    re-solve (rows added) stopped gets the safe bound of its earlier optimal duals, not the prior."""
    P, center, z = budget_problem
    bl, bu = strip_bounds(P["y"], P["b"])
    budgets = LPModel.budgets
    monkeypatch.setattr(LPModel, "budgets", lambda self: (1 if self.solves >= 6 else budgets(self)[0], np.inf))
    res = interval_hull(P["W"], bl, bu, P["lo"], P["hi"], center=center)
    fell = res.info["lp_fallback_endpoints"]
    assert 0 < len(fell) < 16 and res.info["lp_fallbacks"] == len(fell)
    _assert_outer(res, P, z)
    ends, prior_ends = np.r_[res.lower, -res.upper], np.r_[P["lo"], -P["hi"]]
    assert np.any(ends[fell] > prior_ends[fell] + 1e-6)


def test_estimate_reports_the_budget_counters_and_warns_on_fallbacks(budget_problem, monkeypatch):
    P, _, z = budget_problem
    prior = ident.Box(P["lo"], P["hi"], names=tuple("abcdefgh"))
    box = ident.estimate(P["W"], P["y"], 1.0, prior, method="hull")
    assert {k: box.info[k] for k in ("lp_limit_hits", "lp_retries", "lp_fallbacks")} == dict.fromkeys(
        ("lp_limit_hits", "lp_retries", "lp_fallbacks"), 0)
    assert box.info["lp_fallback_parameters"] == [] and box.info["lp_solves"] > 0
    monkeypatch.setattr(lp, "ITERATIONS_FLOOR", 3)  # the defaults of every model: 3 iterations per run
    monkeypatch.setattr(lp, "ITERATIONS_PER_LINE", 0)
    with pytest.warns(ident.LPFallbackWarning, match="per-solve budget") as record:
        cut = ident.estimate(P["W"], P["y"], 1.0, prior, method="hull")
    info = cut.info
    assert info["lp_fallbacks"] >= 1 and info["lp_limit_hits"] >= 2 and info["lp_retries"] >= 1
    assert info["lp_fallback_parameters"] and set(info["lp_fallback_parameters"]) <= set("abcdefgh")
    assert any(name in str(w.message) for w in record for name in info["lp_fallback_parameters"])
    assert np.all(cut.lower <= z[0]) and np.all(cut.upper >= z[1]) and cut.contains(P["theta"]).all()
    assert np.all(cut.lower <= box.lower) and np.all(cut.upper >= box.upper)


def test_chebyshev_stopped_by_its_budget_still_brackets_the_minimax(monkeypatch):
    rng = np.random.default_rng(3)
    n, p = 500, 6
    W = rng.standard_normal((n, p))
    y = W @ rng.uniform(0, 1, p) + rng.uniform(-2, 2, n)
    lo, hi = np.zeros(p), np.ones(p)
    A = np.block([[W, -np.ones((n, 1))], [-W, -np.ones((n, 1))]])
    ref = linprog(np.r_[np.zeros(p), 1.0], A_ub=A, b_ub=np.r_[y, -y], bounds=list(zip(lo, hi)) + [(0, None)],
                  method="highs").fun
    budgets = LPModel.budgets
    for after in (0, 1):  # every run stops; or every run after the first solve (an earlier optimum kept)
        monkeypatch.setattr(LPModel, "budgets", lambda self: (5 if self.solves >= after else budgets(self)[0], np.inf))
        with pytest.warns(ident.LPFallbackWarning, match="per-solve budget"):
            ch = chebyshev(W, y, np.ones(n), lo, hi, initial_rows=40, add_per_round=20)
        assert ch.info["lp_fallback"] and ch.info["lp_fallbacks"] == 1 and not ch.info["converged"]
        assert 0.0 <= ch.lower <= ref <= ch.upper
        assert np.max(np.abs(y - W @ ch.theta)) <= ch.upper


def test_violated_rows_are_the_einsum_decision_whatever_blas_rounds():
    """hull._violated_rows scans with BLAS but decides every row BLAS's rounding could flip by sums in a fixed order: its rows and deviations are those of that computation alone, bit for bit, also for rows whose
    deviation lies on their threshold (the oracle: the sums in the order of j over all rows at once)."""
    from h4bench.ident.estimators.hull import _violated_rows

    rng = np.random.default_rng(5)
    W = rng.standard_normal((20000, 23)) * np.logspace(-3, 3, 23)
    dx = rng.standard_normal((23, 6))
    m0 = rng.standard_normal(20000)
    acc = dx.T[:, :1] * W[:, 0]
    for j in range(1, 23):
        acc = acc + dx.T[:, j:j + 1] * W[:, j]
    exact = np.abs(acc - m0)
    thr = np.quantile(exact.max(axis=0), 0.9) * np.ones(20000)
    on = rng.choice(20000, 300, replace=False)
    thr[on] = exact.max(axis=0)[on] * rng.choice([1.0 - 2.0**-52, 1.0, 1.0 + 2.0**-52], 300)  # on the edge
    skip = np.zeros(20000, dtype=bool)
    skip[:50] = True
    rows, dev = _violated_rows(W, dx, m0, thr, skip)
    want = np.flatnonzero((exact.max(axis=0) > thr) & ~skip)
    np.testing.assert_array_equal(rows, want)
    np.testing.assert_array_equal(dev, exact[:, want].T)
