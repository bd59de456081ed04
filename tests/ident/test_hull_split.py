"""The hull's minima and maxima as two halves (:mod:`ident.estimators.hull_split`), in one process or two.

Oracles: the one-model hull of the same rows (the same set: endpoints within the LPs' tolerance of it) and random
points of the exact Oettli-Prager set (inside every box); one process against two: the same bits.
"""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident.estimators.hull import interval_hull
from h4bench.ident.estimators.hull_split import HullSplit
from h4bench.ident.estimators.uncertain_signed import signed_uncertain_hull


def _problem(m=900, p=5, seed=7):
    rng = np.random.default_rng(seed)
    Wc = rng.normal(size=(m, p))
    D = 0.03 * np.abs(rng.normal(size=(m, p)))
    theta0 = rng.uniform(-2, 2, p)
    y = Wc @ theta0 + rng.uniform(-0.3, 0.3, m)
    return Wc, D, y, np.full(m, 0.3), theta0, rng


def test_two_halves_are_the_one_model_hull():
    rng = np.random.default_rng(3)
    W = rng.normal(size=(2000, 6))
    x0 = rng.uniform(-1, 1, 6)
    c = W @ x0
    bl, bu = c - 0.5, c + 0.5
    lo, hi = -5 * np.ones(6), 5 * np.ones(6)
    one = interval_hull(W, bl, bu, lo, hi)
    with HullSplit(1) as split:
        two = split.hull(W, bl, bu, lo, hi)
    w = one.upper - one.lower
    assert np.all(np.abs(two.lower - one.lower) <= 1e-6 * w) and np.all(np.abs(two.upper - one.upper) <= 1e-6 * w)
    assert two.info["lp_solves"] > 0 and two.warm.minima is not None and two.warm.maxima is not None
    # a half alone: its own endpoints, the prior's on the other side
    half = interval_hull(W, bl, bu, lo, hi, lps=range(6))
    assert np.array_equal(half.lower, two.lower) and np.array_equal(half.upper, hi)


@pytest.mark.parametrize("coarse", [1, 4])
def test_one_or_two_processes_give_the_same_bits_and_enclose_the_set(coarse):
    Wc, D, y, b, theta0, rng = _problem()
    prior = ident.Box(np.full(5, -6.0), np.full(5, 6.0))
    groups = np.repeat(np.arange(300), 3)
    kw = dict(refine=6, rtol=0.02, coarse=coarse, groups=groups)
    a = signed_uncertain_hull(Wc, D, y, b, prior, processes=1, **kw)
    b2 = signed_uncertain_hull(Wc, D, y, b, prior, processes=2, **kw)
    assert np.array_equal(a.lower, b2.lower) and np.array_equal(a.upper, b2.upper)
    assert a.info["lp_solves"] == b2.info["lp_solves"] and a.info["refinements"] == b2.info["refinements"]
    one_model = signed_uncertain_hull(Wc, D, y, b, prior, **kw)
    assert np.allclose(a.upper - a.lower, one_model.upper - one_model.lower, rtol=0.05)
    pts = rng.uniform(one_model.lower, one_model.upper, (40000, 5))
    feasible = np.all(np.abs(y[None] - pts @ Wc.T) <= b + np.abs(pts) @ D.T, axis=1)
    assert feasible.sum() > 10
    assert all(np.all(a.contains(t)) for t in pts[feasible]) and np.all(a.contains(theta0))


def test_processes_other_than_one_or_two_are_refused():
    with pytest.raises(ValueError, match="processes must be 1 or 2"):
        HullSplit(3)


def test_an_error_in_the_block_stops_the_worker():
    W = np.random.default_rng(1).normal(size=(400, 4))
    c = W @ np.ones(4)
    with pytest.raises(RuntimeError, match="stop"):
        with HullSplit(2) as split:
            split.hull(W, c - 0.5, c + 0.5, -5 * np.ones(4), 5 * np.ones(4))
            procs = list(split._pool._processes.values())
            assert procs and all(p.is_alive() for p in procs)
            raise RuntimeError("stop")
    for p in procs:
        p.join(timeout=10)
        assert not p.is_alive()
