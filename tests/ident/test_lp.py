"""The LP core (:class:`ident.numerics.lp.LPModel`) and the safe bound against scipy's linprog (HiGHS via scipy,
an independent build and interface)."""

from __future__ import annotations

import highspy
import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench.ident.numerics import lp
from h4bench.ident.numerics.lp import LPError, LPModel, column_scale, power2_scale
from h4bench.ident.numerics.safe_bound import SafeBound, SafeBounds, safe_lower_bound


def _random_lp(rng, m, n):
    """A feasible LP: rows around a random interior point x_star, box around it."""
    x_star = rng.uniform(-1.0, 1.0, n) * 10.0 ** rng.uniform(-2, 2, n)
    A = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-3, 3, n)  # columns in very different units
    a = A @ x_star
    half = 10.0 ** rng.uniform(-4, 0, m) * (1.0 + np.abs(a))
    lo, hi = a - half, a + half
    width = 5.0 * (np.abs(x_star) + 1.0)
    return A, lo, hi, x_star - width, x_star + width, x_star


@pytest.mark.parametrize("seed", range(6))
def test_random_lps_against_linprog(seed):
    rng = np.random.default_rng(seed)
    m, n = 60, 5
    A, lo, hi, xl, xu, x_star = _random_lp(rng, m, n)
    model = LPModel(xl, xu, center=x_star, col_scale=column_scale(A, power2_scale(0.5 * hi - 0.5 * lo)))
    model.add_rows(A[:30], lo[:30], hi[:30], 0.5 * hi[:30] - 0.5 * lo[:30])
    model.add_rows(A[30:], lo[30:], hi[30:], 0.5 * hi[30:] - 0.5 * lo[30:])  # a second block appended
    assert model.m == m
    for trial in range(4):
        c = rng.normal(size=n)
        ref = linprog(c, A_ub=np.vstack([A, -A]), b_ub=np.concatenate([hi, -lo]), bounds=list(zip(xl, xu)),
                      method="highs")
        assert ref.status == 0
        sol = model.solve(c)
        assert sol.status == "optimal"
        scale = np.abs(c) @ (xu - xl)
        assert c @ sol.x == pytest.approx(ref.fun, abs=1e-7 * scale)
        # the duals are those of the original rows and cost: the safe bound is below the optimum, and tight
        mu = safe_lower_bound(A, lo, hi, xl, xu, c, sol.duals)
        assert mu <= ref.fun + 1e-12 * scale
        mu_c = SafeBound(A, lo, hi, c, sol.duals, x_star).over(xl, xu)
        assert mu_c <= ref.fun + 1e-12 * scale
        assert mu_c == pytest.approx(ref.fun, abs=1e-6 * scale)
    assert model.solves == 4 and model.iterations > 0


def test_safe_bound_below_optimum_for_any_duals():
    rng = np.random.default_rng(7)
    A, lo, hi, xl, xu, _ = _random_lp(rng, 40, 4)
    c = rng.normal(size=4)
    ref = linprog(c, A_ub=np.vstack([A, -A]), b_ub=np.concatenate([hi, -lo]), bounds=list(zip(xl, xu)), method="highs")
    for _ in range(20):  # arbitrary (wrong) dual guesses: still lower bounds
        y = rng.normal(size=40) * 10.0 ** rng.uniform(-3, 1)
        assert safe_lower_bound(A, lo, hi, xl, xu, c, y) <= ref.fun


def test_infeasible_lp_reported():
    model = LPModel(np.zeros(2), np.ones(2))
    model.add_rows(np.array([[1.0, 1.0]]), np.array([3.0]), np.array([4.0]))  # x1 + x2 >= 3 over [0, 1]^2
    assert model.solve(np.array([1.0, 0.0])).status == "infeasible"
    ref = linprog([1.0, 0.0], A_ub=[[-1.0, -1.0]], b_ub=[-3.0], bounds=[(0, 1)] * 2, method="highs")
    assert ref.status == 2  # scipy agrees: infeasible


