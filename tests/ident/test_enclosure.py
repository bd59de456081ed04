"""The one decide-empty / inflate / retry / fall-back step (:func:`ident.estimators.enclosure.decide_and_enclose`),
driven by scripted hull and consistency results (each branch), then through ident.estimate on data built to be
empty or non-empty (the Chebyshev LP is the oracle of the factor the bounds need)."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident.estimators.enclosure import INFLATION, Verdict, decide_and_enclose
from h4bench.ident.estimators.hull import HullResult

LO, HI = np.zeros(2), np.ones(2)


class Empty(Exception):
    pass


def run(results, verdict, residual=2.0):
    calls = {"hull": [], "decide": 0, "fallback": []}

    def hull(factor, start):
        calls["hull"].append((factor, np.array(start)))
        return results.pop(0)

    def decide():
        calls["decide"] += 1
        return verdict

    out = decide_and_enclose(hull, decide, lambda t: residual, lambda lo, up: Empty(lo, up),
                             calls["fallback"].append, np.full(2, 0.5), LO, HI)
    return out, calls


def ok(lower=(0.2, 0.2), upper=(0.8, 0.8)):
    return HullResult(np.array(lower), np.array(upper), "ok", {}, points=np.full((2, 4), 0.5))


def test_mean_point_proves_nonempty_without_the_consistency_lp():
    (res, verdict, factor), calls = run([ok()], Verdict(0.0, 0.0, LO, True), residual=0.5)
    assert verdict is None and factor is None and calls["decide"] == 0 and len(calls["hull"]) == 1


def test_consistency_lp_decides_when_the_mean_point_fails():
    v = Verdict(0.9, 0.95, np.full(2, 0.4), True)
    (res, verdict, factor), calls = run([ok()], v)
    assert verdict is v and factor is None and calls["decide"] == 1
    with pytest.raises(Empty) as exc:
        run([ok()], Verdict(1.5, 1.6, LO, True))
    assert exc.value.args == (1.5, 1.6)


def test_infeasible_hull_inflates_from_the_verified_point_or_proves_empty():
    theta = np.full(2, 0.3)
    infeasible = HullResult(LO.copy(), HI.copy(), "infeasible", {})
    (res, verdict, factor), calls = run([infeasible, ok()], Verdict(0.99, 1.02, theta, True))
    assert factor == 1.02 * INFLATION and calls["hull"][1][0] == factor
    assert np.array_equal(calls["hull"][1][1], theta) and np.array_equal(res.lower, [0.2, 0.2])
    with pytest.raises(Empty) as exc:
        run([infeasible], Verdict(1.2, 1.3, theta, True))
    assert exc.value.args == (1.2, 1.3)


def test_crossing_endpoints_prove_empty_when_the_lp_fails_and_a_failed_retry_falls_back_to_the_prior():
    crossed = ok(lower=(0.6, 0.2), upper=(0.5, 0.8))
    with pytest.raises(Empty) as exc:
        run([crossed], Verdict(0.0, 3.0, LO, False))
    assert exc.value.args == (1.0, 3.0)  # proven by the crossing itself: the factor is at least 1
    (res, _, factor), calls = run([crossed, crossed], Verdict(0.5, 0.9, LO, True))
    assert factor == 1.0 * INFLATION and calls["fallback"]
    assert np.array_equal(res.lower, LO) and np.array_equal(res.upper, HI)


def test_estimate_through_the_step_on_empty_and_thin_sets():
    rng = np.random.default_rng(3)
    W = rng.standard_normal((200, 3))
    y = W @ np.ones(3) + rng.uniform(-0.1, 0.1, 200)
    prior = (np.zeros(3), 2 * np.ones(3))
    t = ident.min_consistent_bound(W, y, prior)  # the oracle: the smallest consistent scalar bound (rounded up)
    with pytest.raises(ident.InconsistentDataError) as exc:
        ident.estimate(W, y, 0.9 * t, prior)
    assert exc.value.min_bound >= t * (1 - 1e-9) and exc.value.scale_lower > 1.0
    box = ident.estimate(W, y, t, prior)  # consistent but nearly a point: enclosed, never empty
    assert np.all(box.lower <= box.upper)
