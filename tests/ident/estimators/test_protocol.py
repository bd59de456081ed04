"""Every reference estimator through the estimator registry by ``module:attribute``: its claims, the context
keywords it takes, a valid box inside the prior and a set of the documented types."""

import numpy as np
import pytest

from h4bench.ident.estimators import registry
from tests.ident.estimators import oracles

SPECS = {
    "h4bench.ident.estimators.ellipsoid:ellipsoid": ("guaranteed", False, "ellipsoid"),
    "h4bench.ident.estimators.zonotope:zonotope": ("guaranteed", False, "zonotope"),
    "h4bench.ident.estimators.zonotope:parallelotope": ("guaranteed", False, "zonotope"),
    "h4bench.ident.estimators.contractor:contractor": ("guaranteed", True, "zonotope"),
    "h4bench.ident.estimators.statistical:ols": ("statistical", False, "ellipsoid"),
    "h4bench.ident.estimators.statistical:wls": ("statistical", False, "ellipsoid"),
    "h4bench.ident.estimators.statistical:iv": ("statistical", False, "ellipsoid"),
}


@pytest.mark.parametrize("spec", sorted(SPECS))
def test_through_the_registry(spec):
    kind, rigorous, set_type = SPECS[spec]
    rng = np.random.default_rng(2)
    W, y, b, prior, theta = oracles.problem(rng, 4, 400, prior_halfwidth=0.2)
    est = registry.get(spec)
    assert (est.kind, est.rigorous) == (kind, rigorous)
    assert est.description and est.citation
    assert (est.level == 0.95) if kind == "statistical" else est.level is None
    box = registry.call(est, W, y, b, prior, groups=np.arange(400) % 4, instruments=W)
    assert np.all(box.lower >= prior.lower) and np.all(box.upper <= prior.upper)
    assert box.names == prior.names
    S = box.info["set"]
    assert S["type"] == set_type
    c = np.asarray(S["center"])
    if set_type == "ellipsoid":
        assert np.asarray(S["shape"]).shape == (4, 4)
    else:
        assert np.asarray(S["generators"]).shape[0] == 4
    assert c.shape == (4,)
    if kind == "guaranteed":
        assert oracles.encloses_exact_hull(box, W, y, b, prior)


@pytest.mark.parametrize("name", sorted(registry.BUILTINS))
def test_the_claims_are_the_same_on_every_path(name):
    """A built-in by name, as ``module:attribute`` and as the callable: one set of claims (read from the function)."""
    by_name = registry.get(name)
    func = by_name.resolve()
    spec = f"{func.__module__}:{func.__name__}"
    fields = registry.CLAIMS
    for other in (registry.get(spec), registry.get(func)):
        assert [getattr(other, f) for f in fields] == [getattr(by_name, f) for f in fields], other.origin
    assert by_name.origin == "built-in" and by_name.description and by_name.citation


def test_context_reaches_only_the_estimators_that_take_it():
    """check_consistency (a built-in's keyword) never reaches a plugin taking ``**context``; groups does."""
    from h4bench import ident

    seen = {}

    def plugin(W, y, bound, prior, **context):
        seen.update(context)
        return prior

    rng = np.random.default_rng(3)
    W, y, b, prior, theta = oracles.problem(rng, 3, 40)
    ident.estimate(W, y, b, prior, method=plugin, groups=np.arange(40) % 4, check_consistency=False)
    assert set(seen) == {"groups"}
    assert registry.takes(plugin, "instruments") and not registry.takes(plugin, "check_consistency")
    assert registry.takes("iv", "instruments") and not registry.takes("hull", "instruments")
    assert not registry.takes("no-such-estimator", "instruments")
    assert registry.get("hull").context == ("check_consistency",)
    assert registry.get("iv").context == ("instruments",) and registry.get("wls").context == ("groups",)


def test_a_declared_context_the_signature_does_not_take_is_refused():
    with pytest.raises(registry.EstimatorError, match="declares the context \\['groups'\\]"):
        @registry.declare(context=("groups",))
        def f(W, y, bound, prior):
            return prior