def test_status_errors_raised():
    model = LPModel(np.zeros(2), np.ones(2))
    with pytest.raises(LPError, match="magnitude"):
        model.add_rows(np.array([[1e16, 1.0]]), np.array([0.0]), np.array([1.0]))
    with pytest.raises(LPError, match="cost"):
        model.solve(np.zeros(2))
    with pytest.raises(LPError, match="option"):
        LPModel(np.zeros(2), np.ones(2), no_such_option=1)
    # an unbounded LP (free column) is neither optimal nor infeasible: LPError, never a silent value
    free = LPModel(np.array([-np.inf]), np.array([np.inf]), center=np.zeros(1))
    free.add_rows(np.array([[1.0]]), np.array([0.0]), np.array([np.inf]))
    with pytest.raises(LPError, match="did not solve"):
        free.solve(np.array([-1.0]))


def test_bad_input():
    with pytest.raises(ValueError, match="xl and xu"):
        LPModel(np.zeros(2), np.ones(3))


def test_sparse_rows_and_bound_changes_against_linprog():
    rng = np.random.default_rng(11)
    m, n = 30, 6
    A, lo, hi, xl, xu, x_star = _random_lp(rng, m, n)
    A[rng.random(A.shape) < 0.5] = 0.0  # sparse
    A[np.arange(m), rng.integers(0, n, m)] = 1.0  # every row non-empty
    half = 10.0 ** rng.uniform(-3, 0, m) * (1.0 + np.abs(A @ x_star))
    lo, hi = A @ x_star - half, A @ x_star + half  # x_star stays feasible
    starts, index, values = [], [], []
    for k in range(m):
        starts.append(len(values))
        nz = np.flatnonzero(A[k])
        index.extend(nz.tolist())
        values.extend(A[k, nz].tolist())
    model = LPModel(xl, xu, center=x_star, col_scale=column_scale(A))
    model.add_sparse_rows(np.array(starts), np.array(index), np.array(values), lo, hi, 0.5 * hi - 0.5 * lo)
    c = rng.normal(size=n)
    for shrink in (1.0, 0.5):  # the whole box, then a node of a branch and bound (bounds changed, warm start)
        bl, bu = x_star - shrink * (x_star - xl), x_star + shrink * (xu - x_star)
        model.set_bounds(bl, bu)
        sol = model.solve(c)
        ref = linprog(c, A_ub=np.vstack([A, -A]), b_ub=np.concatenate([hi, -lo]), bounds=list(zip(bl, bu)),
                      method="highs")
        scale = np.abs(c) @ (bu - bl)
        assert sol.status == "optimal" and c @ sol.x == pytest.approx(ref.fun, abs=1e-7 * scale)
        mu = safe_lower_bound(A, lo, hi, bl, bu, c, sol.duals)
        assert mu <= ref.fun + 1e-12 * scale and mu == pytest.approx(ref.fun, abs=1e-6 * scale)
    with pytest.raises(LPError, match="non-empty"):
        model.add_sparse_rows(np.array([0, 0]), np.array([1]), np.array([1.0]), np.zeros(2), np.ones(2))


def test_unnormalised_cost_gives_the_same_duals():
    rng = np.random.default_rng(12)
    A, lo, hi, xl, xu, x_star = _random_lp(rng, 25, 3)
    c = rng.normal(size=3) * 100.0
    duals = []
    for normalize in (True, False):
        model = LPModel(xl, xu, center=x_star)
        model.add_rows(A, lo, hi)
        model.set_cost(c, normalize=normalize)
        sol = model.solve()
        duals.append(sol.duals)
        assert safe_lower_bound(A, lo, hi, xl, xu, c, sol.duals) <= c @ sol.x + 1e-9 * np.abs(c) @ (xu - xl)
    np.testing.assert_allclose(duals[0], duals[1], rtol=1e-6, atol=1e-9 * np.max(np.abs(duals[0])))


