"""A plugin's failure costs only its own entry on every path, not only in the methods' main call.

A user met it: with ``run paper --methods hull,P``, P calling ``sys.exit(4)`` ended the command with exit 4, nothing
printed and no run folder; ``os._exit(0)`` made it exit 0; a printing P put ten lines before the ``--json``
document. The replay's box history ran P in-process on growing prefixes of the rows. The fast tests run each kind of
failure (tests/scenarios/plugin_cases.py: exits, a crash, changed W, y, bound or prior, a raise, a sleep past the
time limit, output) through the secondary uses directly; the slow ones through the commands, against the same
command without the plugin as the oracle of the other methods' boxes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from h4bench import ident
from tests.scenarios.plugin_cases import FAILURES, prefix_run, write_plugin

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def plugins(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plugins")
    write_plugin(folder)
    sys.path.insert(0, str(folder))
    yield folder
    sys.path.remove(str(folder))


@pytest.fixture(scope="module")
def rows():
    rng = np.random.default_rng(4)
    W = rng.standard_normal((120, 3))
    y = W @ np.array([0.5, 1.0, 1.5]) + rng.uniform(-0.1, 0.1, 120)
    return W, y, np.full(120, 0.1), ident.Box(np.zeros(3), np.full(3, 2.0), ("a", "b", "c"))


@pytest.fixture(scope="module")
def hull_history(rows):
    from h4bench.scenarios.replay import box_history

    return box_history(prefix_run(*rows), methods=("hull",), points=3)["methods"]["hull"]


@pytest.mark.parametrize("name", sorted(FAILURES))
def test_the_box_history_fails_each_point_of_a_failing_plugin_by_name_and_goes_on(plugins, rows, hull_history, name):
    from h4bench.scenarios.replay import box_history

    method = f"trustcases:{name}"
    keep = [np.array(a, copy=True) for a in (*rows[:3], rows[3].lower)]
    h = box_history(prefix_run(*rows), methods=("hull", method), points=3, timeout=2.0 if name == "sleeper" else None)
    res = h["methods"][method]
    assert not res["ok"].any() and np.isnan(res["lower"]).all()
    for message in res["message"]:
        assert repr(method) in message and FAILURES[name] in message, message
    hull = h["methods"]["hull"]  # the other method: the same boxes as without the plugin
    assert hull["ok"].all() and np.array_equal(hull["lower"], hull_history["lower"])
    assert np.array_equal(hull["upper"], hull_history["upper"])
    assert all(np.array_equal(a, b) for a, b in zip((*rows[:3], rows[3].lower), keep))


def test_a_printing_plugin_in_the_box_history_writes_nothing_to_stdout(plugins, rows, capfd):
    from h4bench.scenarios.replay import box_history

    h = box_history(prefix_run(*rows), methods=("trustcases:talker",), points=3)
    assert h["methods"]["trustcases:talker"]["ok"].all()
    out, err = capfd.readouterr()
    assert "trustcases" not in out and err.count("trustcases: a print at call") == 3


def test_the_projections_sets_and_estimate_fail_a_plugin_by_name(plugins, rows):
    from h4bench.scenarios.feasible import reference_sets

    boxes, _, skipped = reference_sets(*rows, ["hull", "trustcases:hard_exit", "trustcases:change_prior"])
    assert set(boxes) == {"hull"}
    assert "os._exit(7)" in skipped["trustcases:hard_exit"] and "(prior.lower)" in skipped["trustcases:change_prior"]
    with pytest.raises(ident.EstimatorError, match=r"'trustcases:soft_exit'.*sys.exit\(5\)"):
        ident.estimate(*rows, method="trustcases:soft_exit")


def test_check_estimator_reports_a_plugin_that_exits_changes_its_inputs_or_sleeps(plugins):
    from h4bench.ident.estimators import check_estimator

    report = check_estimator("trustcases:hard_exit")
    assert not report.passed and all("os._exit(7)" in r.detail for r in report.failures if r.check == "box")
    changed = check_estimator("trustcases:change_bound")
    assert any(r.check == "inputs" and "bound (in its process)" in r.detail for r in changed.failures)
    slow = check_estimator("trustcases:sleeper", timeout=1.0)
    assert any("timeout" in r.detail for r in slow.failures)


# ---------------------------------------------------------------------------------------------- the commands
def h4(folder, *args, timeout=900):
    env = {**os.environ, "COLUMNS": "100"}
    return subprocess.run([sys.executable, "-m", "h4bench", *map(str, args)], cwd=folder, capture_output=True,
                          text=True, env=env, timeout=timeout)


def _hull_boxes(folder) -> dict:
    """Every hull entry (lower, upper) of every JSON file of a run folder, by (file, path): the oracle's shape."""
    found = {}

    def visit(obj, path, f):
        if isinstance(obj, dict):
            if isinstance(obj.get("hull"), dict) and {"lower", "upper"} <= set(obj["hull"]):
                found[(f, path)] = (obj["hull"]["lower"], obj["hull"]["upper"])
            for k, v in obj.items():
                visit(v, f"{path}/{k}", f)
        elif isinstance(obj, list):
            for i, v in enumerate(obj):
                visit(v, f"{path}[{i}]", f)

    for f in sorted(folder.rglob("*.json")):
        visit(json.loads(f.read_text()), "", str(f.relative_to(folder)))
    return found


FAILING = ("soft_exit", "hard_exit", "crasher", "add_y", "change_prior", "sleeper")


@pytest.mark.slow
@pytest.mark.parametrize("command", [("run", "paper", "--quick"), ("run", "enclosure", "--quick", "--workers", "2")],
                         ids=["paper", "enclosure-pool"])
def test_a_run_with_failing_plugins_is_written_and_the_hull_unchanged(plugins, tmp_path, command):
    """Every failing plugin of plugin_cases in one command, and a printing one: exit 4 naming them, the run folder
    written, stdout one JSON document, the hull's boxes those of the hull-only command."""
    methods = ",".join(["hull", *(f"trustcases:{n}" for n in FAILING), "trustcases:talker"])
    base = h4(plugins, *command, "--methods", "hull", "--method-timeout", "20", "--out", tmp_path / "base")
    res = h4(plugins, *command, "--methods", methods, "--method-timeout", "20", "--json", "--out", tmp_path / "p")
    assert base.returncode == 0, base.stderr
    assert res.returncode == 4, res.stderr
    result = json.loads(res.stdout)
    last = res.stderr.strip().splitlines()[-1]
    assert all(f"trustcases:{n}" in last for n in FAILING) and "talker" not in last, last
    assert (tmp_path / "p" / "result.json").exists() and result["methods"]["trustcases:talker"]
    hulls = _hull_boxes(tmp_path / "p")
    assert hulls and hulls == _hull_boxes(tmp_path / "base")


@pytest.mark.slow
def test_check_estimator_of_a_crashing_plugin_names_it(plugins):
    res = h4(plugins, "check-estimator", "trustcases:crasher", "--json")
    assert res.returncode == 1 and json.loads(res.stdout)["passed"] is False
    assert "'trustcases:crasher'" in res.stderr and "SIGSEGV" in res.stderr
    bad = h4(plugins, "check-estimator", "hull", "--method-timeout", "0")
    assert bad.returncode == 2 and "--method-timeout" in bad.stderr
