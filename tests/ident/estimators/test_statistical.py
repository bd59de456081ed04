"""Statistical references: point estimates against numpy.linalg.lstsq and a direct IV solve, coverage of
the confidence box and ellipsoid on Gaussian data against the Clopper-Pearson interval, IV consistency under
errors in variables."""

import numpy as np
import pytest
from scipy import stats

from h4bench.ident import Box
from h4bench.ident.estimators.statistical import iv, iv_at, ols, ols_at, wls, wls_at

WIDE = 1e6


def _prior(p):
    return Box(np.full(p, -WIDE), np.full(p, WIDE))


def _clopper_pearson(k, n, alpha=0.05):
    lo = stats.beta.ppf(alpha / 2, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(1 - alpha / 2, k + 1, n - k) if k < n else 1.0
    return lo, hi


def _in_ellipsoid(E, x):
    d = x - np.asarray(E["center"])
    return float(d @ np.linalg.solve(np.asarray(E["shape"]), d)) <= 1.0


def test_ols_equals_lstsq():
    rng = np.random.default_rng(0)
    W = rng.normal(size=(200, 5)) * [1.0, 10.0, 0.1, 3.0, 1.0]
    y = W @ rng.normal(size=5) + 0.1 * rng.normal(size=200)
    box = ols(W, y, 1.0, _prior(5))
    theta, res, *_ = np.linalg.lstsq(W, y, rcond=None)
    np.testing.assert_allclose(box.info["theta"], theta, rtol=1e-10)
    s2 = float(res[0]) / (200 - 5)
    std = np.sqrt(np.diag(s2 * np.linalg.inv(W.T @ W)))
    np.testing.assert_allclose(box.info["std"], std, rtol=1e-8)
    t = stats.t.ppf(1 - 0.05 / 10, 195)  # Bonferroni over p = 5
    np.testing.assert_allclose(box.upper, theta + t * std, rtol=1e-10)


def test_wls_equals_weighted_lstsq():
    rng = np.random.default_rng(1)
    N, p = 400, 4
    W = rng.normal(size=(N, p))
    groups = np.arange(N) % 4
    sig = np.array([0.05, 0.2, 1.0, 0.5])[groups]
    y = W @ rng.normal(size=p) + sig * rng.normal(size=N)
    box = wls(W, y, 1.0, _prior(p), groups=groups)
    # the recipe by hand: each group's own OLS residual variance, weights 1/sigma_j, then OLS
    sj = np.empty(4)
    for j in range(4):
        r = groups == j
        th, res, rank, _ = np.linalg.lstsq(W[r], y[r], rcond=None)
        sj[j] = np.sqrt(float(res[0]) / (r.sum() - rank))
    w = 1.0 / sj[groups]
    theta = np.linalg.lstsq(W * w[:, None], y * w, rcond=None)[0]
    np.testing.assert_allclose(box.info["theta"], theta, rtol=1e-10)
    np.testing.assert_allclose(box.info["group_sigma"], sj, rtol=1e-10)
    # one group: wls reduces to ols
    np.testing.assert_allclose(wls(W, y, 1.0, _prior(p)).info["theta"], ols(W, y, 1.0, _prior(p)).info["theta"],
                               rtol=1e-10)


@pytest.mark.parametrize("p", [1, 3])
def test_ols_coverage_on_gaussian_data(p):
    rng = np.random.default_rng(100 + p)
    reps, N, level = 400, 30, 0.95
    box_hits = ell_hits = 0
    theta = rng.normal(size=p)
    for _ in range(reps):
        W = rng.normal(size=(N, p))
        y = W @ theta + 0.3 * rng.normal(size=N)
        box = ols(W, y, 1.0, _prior(p), level=level)
        box_hits += bool(box.contains(theta).all())
        ell_hits += _in_ellipsoid(box.info["set"], theta)
    lo, hi = _clopper_pearson(ell_hits, reps)
    assert lo <= level <= hi, (ell_hits, lo, hi)  # the F ellipsoid's level is exact
    lo, hi = _clopper_pearson(box_hits, reps)
    if p == 1:  # Bonferroni over one parameter is the exact t interval
        assert lo <= level <= hi, (box_hits, lo, hi)
    else:  # conservative: at least the level
        assert hi >= level, (box_hits, lo, hi)


def test_wls_coverage_with_group_variances():
    rng = np.random.default_rng(7)
    reps, p, level = 400, 2, 0.9
    groups = np.repeat([0, 1], 150)
    sig = np.where(groups == 0, 0.05, 1.0)
    theta = np.array([0.5, -1.0])
    ell_hits = box_hits = 0
    f = wls_at(level)
    for _ in range(reps):
        W = rng.normal(size=(300, p))
        y = W @ theta + sig * rng.normal(size=300)
        box = f(W, y, 1.0, _prior(p), groups=groups)
        ell_hits += _in_ellipsoid(box.info["set"], theta)
        box_hits += bool(box.contains(theta).all())
    lo, hi = _clopper_pearson(ell_hits, reps)
    assert lo <= level <= hi, (ell_hits, lo, hi)
    assert _clopper_pearson(box_hits, reps)[1] >= level


def test_iv_equals_direct_solve_and_needs_instruments():
    rng = np.random.default_rng(3)
    W = rng.normal(size=(50, 3))
    Z = W + 0.3 * rng.normal(size=(50, 3))
    y = W @ [1.0, 2.0, 3.0] + 0.1 * rng.normal(size=50)
    box = iv(W, y, 1.0, _prior(3), instruments=Z)
    theta = np.linalg.solve(Z.T @ W, Z.T @ y)
    np.testing.assert_allclose(box.info["theta"], theta, rtol=1e-10)
    r = y - W @ theta
    s2 = r @ r / 47
    A = np.linalg.inv(Z.T @ W)
    C = s2 * A @ (Z.T @ Z) @ A.T
    np.testing.assert_allclose(box.info["std"], np.sqrt(np.diag(C)), rtol=1e-8)
    with pytest.raises(ValueError, match="instruments"):
        iv(W, y, 1.0, _prior(3))
    with pytest.raises(ValueError, match="instruments"):
        iv(W, y, 1.0, _prior(3), instruments=Z[:10])


def test_iv_is_consistent_where_ols_is_biased():
    # errors in variables: the regressor is measured with noise, W = X + V; OLS on W is attenuated, IV with the
    # noise-free X as instrument (the regressor on the reference motion) is consistent
    rng = np.random.default_rng(4)
    theta = np.array([2.0, -1.0])
    errs_iv, errs_ols = [], []
    for N in (1000, 100000):
        X = rng.normal(size=(N, 2))
        W = X + 0.7 * rng.normal(size=(N, 2))
        y = X @ theta + 0.1 * rng.normal(size=N)
        errs_iv.append(np.abs(iv(W, y, 1.0, _prior(2), instruments=X).info["theta"] - theta).max())
        errs_ols.append(np.abs(ols(W, y, 1.0, _prior(2)).info["theta"] - theta).max())
    assert errs_ols[-1] > 0.5  # attenuation 1 / (1 + 0.49): about 0.66 on theta1 = 2
    assert errs_iv[-1] < 0.02 and errs_iv[-1] < errs_iv[0] + 1e-3
    box = iv(W, y, 1.0, _prior(2), instruments=X)
    assert box.contains(theta).all()


def test_prior_intersection_and_attributes():
    rng = np.random.default_rng(5)
    W = rng.normal(size=(40, 2))
    y = W @ [1.0, 1.0] + 0.5 * rng.normal(size=40)
    box = ols(W, y, 1.0, Box([0.9, -5.0], [5.0, 5.0]))
    assert box.lower[0] >= 0.9
    assert box.upper[1] < 5.0
    far = ols(W, y, 1.0, Box([100.0, 100.0], [101.0, 101.0]))
    assert far.info["prior_disjoint"] is True and far.upper[0] < 100.0
    for f in (ols, wls, iv, ols_at(0.99), wls_at(0.99), iv_at(0.99)):
        assert f.kind == "statistical" and f.rigorous is False and f.description and f.citation
    assert ols.level == 0.95 and ols_at(0.99).level == 0.99
    with pytest.raises(ValueError, match="level"):
        ols(W, y, 1.0, _prior(2), level=1.5)
    with pytest.raises(ValueError, match="groups"):
        wls(W, y, 1.0, _prior(2), groups=np.zeros(3, dtype=int))


def test_the_registered_wls_is_ident_wls():
    """One WLS: the registered estimator's centre and standard deviations are ident.wls's (groups as joints)."""
    from h4bench import ident

    rng = np.random.default_rng(5)
    W = rng.standard_normal((120, 3)) * np.array([1.0, 1e3, 1e-3])
    groups = np.arange(120) % 3 + 7  # labels need not start at 0
    y = W @ np.array([1.0, 2e-3, 5e2]) + rng.standard_normal(120) * (groups - 6)
    box = wls(W, y, 1.0, Box(np.full(3, -1e6), np.full(3, 1e6)), groups=groups)
    ref = ident.wls(W, y, 3, joint_of_row=groups - 7)
    t = stats.t.ppf(1 - 0.05 / 6, ref.dof)
    np.testing.assert_allclose(box.info["theta"], ref.theta, rtol=1e-14)
    np.testing.assert_allclose(box.upper - box.lower, 2 * t * ref.std, rtol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.diag(ref.cov)), ref.std, rtol=1e-12)