@pytest.mark.parametrize("seed", range(4))
def test_safe_bounds_of_many_lps_at_once_agree_with_one_by_one_and_stay_below_linprog(seed):
    """SafeBounds (k LPs over the rows of all their duals, each LP's zeros left out of its error bounds) gives
    SafeBound's bound of each LP to rounding, below linprog's optimum, for the LPs' own duals and random ones."""
    rng = np.random.default_rng(seed)
    A, lo, hi, xl, xu, x_star = _random_lp(rng, 50, 4)
    k = 6
    C = rng.normal(size=(k, 4))
    Y = np.zeros((50, k))
    model = LPModel(xl, xu, center=x_star)
    model.add_rows(A, lo, hi, 0.5 * hi - 0.5 * lo)
    refs = []
    for j in range(k):
        if j < 4:
            Y[:, j] = model.solve(C[j]).duals  # the LP's own duals: tight
        else:
            Y[rng.choice(50, 10, replace=False), j] = rng.normal(size=10)  # a sparse wrong guess: still a bound
        ref = linprog(C[j], A_ub=np.vstack([A, -A]), b_ub=np.concatenate([hi, -lo]), bounds=list(zip(xl, xu)),
                      method="highs")
        refs.append(ref.fun)
    Y[3, 5] = np.nan  # dropped, as SafeBound drops it
    many = SafeBounds(A, lo, hi, C, Y, x_star)
    for box_lo, box_hi in ((xl, xu), (x_star - 0.1 * (xu - xl), x_star + 0.1 * (xu - xl))):
        mu = many.over(box_lo, box_hi)
        for j in range(k):
            y = np.where(np.isfinite(Y[:, j]), Y[:, j], 0.0)
            one = SafeBound(A, lo, hi, C[j], y, x_star).over(box_lo, box_hi)
            scale = np.abs(C[j]) @ (xu - xl) + 1.0
            assert mu[j] == pytest.approx(one, abs=1e-12 * scale)
            if box_lo is xl:  # over the LP's own box: below the optimum, tight for the LP's duals
                assert mu[j] <= refs[j]
                if j < 4:
                    assert mu[j] == pytest.approx(refs[j], abs=1e-6 * scale)
    with pytest.raises(ValueError, match="finite"):
        many.over(np.full(4, -np.inf), xu)


# ------------------------------------------------------------------------------------------ per-solve budgets
def _strips(rng, m, n):
    """Hull-like LP rows ``|A x - a| <= 1`` around a random x_star (A standard normal), box x_star +- 3."""
    A = rng.normal(size=(m, n))
    x_star = rng.uniform(-1.0, 1.0, n)
    a = A @ x_star + rng.uniform(-0.9, 0.9, m)
    return A, a - 1.0, a + 1.0, x_star - 3.0, x_star + 3.0, x_star


def test_a_solve_stopped_at_its_iteration_limit_is_retried_cold_once_then_reports_the_limit():
    rng = np.random.default_rng(3)
    A, lo, hi, xl, xu, x_star = _strips(rng, 400, 12)
    model = LPModel(xl, xu, center=x_star, iteration_limit=1)
    model.add_rows(A, lo, hi)
    c = rng.normal(size=12)
    ref = linprog(c, A_ub=np.vstack([A, -A]), b_ub=np.concatenate([hi, -lo]), bounds=list(zip(xl, xu)), method="highs")
    sol = model.solve(c)
    assert sol.status == "limit" and sol.x is None and sol.iterations <= 2
    assert model.counters() == {"lp_solves": 2, "lp_iterations": sol.iterations, "lp_limit_hits": 2,
                                "lp_retries": 1, "lp_fallbacks": 1}
    assert sol.dual_valid and sol.duals.shape == (400,)
    assert safe_lower_bound(A, lo, hi, xl, xu, c, sol.duals) <= ref.fun  # the duals at the limit: a valid guess
    # the budget lifted, the same model solves it (cold: the basis where it stopped was dropped), as linprog does
    model.iteration_limit = None
    sol = model.solve(c)
    assert sol.status == "optimal" and c @ sol.x == pytest.approx(ref.fun, abs=1e-7 * np.abs(c) @ (xu - xl))
    assert (model.limit_hits, model.retries, model.fallbacks) == (2, 1, 1)


def test_a_warm_run_is_cut_at_the_warm_limit_and_solved_again_cold():
    """warm_iteration_limit: the first solve (no basis yet) has the full budget; a later solve starting from the
    previous basis stops at the warm limit and is re-run cold under the full budget, reaching linprog's optimum;
    a set basis counts as warm too; the value is checked."""
    rng = np.random.default_rng(5)
    A, lo, hi, xl, xu, x_star = _strips(rng, 400, 12)
    model = LPModel(xl, xu, center=x_star, warm_iteration_limit=1)
    model.add_rows(A, lo, hi)
    span = xu - xl
    for k, c in enumerate(rng.normal(size=(4, 12))):
        ref = linprog(c, A_ub=np.vstack([A, -A]), b_ub=np.concatenate([hi, -lo]), bounds=list(zip(xl, xu)),
                      method="highs")
        sol = model.solve(c)
        assert sol.status == "optimal" and c @ sol.x == pytest.approx(ref.fun, abs=1e-7 * np.abs(c) @ span)
        if k == 0:  # cold: the full budget, no retry
            assert model.counters()["lp_retries"] == 0 and sol.iterations > 1
    assert model.retries == model.limit_hits == 3 and model.fallbacks == 0
    fresh = LPModel(xl, xu, center=x_star, warm_iteration_limit=1)
    fresh.add_rows(A, lo, hi)
    fresh.set_basis(model.basis())
    assert fresh.solve(rng.normal(size=12)).status == "optimal" and fresh.retries == 1
    with pytest.raises(ValueError, match="warm_iteration_limit"):
        LPModel(xl, xu, warm_iteration_limit=0)


