"""One door for untrusted code: no path of h4bench runs a plugin's code (its import or its call) in the caller's process.

Two halves. The walk: every call in the package (and the benchmarks) that runs or resolves an estimator by name
(a call of ``ident.estimate``, ``registry.get/call/takes/available``, ``isolation.resolve/call/available``, a
``.resolve()(...)`` or any call with a non-literal ``method=``) is found in the source and must be one of
:data:`SITES`, each mapped to a case below. The cases: each site's function run with a plugin that writes its
process id to a log at import and at every call (the oracle: the plugin's own record of where it ran, independent
of the door). Every case must reach the plugin (else it proves nothing) and never in this test's process.
On the code before the door, the replay's box history ran the plugin here (``case_box_history`` fails).
"""

from __future__ import annotations

import ast
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from h4bench import ident
from tests.scenarios.plugin_cases import fake_distribution, prefix_run

ROOT = Path(__file__).resolve().parents[2]
WALKED = ("ident", "scenarios", "trajectories", "sim", "h4bench", "benchmarks")

PLUGIN = '''\
import os
from h4bench import ident

def _note(what):
    with open(os.environ["H4BENCH_DOOR_LOG"], "a") as f:
        f.write(f"{what} {os.getpid()}\\n")

_note("import")

def estimate(W, y, bound, prior, **context):
    _note("call")
    return ident.Box(prior.lower, prior.upper, prior.names)
'''

#: every site that runs or resolves an estimator by name ("file:function") -> the case that runs it
SITES = {
    "ident/estimators/estimate.py:estimate": "estimate",
    "ident/estimators/registry.py:_call_here": "registry_call",  # what a door's child runs (every case reaches it)
    "ident/estimators/isolation.py:resolve": "isolation_resolve",
    "ident/estimators/isolation.py:available": "available",
    "ident/estimators/isolation.py:call": "isolation_call",
    "ident/estimators/conformance.py:_check_problem": "check_estimator",
    "ident/estimators/conformance.py:check_estimator": "check_estimator",
    "scenarios/experiment.py:_takes": "takes",
    "scenarios/feasible.py:reference_sets": "reference_sets",
    "scenarios/judging/running.py:run_method": "run_methods",
    "scenarios/judging/running.py:parse_methods": "parse_methods",
    "scenarios/judging/running.py:describe_estimators": "available",
    "scenarios/kinds/paper.py:feasible_set": "isolation_resolve",  # the kinds of the sets reference_sets drew
    "scenarios/plugins.py:methods_code": "methods_code",
    "scenarios/plugins.py:_plugin_source": "methods_code",
    "scenarios/plugins.py:worker_lacks": "worker_lacks",
    "scenarios/replay.py:box_history": "box_history",
    "scenarios/replay.py:_contained_estimator.estimator": "box_history",
    "scenarios/spec.py:_check_methods": "spec_methods",
    "benchmarks/bench_estimators.py:bench_size": "registry_call",
    "benchmarks/bench_estimators.py:main": "registry_get",
    "benchmarks/bench_isolation.py:main": "isolation_call",
}
_OWNERS = {"h4bench.ident.estimators.registry": ("get", "call", "takes", "available"),
           "h4bench.ident.estimators.isolation": ("resolve", "call", "available"),
           "h4bench.ident": ("estimate",), "h4bench.ident.estimators.estimate": ("estimate",)}


def _imported(tree) -> dict[str, str]:
    """Local name -> imported module or object (``from h4bench.ident.estimators import registry`` -> registry)."""
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            for a in node.names:
                out[a.asname or a.name] = f"{node.module}.{a.name}"
        elif isinstance(node, ast.Import):
            for a in node.names:
                out[a.asname or a.name] = a.name
    return out


def _by_name(call: ast.Call, names: dict[str, str]) -> bool:
    fn = call.func
    method = [k.value for k in call.keywords if k.arg == "method"]
    if method and not isinstance(method[0], ast.Constant) and isinstance(fn, ast.Name) and fn.id not in names:
        return True  # a callback given the method by name: the box history's estimator(W, y, b, prior, method=m)
    if isinstance(fn, ast.Call) and isinstance(fn.func, ast.Attribute) and fn.func.attr == "resolve" and not fn.args:
        return True  # registry.get(m).resolve()(...)
    if isinstance(fn, ast.Attribute) and isinstance(fn.value, ast.Name):
        owner, attr = names.get(fn.value.id), fn.attr
    elif isinstance(fn, ast.Name) and fn.id in names:
        owner, _, attr = names[fn.id].rpartition(".")
    else:
        return False
    if attr not in _OWNERS.get(owner, ()):
        return False
    if attr != "estimate":
        return True
    given = call.args[4:5] or method  # ident.estimate(W, y, b, prior[, method]): the default is the hull
    return bool(given) and not isinstance(given[0], ast.Constant)


def walk() -> set[str]:
    """The sites (``file:function``) of the package and the benchmarks that run or resolve an estimator by name."""
    found = set()
    for pkg in WALKED:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text())
            names = _imported(tree)
            if path.parent.name == "estimators" and path.parent.parent.name == "ident":
                names.setdefault("estimate", "h4bench.ident.estimators.estimate.estimate")
            stack: list[str] = []

            class Visit(ast.NodeVisitor):
                def visit_FunctionDef(self, node):
                    stack.append(node.name)
                    self.generic_visit(node)
                    stack.pop()

                def visit_Call(self, node):
                    if _by_name(node, names):
                        found.add(f"{path.relative_to(ROOT)}:{'.'.join(stack) or '<module>'}")
                    self.generic_visit(node)

            Visit().visit(tree)
    return found


