"""The estimator registry: built-ins, callables, ``module:attribute``, entry points (a fake installed distribution
written into tmp_path), broken plugins, result checks and the context keywords."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident.estimators import registry


def _problem(seed=0, m=60, p=3):
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((m, p))
    theta = rng.uniform(0.5, 1.5, p)
    y = W @ theta + rng.uniform(-0.1, 0.1, m)
    return W, y, 0.1, ident.Box(np.zeros(p), np.full(p, 2.0), names=("a", "b", "c")[:p]), theta


PLUGIN_SOURCE = '''
import numpy as np
from h4bench import ident

def estimator(W, y, bound, prior):
    """The prior itself: a valid (trivial) outer box."""
    return ident.Box(prior.lower, prior.upper, prior.names, info={"plugin": "prior"})

estimator.description = "the prior box"
'''


def test_builtins_are_registered_with_their_claims():
    assert tuple(registry.BUILTINS)[:2] == ("hull", "cgsp")
    assert {"ellipsoid", "zonotope", "parallelotope", "contractor", "ols", "wls", "iv"} <= set(registry.BUILTINS)
    for name in ("hull", "cgsp"):
        est = registry.get(name)
        assert est.kind == "guaranteed" and est.rigorous is True and est.origin == "built-in"
        assert est.description and est.citation
    names = [e.name for e in registry.available().estimators]
    assert names[:2] == ["hull", "cgsp"]


@pytest.mark.parametrize("method", ["hull", "cgsp"])
def test_builtins_through_the_registry_keep_their_box_and_info(method):
    W, y, b, prior, theta = _problem()
    direct = registry.get(method).resolve()(W, y, b, prior)  # hull_estimator / cgsp_estimator, unchecked
    via = ident.estimate(W, y, b, prior, method=method)
    assert np.array_equal(via.lower, direct.lower) and np.array_equal(via.upper, direct.upper)
    assert set(via.info) == set(direct.info) and via.info["method"] == method
    assert via.contains(theta).all()


def test_a_callable_is_an_estimator_and_its_attributes_are_its_claims():
    W, y, b, prior, theta = _problem()
    seen = {}

    def half_width(W, y, bound, prior):
        seen["bound"], seen["prior"] = bound, prior
        hull = ident.estimate(W, y, bound, prior)
        return ident.Box(hull.lower - 0.5, hull.upper + 0.5, prior.names)

    half_width.kind, half_width.level = "statistical", 0.9
    est = registry.get(half_width)
    assert (est.name, est.kind, est.level, est.rigorous, est.origin) == ("half_width", "statistical", 0.9, False,
                                                                          "callable")
    box = ident.estimate(W, y, b, prior, method=half_width)
    hull = ident.estimate(W, y, b, prior)
    # the plugin's own endpoints, exactly (its width is hull.width + 1 only up to the rounding of the subtraction)
    np.testing.assert_array_equal(box.lower, hull.lower - 0.5)
    np.testing.assert_array_equal(box.upper, hull.upper + 0.5)
    # a plugin gets the checked inputs: bound as (m,) floats, the prior as a Box with its names
    assert seen["bound"].shape == (W.shape[0],) and np.all(seen["bound"] == b) and seen["prior"].names == prior.names


def test_a_statistical_plugin_needs_a_level():
    def f(W, y, bound, prior):
        return prior

    f.kind = "statistical"
    with pytest.raises(ident.EstimatorError, match="'f'.*level in \\(0, 1\\)"):
        registry.get(f)
    f.kind = "bayesian"
    with pytest.raises(ident.EstimatorError, match="kind must be one of"):
        registry.get(f)


def test_module_attribute_string(tmp_path, monkeypatch):
    (tmp_path / "h4plugin_modattr.py").write_text(PLUGIN_SOURCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    W, y, b, prior, _ = _problem()
    box = ident.estimate(W, y, b, prior, method="h4plugin_modattr:estimator")
    assert np.array_equal(box.lower, prior.lower) and box.info == {"plugin": "prior"}
    est = registry.get("h4plugin_modattr:estimator")
    assert est.origin == "h4plugin_modattr:estimator" and est.description == "the prior box"
    with pytest.raises(ident.EstimatorError, match="has no attribute 'missing'"):
        registry.get("h4plugin_modattr:missing")
    with pytest.raises(ident.EstimatorError, match="cannot import 'h4plugin_nowhere'"):
        registry.get("h4plugin_nowhere:estimator")


def _fake_distribution(tmp_path, entries: str) -> None:
    info = tmp_path / "h4fakeplug-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: h4fakeplug\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entries))
    (tmp_path / "h4fakeplug_mod.py").write_text(PLUGIN_SOURCE + "\nnot_callable = 3\n")


def test_entry_points_are_listed_and_broken_ones_reported(tmp_path, monkeypatch):
    _fake_distribution(tmp_path, """\
        [h4bench.estimators]
        fake_prior = h4fakeplug_mod:estimator
        fake_broken = h4fakeplug_missing_module:estimator
        fake_number = h4fakeplug_mod:not_callable
        hull = h4fakeplug_mod:estimator
        """)
    monkeypatch.syspath_prepend(str(tmp_path))
    found = registry.available()
    by_name = {e.name: e for e in found.estimators}
    assert by_name["fake_prior"].origin == "entry point h4fakeplug"
    assert by_name["hull"].origin == "built-in"  # a plugin cannot take a built-in's name
    broken = dict(found.broken)
    assert set(broken) == {"fake_broken", "fake_number", "hull"}
    assert "h4fakeplug_missing_module" in broken["fake_broken"] and "not a callable" in broken["fake_number"]
    W, y, b, prior, _ = _problem()
    box = ident.estimate(W, y, b, prior, method="fake_prior")
    assert box.info == {"plugin": "prior"}
    with pytest.raises(ident.EstimatorError, match="'fake_broken'.*cannot load"):
        ident.estimate(W, y, b, prior, method="fake_broken")


def test_unknown_method_and_wrong_type():
    with pytest.raises(ident.EstimatorError, match=r"method must be one of \('hull', 'cgsp', .*\).*got 'nope'"):
        registry.get("nope")
    with pytest.raises(TypeError, match="method must be a string"):
        registry.get(3)


@pytest.mark.parametrize("result, what", [
    (lambda prior: ident.Box(prior.lower[:2], prior.upper[:2]), "shape"),
    (lambda prior: (prior.lower, np.r_[prior.upper[:2], np.nan]), "non-finite"),
    (lambda prior: ident.Box(prior.lower, np.r_[prior.upper[:2], np.inf]), "non-finite"),
    (lambda prior: (prior.upper, prior.lower), "lower > upper"),
    (lambda prior: {"lower": prior.lower}, "not an ident.Box"),
])
def test_an_invalid_box_is_an_estimator_error_naming_the_plugin(result, what):
    W, y, b, prior, _ = _problem()

    def bad_plugin(W, y, bound, prior):
        return result(prior)

    with pytest.raises(ident.EstimatorError, match=f"'bad_plugin' \\(callable\\) returned .*{what}"):
        ident.estimate(W, y, b, prior, method=bad_plugin)


def test_proven_empty_propagates():
    W, y, b, prior, _ = _problem()

    def empty(W, y, bound, prior):
        raise ident.InconsistentDataError("empty", min_bound=1.0, bound=0.1, scale_lower=2.0)

    with pytest.raises(ident.InconsistentDataError):
        ident.estimate(W, y, b, prior, method=empty)


def test_context_keywords_are_passed_only_when_accepted():
    W, y, b, prior, _ = _problem()
    m, p = W.shape
    groups = np.arange(m) % 3
    instruments = W + 1.0
    got = {}

    def plain(W, y, bound, prior):  # would raise TypeError if given a keyword
        return prior

    def with_groups(W, y, bound, prior, groups=None):
        got["groups"] = groups
        return prior

    def with_kwargs(W, y, bound, prior, **context):
        got["kwargs"] = context
        return prior

    for f in (plain, with_groups, with_kwargs):
        ident.estimate(W, y, b, prior, method=f, groups=groups, instruments=instruments)
    assert np.array_equal(got["groups"], groups)
    assert set(got["kwargs"]) >= {"groups", "instruments"} and np.array_equal(got["kwargs"]["instruments"],
                                                                             instruments)
    with pytest.raises(ValueError, match=r"instruments must have shape \(60, 3\)"):
        ident.estimate(W, y, b, prior, method=with_kwargs, instruments=instruments[:, :2])
    with pytest.raises(ValueError, match=r"groups must be an integer array of shape \(60,\)"):
        ident.estimate(W, y, b, prior, method=with_groups, groups=groups[:-1])


def test_the_spec_check_and_identify_accept_what_the_registry_resolves(tmp_path, monkeypatch):
    from h4bench.scenarios.identify import check_method
    from h4bench.scenarios.spec import ScenarioError, load_spec

    (tmp_path / "h4plugin_spec.py").write_text(PLUGIN_SOURCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    spec = tmp_path / "s.toml"
    spec.write_text('kind = "paper"\n[estimators]\nmethods = ["hull", "h4plugin_spec:estimator"]\n')
    assert load_spec(spec)["estimators"]["methods"] == ["hull", "h4plugin_spec:estimator"]
    spec.write_text('kind = "paper"\n[estimators]\nmethods = ["hull", "lsq"]\n')
    with pytest.raises(ScenarioError, match="estimators.methods: method must be one of .*got 'lsq'"):
        load_spec(spec)
    assert check_method("wls") == "wls" and check_method("h4plugin_spec:estimator") == "h4plugin_spec:estimator"
    with pytest.raises(ValueError, match=r"method must be one of \('hull', 'cgsp', .*'wls'"):
        check_method("lsq")
