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


def test_registered_claims_match_the_modules():
    """The built-in registry entries (written without importing the modules) claim what the functions say."""
    for spec in SPECS:
        by_name = [e for e in registry.BUILTINS.values() if e.func == spec]
        assert len(by_name) == 1, f"{spec} is not registered once"
        est, func = by_name[0], registry.get(spec).resolve()
        assert (est.kind, est.rigorous, est.level) == (func.kind, func.rigorous, getattr(func, "level", None))
