"""h4bench.ident.estimate / ident.min_consistent_bound: enclosure of the truth, inconsistency, identifiability and
input validation. Oracles: the true parameter vector of synthetic data, scipy's linprog (naive Chebyshev
fit on all rows), and the equivalence of per-row bounds with row scaling."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench import ident
from h4bench.ident import PARAMETER_NAMES, Box

METHODS = ("hull", "cgsp")


def synthetic(seed: int, n: int, p: int, noise: float = 1.0, per_row: bool = False):
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((n, p)) * 10.0 ** rng.uniform(-1, 1, p)
    theta = rng.uniform(-1, 1, p)
    bound = rng.uniform(0.5, 2.0, n) if per_row else 1.0
    y = W @ theta + noise * rng.uniform(-1, 1, n) * bound
    prior = (theta - rng.uniform(0.5, 5, p), theta + rng.uniform(0.5, 5, p))
    return W, y, bound, prior, theta


def naive_min_bound(W, y, lo, hi) -> float:
    """min t s.t. -t <= y - W theta <= t on all rows, theta in the prior (scipy linprog)."""
    n, p = W.shape
    A = np.block([[W, -np.ones((n, 1))], [-W, -np.ones((n, 1))]])
    res = linprog(np.r_[np.zeros(p), 1.0], A_ub=A, b_ub=np.r_[y, -y], bounds=list(zip(lo, hi)) + [(0, None)],
                  method="highs", options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10})
    assert res.status == 0
    return float(res.fun)


# ---------------------------------------------------------------------------------------- enclosure
@pytest.mark.parametrize("seeds", [100, pytest.param(1000, marks=pytest.mark.slow)])
def test_every_box_method_encloses_the_true_theta_on_1000_seeds(seeds):
    """Noise uniform in the whole [-bound, bound]: the true theta is always feasible, so never missed (the first
    100 seeds in the default run, all 1000 with -m slow)."""
    misses = []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        p = int(rng.integers(1, 6))
        n = 4 * int(rng.integers(max(1, (p + 3) // 4), 8))
        W, y, bound, prior, theta = synthetic(seed, n, p, per_row=bool(seed % 2))
        for method in METHODS:
            box = ident.estimate(W, y, bound, prior, method=method)
            if not box.contains(theta).all():
                misses.append((seed, method))
    assert misses == []


def test_per_row_bounds_equal_scaled_rows():
    """S is invariant under row scaling, so the exact hull is too (CGSP is not: W^+ changes with the
    row weights, which is why it is not tested here)."""
    W, y, bound, prior, theta = synthetic(3, 80, 4, per_row=True)
    a = ident.estimate(W, y, bound, prior, method="hull")
    b = ident.estimate(W / bound[:, None], y / bound, 1.0, prior, method="hull")
    np.testing.assert_allclose(a.lower, b.lower, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(a.upper, b.upper, rtol=1e-9, atol=1e-9)


def test_hull_is_inside_cgsp_up_to_rounding():
    W, y, bound, prior, theta = synthetic(5, 400, 6)
    h = ident.estimate(W, y, bound, prior, method="hull")
    c = ident.estimate(W, y, bound, prior, method="cgsp")
    assert np.all(c.lower <= h.lower + 1e-12) and np.all(h.upper <= c.upper + 1e-12)
    assert h.width.mean() < c.width.mean()


def test_box_carries_names_and_diagnostics():
    W, y, bound, prior, theta = synthetic(1, 200, 14)
    box = ident.estimate(W, y, bound, prior)
    assert box.names == tuple(f"theta{j + 1}" for j in range(14))  # generic: a (lower, upper) prior has no names
    h4 = ident.estimate(W, y, bound, Box(prior[0], prior[1], names=PARAMETER_NAMES))
    assert h4.names == PARAMETER_NAMES and np.array_equal(h4.lower, box.lower)  # the names come from the prior
    for key in ("lp_iterations", "working_rows", "seconds", "at_prior", "unidentifiable", "cond"):
        assert key in box.info
    assert box.info["working_rows"] <= 200 and box.info["seconds"] > 0
    small = ident.estimate(W[:, :3], y, 30.0, (prior[0][:3], prior[1][:3]), method="cgsp")
    assert small.names == ("theta1", "theta2", "theta3") and "sweeps" in small.info
    named = ident.estimate(W[:, :2], y, 30.0, Box(prior[0][:2], prior[1][:2], names=("a", "b")))
    assert named.names == ("a", "b")


def test_degenerate_prior_component_is_kept_fixed():
    W, y, bound, (lo, hi), theta = synthetic(2, 60, 3)
    lo[1] = hi[1] = theta[1]
    for method in METHODS:
        box = ident.estimate(W, y, bound, (lo, hi), method=method)
        assert box.lower[1] == box.upper[1] == theta[1] and box.contains(theta).all()


# --------------------------------------------------------------------------------------- inconsistency
@pytest.mark.parametrize("method", METHODS)
def test_noise_beyond_the_bound_raises_with_the_minimal_bound(method):
    W, y, _, prior, _ = synthetic(7, 2000, 5, noise=1.5)
    with pytest.raises(ident.InconsistentDataError) as err:
        ident.estimate(W, y, 1.0, prior, method=method)
    e = err.value
    assert isinstance(e, ValueError) and e.bound == 1.0 and e.scale_lower > 1.0
    naive = naive_min_bound(W, y, *prior)
    assert naive - 1e-9 <= e.min_bound <= naive * (1 + 1e-8)  # rounded up, tight
    assert "contradict bound=1" in str(e) and f"{e.min_bound:.6g}" in str(e)
    # with the reported bound the data are consistent: no error, and the Chebyshev point is enclosed
    box = ident.estimate(W, y, e.min_bound, prior, method=method)
    assert np.all(box.lower <= box.upper)


def test_per_row_bounds_inconsistency_reports_the_scale():
    W, y, bound, prior, _ = synthetic(8, 1500, 4, noise=1.4, per_row=True)
    with pytest.raises(ident.InconsistentDataError, match="must be scaled by at least") as err:
        ident.estimate(W, y, bound, prior)
    assert err.value.scale_lower > 1.0


@pytest.mark.parametrize("seed", range(5))
def test_min_consistent_bound_matches_a_naive_linprog(seed):
    rng = np.random.default_rng(seed)
    n, p = int(rng.integers(20, 600)), int(rng.integers(1, 10))
    W, y, _, (lo, hi), theta = synthetic(seed, n, p, noise=rng.uniform(0.1, 3))
    if seed % 2:  # a narrow prior that excludes the unconstrained Chebyshev point
        lo, hi = theta + 0.5, theta + 0.6
    t = ident.min_consistent_bound(W, y, (lo, hi))
    naive = naive_min_bound(W, y, lo, hi)
    assert naive - 1e-9 * naive <= t <= naive * (1 + 1e-8) + 1e-12


@pytest.mark.parametrize("seed", range(9, 13))
def test_emptiness_is_decided_at_the_edge_of_consistency(seed):
    """bound = min_consistent_bound: S is a point or tiny, never an error; 1e-12 below it, S is empty and
    the safe dual bound of the Chebyshev LP proves it."""
    W, y, _, prior, _ = synthetic(seed, 300, 3, noise=1.0)
    t = ident.min_consistent_bound(W, y, prior)
    for method in METHODS:
        box = ident.estimate(W, y, t, prior, method=method)
        assert np.all(box.lower <= box.upper)
        assert box.info["nonempty_proven"] != box.info["nearly_inconsistent"]
        with pytest.raises(ident.InconsistentDataError):
            ident.estimate(W, y, t * (1 - 1e-12), prior, method=method)
    assert ident.estimate(W, y, t, prior, method="hull").width.max() < 1e-6


def test_consistent_data_come_with_a_verified_feasible_point():
    W, y, bound, prior, theta = synthetic(6, 500, 5)
    for method in METHODS:
        assert ident.estimate(W, y, bound, prior, method=method).info["nonempty_proven"] is True


# ------------------------------------------------------------------------------------- identifiability
@pytest.mark.parametrize("method", METHODS)
def test_undetermined_parameters_are_reported_by_name(method):
    W, y, _, (lo, hi), theta = synthetic(4, 400, 14, noise=1.0)
    W[:, 7] = W[:, 2]  # only Imot3 + Fv2 enters the data
    W[:, 12] = 0.0  # Fs3 never excited
    y = W @ theta + np.random.default_rng(0).uniform(-1, 1, 400)
    box = ident.estimate(W, y, 1.0, Box(lo, hi, names=PARAMETER_NAMES), method=method)
    assert np.all(np.isfinite(box.lower)) and np.all(np.isfinite(box.upper)) and box.contains(theta).all()
    assert set(box.info["unidentifiable"]) == {"Imot3", "Fv2", "Fs3"}
    assert "Fs3" in box.info["at_prior"]
    assert box.lower[12] == lo[12] and box.upper[12] == hi[12]


# ---------------------------------------------------------------------------------------- bad input
GOOD_W = np.random.default_rng(0).standard_normal((20, 3))
GOOD_Y = GOOD_W @ np.ones(3)
GOOD_PRIOR = (np.zeros(3), 2 * np.ones(3))
NAN_W = GOOD_W.copy()
NAN_W[4, 1] = np.nan
INF_Y = GOOD_Y.copy()
INF_Y[3] = np.inf


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        ({"W": NAN_W}, ValueError, r"W must be finite, got 1 NaN and 0 inf entries \(first at index \(4, 1\)\)"),
        ({"y": INF_Y}, ValueError, r"y must be finite, got 0 NaN and 1 inf"),
        ({"y": GOOD_Y[:-1]}, ValueError, r"y must have shape \(m,\) = \(20,\) to match W, got \(19,\)"),
        ({"W": GOOD_W[:0]}, ValueError, r"W must have shape \(m, p\) with m >= 1 and p >= 1, got \(0, 3\)"),
        ({"W": GOOD_W[:, 0]}, ValueError, r"W must have shape \(m, p\) with m >= 1 and p >= 1, got \(20,\)"),
        ({"W": np.full((20, 3), "a")}, TypeError, r"W must be a real numeric array, got dtype <U1"),
        ({"bound": 0.0}, ValueError, r"bound must be finite and > 0 .* got 0.0"),
        ({"bound": -1.0}, ValueError, r"bound must be finite and > 0"),
        ({"bound": np.nan}, ValueError, r"bound must be finite and > 0 .* got nan"),
        ({"bound": np.ones(5)}, ValueError, r"bound must be a scalar or have shape \(m,\) = \(20,\), got shape \(5,\)"),
        ({"bound": np.r_[np.ones(19), 0.0]}, ValueError, r"bound must be finite and > 0 in every row, got 0.0 at row 19"),
        ({"prior": (np.ones(3), np.zeros(3))}, ValueError, r"prior lower must be <= upper, violated for \['theta1', 'theta2', 'theta3'\]"),
        ({"prior": (np.zeros(3), np.full(3, np.inf))}, ValueError, r"prior must be finite"),
        ({"prior": (np.zeros(2), np.ones(2))}, ValueError, r"prior lower and upper must have shape \(3,\) to match W's columns, got \(2,\)"),
        ({"prior": np.ones(3)}, TypeError, r"prior must be a Box or a \(lower, upper\) pair of arrays of length 3, got ndarray"),
        ({"method": "lsq"}, ValueError, r"method must be one of \('hull', 'cgsp', .*\) .*, got 'lsq'"),
        ({"method": 3}, TypeError, r"method must be a string"),
    ],
)
def test_bad_input_is_rejected_with_a_message_naming_the_argument(kwargs, exc, match):
    args = {"W": GOOD_W, "y": GOOD_Y, "bound": 1.0, "prior": GOOD_PRIOR, "method": "hull"}
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        ident.estimate(args["W"], args["y"], args["bound"], args["prior"], method=args["method"])


def test_min_consistent_bound_validates_its_input():
    with pytest.raises(ValueError, match="W must be finite"):
        ident.min_consistent_bound(NAN_W, GOOD_Y, GOOD_PRIOR)
    with pytest.raises(TypeError, match="prior must be a Box"):
        ident.min_consistent_bound(GOOD_W, GOOD_Y, None)


def test_integer_and_fortran_ordered_input_is_accepted():
    W = np.asfortranarray(np.random.default_rng(1).integers(-5, 6, (30, 3)))
    y = (W @ np.ones(3)).astype(np.int64)
    box = ident.estimate(W, y, 1, (np.zeros(3), 2 * np.ones(3)))
    assert box.contains(np.ones(3)).all()


@pytest.mark.parametrize("method", ["hull", "cgsp", "contractor", "zonotope", "ellipsoid", "parallelotope"])
def test_fewer_rows_than_parameters_give_an_outer_box(method):
    """N < p is a bounded polytope (the prior bounds it): every guaranteed built-in returns a box containing the
    exact hull (scipy linprog), the hull equal to it within the LP tolerance."""
    from tests.ident.estimators.oracles import box_contains, exact_hull

    rng = np.random.default_rng(7)
    W = rng.standard_normal((2, 5))
    theta = rng.uniform(-1, 1, 5)
    y = W @ theta + rng.uniform(-0.1, 0.1, 2)
    prior = Box(theta - 1.0, theta + 1.0)
    lo, hi = exact_hull(W, y, np.full(2, 0.1), prior)
    box = ident.estimate(W, y, 0.1, (prior.lower, prior.upper), method=method)
    assert box_contains(box, lo, hi)
    if method == "hull":
        np.testing.assert_allclose(box.lower, lo, atol=1e-7)
        np.testing.assert_allclose(box.upper, hi, atol=1e-7)


def test_the_builtin_dispatch_runs_only_its_own_methods():
    """estimate.METHODS names what _builtin_estimate runs; another registry name is refused, not run as cgsp."""
    from h4bench.ident.estimators import estimate as est

    assert est.METHODS == ("hull", "cgsp")
    with pytest.raises(ValueError, match="method must be one of \\('hull', 'cgsp'\\), got 'ellipsoid'"):
        est._builtin_estimate(GOOD_W, GOOD_Y, 1.0, GOOD_PRIOR, "ellipsoid")
