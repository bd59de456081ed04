"""check_estimator and ``h4bench check-estimator``: the examples' unsound boxes fail with a proof point that exact
rational arithmetic (fractions) confirms feasible and outside the box; every built-in passes; defects of a plugin
(changed inputs, a wrong box, an exception) are each named. Oracles: Fraction arithmetic, scipy linprog."""

from __future__ import annotations

import re
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog
from typer.testing import CliRunner

from h4bench import ident
from h4bench.ident.estimators import check_estimator, registry
from h4bench.ident.estimators.conformance import problems
from h4bench.scenarios.cli import app

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(autouse=True)
def _examples_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))


def _exactly_feasible(problem, x) -> bool:
    """|y_k - W_k x| <= b_k for every row and x in the prior, in exact rational arithmetic."""
    xs = [Fraction(v) for v in x]
    if any(not (Fraction(lo) <= v <= Fraction(hi)) for v, lo, hi in zip(xs, problem.prior.lower, problem.prior.upper)):
        return False
    for Wk, yk, bk in zip(problem.W, problem.y, problem.bound):
        r = Fraction(yk) - sum(Fraction(w) * v for w, v in zip(Wk, xs))
        if abs(r) > Fraction(bk):
            return False
    return True


@pytest.mark.parametrize("spec", ["examples.shrunk_hull:estimate", "examples.shrunk_hull:rounded_inward"])
def test_the_unsound_examples_fail_with_a_proof_point(spec):
    report = check_estimator(spec)
    assert not report.passed
    outer = [r for r in report.failures if r.check == "outer"]
    assert outer and {r.check for r in report.failures} == {"outer"}
    by_name = {p.name: p for p in problems(0)}
    for r in outer:
        x = np.asarray(r.proof["point"])
        j = by_name[r.problem].prior.names.index(r.proof["parameter"])
        lo, hi = r.proof["box"]
        assert not lo <= x[j] <= hi  # the box excludes the point ...
        assert _exactly_feasible(by_name[r.problem], x), r.problem  # ... which is exactly feasible


@pytest.mark.parametrize("name", sorted(registry.BUILTINS))
def test_every_builtin_passes(name):
    report = check_estimator(name)
    assert report.passed, report.table()
    outer = {r.status for r in report.results if r.check == "outer"}
    assert outer == ({"skip"} if registry.get(name).kind == "statistical" else {"pass"})


def test_the_problems_are_what_they_say():
    """The empty problem is infeasible and the others feasible (scipy linprog); the bad-scaling rows span 1e8."""
    for p in problems(0):
        A = np.vstack([p.W, -p.W])
        rhs = np.r_[p.y + p.bound, -(p.y - p.bound)]
        res = linprog(np.zeros(p.W.shape[1]), A_ub=A, b_ub=rhs, bounds=list(zip(p.prior.lower, p.prior.upper)),
                      method="highs")
        assert (res.status == 2) == p.empty, p.name
    by_name = {p.name: p for p in problems(0)}
    assert by_name["fewer-rows"].W.shape[0] < by_name["fewer-rows"].W.shape[1]
    row = np.abs(by_name["bad-scaling"].W).max(axis=1)
    assert row.max() / row.min() > 1e7


def _plugin(defect):
    def f(W, y, bound, prior):
        if defect == "mutates":
            y[0] += 1.0
        if defect == "raises":
            raise RuntimeError("boom")
        box = ident.estimate(W, y, bound, prior)
        if defect == "shape":
            return ident.Box(box.lower[:-1], box.upper[:-1])
        return ident.Box(box.lower - 1.0, box.upper + 1.0, box.names)

    f.__name__ = f"plugin_{defect}"
    return f


@pytest.mark.parametrize(("defect", "check", "message"), [
    ("mutates", "inputs", "changed \\['y'\\]"),
    ("raises", "box", "RuntimeError: boom"),
    ("shape", "box", "EstimatorError: .*shape"),
])
def test_a_defect_is_named(defect, check, message):
    report = check_estimator(_plugin(defect))
    failed = [r for r in report.failures if r.check == check]
    assert failed and all(re.search(message, r.detail) for r in failed), report.table()


def test_a_sound_wider_plugin_passes():
    assert check_estimator(_plugin(None)).passed


def test_the_command_exits_non_zero_naming_the_check_and_the_proof(monkeypatch):
    monkeypatch.chdir(ROOT)
    runner = CliRunner()
    bad = runner.invoke(app, ["check-estimator", "examples.shrunk_hull:estimate"])
    assert bad.exit_code == 1
    assert "FAILED outer on random" in bad.output and "proof point" in bad.output
    good = runner.invoke(app, ["check-estimator", "hull"])
    assert good.exit_code == 0 and good.output.rstrip().endswith("PASSED")
