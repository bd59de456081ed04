"""The width analysis (scenarios/explain.py): the slice widths against an LP oracle (scipy's HiGHS), and the
slice never wider than the hull it bounds from below."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from h4bench import ident
from h4bench.scenarios.explain import slice_widths, width_analysis


def _problem(seed, m=300, p=6, b=0.5):
    rng = np.random.default_rng(seed)
    W = rng.normal(size=(m, p)) * rng.uniform(0.1, 3.0, p)
    W[rng.random((m, p)) < 0.2] = 0.0  # rows that do not see a parameter (as the per-joint friction columns)
    theta = rng.uniform(0.5, 1.5, p)
    bound = np.full(m, b) * rng.uniform(0.5, 1.5, m)
    y = W @ theta + bound * rng.uniform(-0.95, 0.95, m)
    return W, y, bound, theta


@pytest.mark.parametrize("seed", range(5))
def test_slice_widths_match_an_lp_with_the_others_fixed(seed):
    W, y, bound, theta = _problem(seed)
    p = W.shape[1]
    lo, hi = np.zeros(p), np.full(p, 2.0)
    got = slice_widths(W, y, bound, theta, lo, hi)
    A, ub = np.vstack([W, -W]), np.concatenate([y + bound, bound - y])
    for j in range(p):
        box = [(lo[j], hi[j]) if k == j else (theta[k], theta[k]) for k in range(p)]
        ends = [scipy.optimize.linprog(c * np.eye(p)[j], A_ub=A, b_ub=ub, bounds=box, method="highs").x[j]
                for c in (1.0, -1.0)]
        assert got[j] == pytest.approx(ends[1] - ends[0], rel=1e-9, abs=1e-12)


def test_slice_is_within_the_hull_and_reported():
    W, y, bound, theta = _problem(7, m=400, p=5)
    p = W.shape[1]
    prior = ident.Box(np.zeros(p), np.full(p, 2.0))
    hull = ident.estimate(W, y, bound, prior, method="hull")
    a = width_analysis(W, y, bound, theta, prior.lower, prior.upper, [f"x{j}" for j in range(p)], hull.width)
    sw = np.asarray(a["slice_width"])
    assert np.all(sw > 0) and np.all(sw <= np.asarray(hull.width) * (1 + 1e-9) + 1e-12)
    assert "slice_ratio_to_paper" in a and a["slice_at_most_paper"] == 0  # no paper values for these names


def test_slice_is_empty_when_the_bound_misses_the_truth():
    W, y, bound, theta = _problem(3)
    W, y = W.copy(), y.copy()
    W[0], y[0] = 0.0, 2 * bound[0]  # a row no parameter value explains: every slice is empty
    sw = slice_widths(W, y, bound, theta, np.zeros(W.shape[1]), np.full(W.shape[1], 2.0))
    assert np.all(sw == 0.0)
    # a slice that is empty because the constraints cross: the row's interval for x0 lies outside the prior
    W2, y2 = W[1:].copy(), y[1:].copy()
    W2[0] = 0.0
    W2[0, 0] = 1.0
    y2[0] = theta[0] + 10.0  # needs x0 >= theta0 + 10 - b, beyond the prior's 2
    assert slice_widths(W2, y2, bound[1:], theta, np.zeros(W.shape[1]), np.full(W.shape[1], 2.0))[0] == 0.0