def test_the_time_limit_is_rearmed_for_every_run():
    """HiGHS's ``time_limit`` is compared with the run time of the whole ``Highs`` object (the control at the
    end); LPModel re-arms it per run, so solves keep succeeding long after the runs together used the budget."""
    rng = np.random.default_rng(4)
    A, lo, hi, xl, xu, x_star = _strips(rng, 600, 15)
    model = LPModel(xl, xu, center=x_star, time_limit=1e-9)
    model.add_rows(A, lo, hi)
    assert model.solve(rng.normal(size=15)).status == "limit" and model.limit_hits == 2
    budget = 0.3  # [s] per run; one cold solve of this LP takes about 5 ms (a margin for a loaded machine)
    model.time_limit = budget
    h = model.highs
    solves = 0
    while h.getRunTime() < 2 * budget and solves < 2000:
        h.clearSolver()  # cold: every run does the whole work
        assert model.solve(rng.normal(size=15)).status == "optimal"
        solves += 1
    assert h.getRunTime() >= 2 * budget and model.limit_hits == 2 and model.fallbacks == 1
    # the control: HiGHS's own limit, set once, stops at once every run after the object's total exceeded it
    assert h.setOptionValue("time_limit", budget) != highspy.HighsStatus.kError
    h.clearSolver()
    h.run()
    assert h.getModelStatus() == highspy.HighsModelStatus.kTimeLimit


def test_budgets_default_from_the_size_and_are_checked():
    model = LPModel(np.zeros(3), np.ones(3))
    its, secs = model.budgets()
    assert its == lp.ITERATIONS_FLOOR and secs == lp.SECONDS_FLOOR  # a small model: the floors
    model.add_rows(np.ones((100_000, 3)), np.zeros(100_000), np.ones(100_000))
    its, secs = model.budgets()
    assert its == lp.ITERATIONS_PER_LINE * 100_003 and secs == max(lp.SECONDS_FLOOR, lp.SECONDS_PER_ENTRY * 300_000)
    assert LPModel(np.zeros(3), np.ones(3), iteration_limit=np.inf, time_limit=np.inf).budgets() == (2**31 - 1, np.inf)
    for bad in (0, -1.0, True):
        with pytest.raises(ValueError, match="iteration_limit"):
            LPModel(np.zeros(3), np.ones(3), iteration_limit=bad)
        with pytest.raises(ValueError, match="time_limit"):
            LPModel(np.zeros(3), np.ones(3), time_limit=bad)


def test_dual_simplex_after_added_rows_solves_the_same_lps():
    """``dual_after_rows``: a re-solve after rows were added (same cost) runs the dual simplex for that run only;
    the optima are linprog's, and the model's own strategy (primal) is back afterwards."""
    rng = np.random.default_rng(8)
    A, lo, hi, xl, xu, x_star = _strips(rng, 600, 8)
    model = LPModel(xl, xu, center=x_star, dual_after_rows=True, simplex_strategy=4)
    model.add_rows(A[:100], lo[:100], hi[:100])
    c = rng.normal(size=8)
    assert model.solve(c).status == "optimal"
    for k in range(100, 600, 100):
        model.add_rows(A[k:k + 100], lo[k:k + 100], hi[k:k + 100])
        sol = model.solve()
        ref = linprog(c, A_ub=np.vstack([A[:k + 100], -A[:k + 100]]), b_ub=np.concatenate([hi[:k + 100], -lo[:k + 100]]),
                      bounds=list(zip(xl, xu)), method="highs")
        assert sol.status == "optimal" and c @ sol.x == pytest.approx(ref.fun, abs=1e-7 * np.abs(c) @ (xu - xl))
        strategy = model.highs.getOptionValue("simplex_strategy")
        assert (strategy[1] if isinstance(strategy, tuple) else strategy) == 4