def test_the_walk_finds_every_site_and_only_known_ones():
    found = walk()
    assert "scenarios/replay.py:box_history" in found  # the call that ran plugins in-process before the door
    assert found - set(SITES) == set(), "a new site runs an estimator by name: add it to SITES with a case"
    assert set(SITES) - found == set(), "a site of SITES is gone: remove it"


def test_the_walk_sees_calls_by_name_and_not_literal_builtins():
    """The walker itself: it must flag a call by name and pass a literal built-in (a walker that flags nothing, or
    everything, would pass or fail whatever the package holds)."""
    names = {"ident": "h4bench.ident", "registry": "h4bench.ident.estimators.registry"}
    flagged = [_by_name(ast.parse(src).body[0].value, names) for src in (
        "ident.estimate(W, y, b, p, method=m)", "ident.estimate(W, y, b, p, method='hull')", "ident.estimate(W, y, b, p)",
        "registry.call(m, W, y, b, p)", "registry.get(m).resolve()(W, y, b, p)", "f(W, method=m)", "g(W, y)",
        "ident.estimate(W, y, b, p, m)", "ident.relaxed_hull(W, y, b, p, 1, method=m)")]
    assert flagged == [True, False, False, True, True, True, False, True, False]


# ------------------------------------------------------------------------------------------------ the cases
@pytest.fixture
def door(tmp_path, monkeypatch):
    """The plugin ``doorplug:estimate`` (also installed as the entry point ``doorep``), its log, a small problem."""
    from h4bench.ident.estimators import isolation

    (tmp_path / "doorplug.py").write_text(PLUGIN)
    site = tmp_path / "site"
    fake_distribution(site, "doordist", {"doorep": "doorplug:estimate"})
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.syspath_prepend(str(site))
    log = tmp_path / "door.log"
    monkeypatch.setenv("H4BENCH_DOOR_LOG", str(log))
    isolation.forget()
    rng = np.random.default_rng(1)
    W = rng.standard_normal((80, 3))
    y = W @ np.ones(3) + rng.uniform(-0.1, 0.1, 80)
    yield SimpleNamespace(method="doorplug:estimate", log=log, W=W, y=y, bound=np.full(80, 0.1),
                          prior=ident.Box(np.zeros(3), np.full(3, 2.0), ("a", "b", "c")))
    isolation.forget()


def _fake_run(d):
    """What box_history reads of an ExperimentRun: 20 samples of 4 rows, no box yet (every point estimated)."""
    return prefix_run(d.W, d.y, d.bound, d.prior)


def case_estimate(d):
    ident.estimate(d.W, d.y, d.bound, d.prior, method=d.method)


def case_registry_call(d):
    from h4bench.ident.estimators import registry

    registry.call(d.method, d.W, d.y, d.bound, d.prior, groups=np.arange(80) % 4)


def case_registry_get(d):
    from h4bench.ident.estimators import registry

    registry.get(d.method).resolve()(d.W, d.y, d.bound, d.prior)


def case_isolation_call(d):
    from h4bench.ident.estimators import isolation

    isolation.call(d.method, d.W, d.y, d.bound, d.prior)


def case_isolation_resolve(d):
    from h4bench.ident.estimators import isolation

    assert isolation.resolve(d.method).source["sha256"]


def case_run_methods(d):
    from h4bench.scenarios import judging

    outcomes, _ = judging.run_methods([d.method], d.W, d.y, d.bound, d.prior)
    assert outcomes[d.method].status == "ok"


def case_box_history(d):
    from h4bench.scenarios.replay import box_history

    h = box_history(_fake_run(d), methods=(d.method,), points=3)
    assert h["methods"][d.method]["ok"].all()


def case_reference_sets(d):
    from h4bench.scenarios.feasible import reference_sets

    boxes, _, skipped = reference_sets(d.W, d.y, d.bound, d.prior, [d.method])
    assert d.method in boxes, skipped


def case_check_estimator(d):
    from h4bench.ident.estimators import check_estimator

    assert check_estimator(d.method).results


def case_takes(d):
    from h4bench.scenarios import experiment

    assert experiment._takes(d.method, "groups") is True  # the plugin takes **context


def case_parse_methods(d):
    from h4bench.scenarios import judging

    assert judging.parse_methods(f"hull,{d.method}") == ["hull", d.method]


def case_available(d):
    from h4bench.scenarios import judging

    assert "doorep" in [e["name"] for e in judging.describe_estimators()["estimators"]]


def case_methods_code(d):
    from h4bench.scenarios import plugins

    assert plugins.methods_code([d.method])[d.method]["sha256"]


def case_worker_lacks(d):
    from h4bench.scenarios import plugins

    assert plugins.worker_lacks([d.method]) == {}


def case_spec_methods(d):
    from h4bench.scenarios import spec

    spec._check_methods(["hull", d.method, "doorep"], "estimators.methods")


CASES = {name[len("case_"):]: f for name, f in globals().items() if name.startswith("case_")}


def test_every_site_has_a_case():
    assert set(SITES.values()) <= set(CASES)


@pytest.mark.parametrize("case", sorted(CASES))
def test_no_site_runs_a_plugin_in_this_process(door, case):
    CASES[case](door)
    lines = door.log.read_text().split() if door.log.exists() else []
    records = list(zip(lines[::2], map(int, lines[1::2])))
    assert records, f"{case}: the plugin never ran (the case proves nothing)"
    here = [what for what, pid in records if pid == os.getpid()]
    assert here == [], f"{case}: the plugin's {here} ran in the caller's process"
