"""The prediction envelope (:mod:`ident.estimators.envelope`) against scipy's linprog on a sample of rows."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench import ident
from h4bench.ident.estimators.envelope import envelope_lp, prediction_envelope


def _problem(seed, m=400, p=5):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.5, 2.0, p)
    W = rng.standard_normal((m, p)) * 10.0 ** rng.uniform(-1, 1, p)
    b = rng.uniform(0.05, 0.2, m)
    y = W @ theta + rng.uniform(-1, 1, m) * b
    lo, hi = np.zeros(p), 4.0 * np.ones(p)
    return W, y, b, lo, hi, theta, rng


def _linprog_range(W, y, b, lo, hi, w):
    A = np.vstack([W, -W])
    rhs = np.concatenate([y + b, b - y])
    out = []
    for sign in (1.0, -1.0):
        res = linprog(sign * w, A_ub=A, b_ub=rhs, bounds=list(zip(lo, hi)), method="highs")
        assert res.status == 0
        out.append(sign * res.fun)
    return out


@pytest.mark.parametrize("seed", range(3))
def test_envelope_against_linprog_on_sampled_rows(seed):
    W, y, b, lo, hi, theta, rng = _problem(seed)
    W_new = rng.standard_normal((30, W.shape[1]))
    rows = rng.choice(30, 8, replace=False)
    lower, upper = prediction_envelope(W, y, b, ident.Box(lo, hi), W_new, rows=rows)
    assert lower.shape == upper.shape == (8,)
    for k, r in enumerate(rows):
        ref_lo, ref_hi = _linprog_range(W, y, b, lo, hi, W_new[r])
        scale = np.abs(W_new[r]) @ (hi - lo)
        assert lower[k] <= ref_lo + 1e-12 * scale and upper[k] >= ref_hi - 1e-12 * scale  # outer
        assert lower[k] == pytest.approx(ref_lo, abs=1e-6 * scale)  # and tight to the LP tolerance
        assert upper[k] == pytest.approx(ref_hi, abs=1e-6 * scale)
        assert lower[k] <= W_new[r] @ theta <= upper[k]  # the truth is feasible, so its prediction is inside


def test_envelope_all_rows_and_info():
    W, y, b, lo, hi, _, rng = _problem(5)
    W_new = np.vstack([rng.standard_normal((4, W.shape[1])), np.zeros((1, W.shape[1]))])
    lo_e, hi_e, info = envelope_lp(W, y, b, lo, hi, W_new)
    assert info["lps"] == 8 and info["lp_solves"] >= 8  # the zero row needs no LP: its range is {0}
    assert info["lp_failures"] == 0
    assert lo_e[-1] <= 0.0 <= hi_e[-1] and hi_e[-1] - lo_e[-1] < 1e-290  # {0}, rounded outward
    lower, upper = prediction_envelope(W, y, b, (lo, hi), W_new)
    assert np.array_equal(lower, lo_e) and np.array_equal(upper, hi_e)


def test_envelope_bad_input():
    W, y, b, lo, hi, _, _ = _problem(1)
    with pytest.raises(ValueError, match="prior lower and upper"):
        prediction_envelope(W, y, b, (lo[:2], hi[:2]), W[:3])
    with pytest.raises(TypeError, match="prior must be"):
        prediction_envelope(W, y, b, 3.0, W[:3])
    with pytest.raises(ValueError, match="bound"):
        prediction_envelope(W, y, -b, (lo, hi), W[:3])
