"""The rigorous residual, envelope and coverage checks scenarios call, against exact rational arithmetic."""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from h4bench.ident.estimators import residuals


def _problem(seed: int, m: int = 40, p: int = 6):
    rng = np.random.default_rng(seed)
    scale = 10.0 ** rng.uniform(-6, 6, size=(m, p))  # wide magnitudes: cancellation and rounding matter
    W = rng.standard_normal((m, p)) * scale
    theta = rng.standard_normal(p)
    y = W @ theta + rng.standard_normal(m) * 1e-9
    return W, y, theta


def _exact_dot(row, theta) -> Fraction:
    return sum((Fraction(float(a)) * Fraction(float(t)) for a, t in zip(row, theta)), Fraction(0))


def test_residual_bound_is_at_least_the_exact_residual():
    for seed in range(5):
        W, y, theta = _problem(seed)
        b = residuals.residual_bound(W, y, theta)
        for k in range(W.shape[0]):
            exact = abs(Fraction(float(y[k])) - _exact_dot(W[k], theta))
            assert Fraction(float(b[k])) >= exact
            assert float(b[k]) <= float(exact) * (1 + 1e-6) + 1e-6 * np.abs(W[k] * theta).sum()  # not loose


def test_box_envelope_contains_the_exact_extremes():
    rng = np.random.default_rng(7)
    W, _, theta = _problem(7)
    lower = theta - rng.uniform(0, 1, theta.size)
    upper = theta + rng.uniform(0, 1, theta.size)
    lo, hi = residuals.box_envelope(W, lower, upper)
    for k in range(W.shape[0]):  # the exact min and max of a linear function over a box, vertex by vertex
        lo_x = sum((min(Fraction(float(a)) * Fraction(float(l)), Fraction(float(a)) * Fraction(float(u)))
                    for a, l, u in zip(W[k], lower, upper)), Fraction(0))
        hi_x = sum((max(Fraction(float(a)) * Fraction(float(l)), Fraction(float(a)) * Fraction(float(u)))
                    for a, l, u in zip(W[k], lower, upper)), Fraction(0))
        assert Fraction(float(lo[k])) <= lo_x and Fraction(float(hi[k])) >= hi_x


def test_interval_envelope_contains_every_corner_product():
    rng = np.random.default_rng(3)
    Wc, _, theta = _problem(3, m=10, p=4)
    D = np.abs(Wc) * 1e-3
    lower, upper = theta - 0.1, theta + 0.1
    lo, hi = residuals.interval_envelope(Wc, D, lower, upper)
    for _ in range(50):  # points of the interval regressor and the box, evaluated exactly
        W = Wc + D * rng.choice([-1.0, 1.0], size=Wc.shape)
        W = np.clip(W, Wc - D, Wc + D)  # a float inside the rounded-outward interval
        t = rng.choice([0, 1], size=theta.size)
        th = np.where(t, upper, lower)
        for k in range(W.shape[0]):
            v = _exact_dot(W[k], th)
            assert Fraction(float(lo[k])) <= v <= Fraction(float(hi[k]))


def test_covered_keeps_the_exact_envelope_and_rejects_outside():
    rng = np.random.default_rng(11)
    lo = rng.standard_normal(200) * 1e3
    hi = lo + rng.uniform(0, 1, 200)
    b = rng.uniform(0, 1e-3, 200)
    # the exact ends lo - b and hi + b, and floats one ulp inside and around them
    ends_lo = np.array([float(Fraction(float(a)) - Fraction(float(c))) for a, c in zip(lo, b)])
    ends_hi = np.array([float(Fraction(float(a)) + Fraction(float(c))) for a, c in zip(hi, b)])
    for y in (ends_lo, ends_hi, np.nextafter(ends_lo, np.inf), np.nextafter(ends_hi, -np.inf), 0.5 * (lo + hi)):
        exact_inside = np.array([Fraction(float(a)) - Fraction(float(c)) <= Fraction(float(v))
                                 <= Fraction(float(h)) + Fraction(float(c)) for v, a, h, c in zip(y, lo, hi, b)])
        assert np.all(residuals.covered(y, lo, hi, b)[exact_inside])
    outside = lo - b - 1.0
    assert not np.any(residuals.covered(outside, lo, hi, b))
    assert not np.any(residuals.covered(hi + b + 1.0, lo, hi, b))
    assert np.all(residuals.covered(0.5 * (lo + hi), lo, hi, 0.0))


def test_min_consistent_scale_is_the_weighted_chebyshev_fit():
    """Against scipy's linprog on the same LP (min s, |y - W theta| <= s w, theta in the box): an upper bound,
    tight to the LP tolerance; bad weights are named."""
    import pytest
    from scipy.optimize import linprog

    from h4bench.ident.estimators import min_consistent_scale

    rng = np.random.default_rng(5)
    m, p = 60, 4
    W = rng.standard_normal((m, p))
    y = W @ rng.uniform(-1, 1, p) + rng.uniform(-0.3, 0.3, m)
    w = rng.uniform(0.5, 2.0, m)
    lo, hi = np.full(p, -2.0), np.full(p, 2.0)
    s = min_consistent_scale(W, y, w, (lo, hi))
    A = np.block([[W, -w[:, None]], [-W, -w[:, None]]])
    ref = linprog(np.r_[np.zeros(p), 1.0], A_ub=A, b_ub=np.r_[y, -y], bounds=[*zip(lo, hi), (0, None)],
                  method="highs")
    assert ref.status == 0
    assert s >= ref.fun * (1 - 1e-7) and s <= ref.fun * (1 + 1e-6) + 1e-9
    with pytest.raises(ValueError, match="weights"):
        min_consistent_scale(W, y, -w, (lo, hi))
