"""ident.estimators.isolation: the built-ins are safe in-process (they never write to their inputs), a plugin in its
child process cannot change what the caller holds, HiGHS and OpenBLAS work in a child forked after the parent
used them, and a plugin's exceptions of every kind come back as its failure by name."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident.estimators import isolation, registry
from tests.conftest import bounded_noise_problem


@pytest.fixture(scope="module")
def problem():
    W, theta, y = bounded_noise_problem(np.random.default_rng(3), 120, 3)
    bound = np.ones(len(y))
    prior = ident.Box(np.zeros(3), np.full(3, 2.0))
    groups = np.arange(len(y)) % 4
    return W, y, bound, prior, groups


def test_every_builtin_runs_on_read_only_inputs_and_leaves_them_unchanged(problem):
    """A built-in that wrote to its inputs would raise on the read-only views; the oracle is the same built-in on
    writable copies through the registry (same box)."""
    W, y, bound, prior, groups = problem
    keep = [a.copy() for a in (W, y, groups)]
    for name in registry.BUILTINS:
        # every context a built-in may take (the registry passes each only what it declares)
        ctx = {"groups": groups, "instruments": W, "regressor_radius": np.zeros_like(W)}
        try:
            box = isolation.call(name, W, y, bound, prior, **ctx)
        except ident.InconsistentDataError:
            continue
        oracle = registry.call(name, W.copy(), y.copy(), bound, prior, **{k: v.copy() for k, v in ctx.items()})
        assert np.array_equal(box.lower, oracle.lower) and np.array_equal(box.upper, oracle.upper), name
    assert all(np.array_equal(a, b) for a, b in zip((W, y, groups), keep))


def _hull_plugin(W, y, bound, prior):
    return ident.estimate(W, y, bound, prior, method="hull")


def test_hull_in_a_child_after_the_parent_used_highs(problem):
    """HiGHS (threads) and OpenBLAS used here first, then in the forked child: the same box, no hang."""
    W, y, bound, prior, _ = problem
    here = ident.estimate(W, y, bound, prior, method="hull")
    child = isolation.call(_hull_plugin, W, y, bound, prior, timeout=60)
    assert np.array_equal(here.lower, child.lower) and np.array_equal(here.upper, child.upper)
    with_timeout = isolation.call("hull", W, y, bound, prior, timeout=60)  # a built-in in a child
    assert np.array_equal(here.lower, with_timeout.lower)


def _writes_through_base(W, y, bound, prior):
    root = W
    while root.base is not None:
        root = root.base
    root[0, 0] += 1.0
    return prior


def _raises_keyboard_interrupt(W, y, bound, prior):
    raise KeyboardInterrupt


def _returns_nan(W, y, bound, prior):
    return (np.full(len(prior), np.nan), prior.upper)


def test_a_plugin_cannot_change_the_callers_arrays(problem):
    W, y, bound, prior, _ = problem
    keep = W.copy()
    with pytest.raises(ident.EstimatorError, match=r"'_writes_through_base'.*changed its inputs in place \(W\)"):
        isolation.call(_writes_through_base, W, y, bound, prior)
    assert np.array_equal(W, keep)


def test_every_kind_of_failure_is_the_plugins_by_name(problem):
    W, y, bound, prior, _ = problem
    with pytest.raises(ident.EstimatorError, match="'_raises_keyboard_interrupt'.*KeyboardInterrupt"):
        isolation.call(_raises_keyboard_interrupt, W, y, bound, prior)
    with pytest.raises(ident.EstimatorError, match="'_returns_nan'.*non-finite"):
        isolation.call(_returns_nan, W, y, bound, prior)
    with pytest.raises(ValueError, match="timeout must be"):
        isolation.call(_returns_nan, W, y, bound, prior, timeout=0)


def test_inconsistent_comes_back_as_inconsistent(problem):
    W, y, bound, prior, _ = problem
    with pytest.raises(ident.InconsistentDataError) as here:
        ident.estimate(W, y, 1e-6 * bound, prior, method="hull")
    with pytest.raises(ident.InconsistentDataError) as child:
        isolation.call(_hull_plugin, W, y, 1e-6 * bound, prior)
    assert child.value.min_bound == here.value.min_bound and child.value.scale_lower == here.value.scale_lower
