"""A plugin is untrusted code: nothing it does may corrupt the reference, the output or the campaign.

Each test runs the real command line (``python -m h4bench ...`` in a subprocess, the plugins of
tests/scenarios/plugin_cases.py written into the test's folder) and reproduces one of the defects a user met:
a plugin changing its inputs in place corrupted the exact hull; ``sys.exit``/``os._exit`` ended the command with
exit 0 and no output; ``--json`` was not one JSON document; an object in ``Box.info`` crashed the command; a
failed method exited 0; entry-point name collisions went unnoticed; names broke rich markup; the exit-3 message
gave a processed-row bound in ``--bound``'s units; no time limit. The oracle of a plugin's damage is the same
command without the plugin.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.scenarios.plugin_cases import EXIT_AT_IMPORT, fake_distribution, write_plugin

HEADER = "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4"


def strict_json(text: str):
    def refuse(constant):
        raise ValueError(f"not JSON: bare {constant}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def here(tmp_path_factory):
    """A user's folder: the log of a quick paper experiment (seed 5) and the plugin module trustcases.py."""
    from h4bench.scenarios.experiment import run_experiment
    from h4bench.scenarios.spec import load_spec

    spec = load_spec("paper", quick=True)
    spec["replay"]["enabled"] = False
    ds = run_experiment(spec, seed=5, estimate=False).dataset
    folder = tmp_path_factory.mktemp("user")
    np.savetxt(folder / "log.csv", np.column_stack([ds.t, ds.q, ds.tau]), delimiter=",", header=HEADER,
               comments="", fmt="%.17g")
    write_plugin(folder)
    return folder


def h4(folder, *args, env=None, timeout=300):
    """``python -m h4bench ARGS`` in ``folder`` (COLUMNS=100); returns the CompletedProcess."""
    env = {**os.environ, "COLUMNS": "100", **(env or {})}
    return subprocess.run([sys.executable, "-m", "h4bench", *map(str, args)], cwd=folder, capture_output=True,
                          text=True, env=env, timeout=timeout)


def identify(folder, method, *more, bound="1.5", out="out", json_=True):
    return h4(folder, "identify", "log.csv", "--bound", bound, "--method", method, "--out", out,
              *(("--json",) if json_ else ()), *more)


@pytest.fixture(scope="module")
def baseline(here):
    """The oracle: hull and cgsp without any plugin."""
    res = identify(here, "hull,cgsp", out="baseline")
    assert res.returncode == 0, res.stderr
    return strict_json(res.stdout)


@pytest.fixture(scope="module")
def with_plugins(here):
    """Cases 1, 2, 4, 5 at once: the misbehaving plugins first, then hull and cgsp, in one command."""
    methods = [f"trustcases:{f}" for f in ("add_y", "scale_w", "hard_exit", "soft_exit", "talker", "weird_info")]
    res = identify(here, ",".join([*methods, "hull", "cgsp"]), out="plugins")
    return res, strict_json(res.stdout)  # case 4: stdout is one strict JSON document


def test_a_plugin_that_changes_its_inputs_corrupts_nothing(with_plugins, baseline):
    res, result = with_plugins
    m = result["methods"]
    for name, what in (("trustcases:add_y", "(y)"), ("trustcases:scale_w", "(W)")):
        assert m[name]["status"] == "failed" and f"changed its inputs in place {what}" in m[name]["message"], m[name]
    for name in ("hull", "cgsp"):  # bit for bit the boxes of the command without the plugins
        assert m[name]["lower"] == baseline["methods"][name]["lower"], name
        assert m[name]["upper"] == baseline["methods"][name]["upper"], name
    assert result["consistent"] is True and result["unsound"] == []


def test_exits_are_the_plugins_failure_and_the_run_is_written(with_plugins, here):
    res, result = with_plugins
    m = result["methods"]
    assert "os._exit(7)" in m["trustcases:hard_exit"]["message"]
    assert "sys.exit(5)" in m["trustcases:soft_exit"]["message"]
    assert res.returncode == 4 and "trustcases:hard_exit" in res.stderr.splitlines()[-1]
    assert strict_json((here / "plugins" / "result.json").read_text())["methods"]["hull"]["status"] == "ok"


def test_json_stays_one_document_when_a_plugin_prints(with_plugins):
    res, result = with_plugins
    assert "trustcases: a print at call" in res.stderr and "trustcases: a write to fd 1" in res.stderr
    assert "trustcases: a print at import" in res.stderr and "trustcases" not in res.stdout.split('"methods"')[0]
    assert result["methods"]["trustcases:talker"]["status"] == "ok"


def test_an_object_in_box_info_is_written_as_its_repr(with_plugins, here):
    _, result = with_plugins
    info = result["methods"]["trustcases:weird_info"]["info"]
    assert result["methods"]["trustcases:weird_info"]["status"] == "ok"
    assert "Thing object" in info["obj_repr"] and "lambda" in info["fn_repr"] and info["ok"] == [1, 2]
    assert "Thing object" in info["objs_repr"]  # a list holding an object: before, "not JSON serialisable"


def test_a_failed_only_method_exits_4_and_claims_no_verdict(here):
    res = identify(here, "trustcases:raiser", json_=False, out="raiser")
    assert res.returncode == 4, res.stderr
    assert "narrower-than-hull check: no guaranteed box to check" in res.stdout
    entry = strict_json((here / "raiser" / "result.json").read_text())["methods"]["trustcases:raiser"]
    assert entry["status"] == "failed" and entry["unsound"] is None and "plugin bug" in entry["message"]


@pytest.mark.parametrize("method", ["hull:", ":x", "nosuchmod_h4:f", "trustcases:nope"])
def test_a_method_that_cannot_resolve_is_a_bad_option_before_any_work(here, method):
    res = identify(here, method, out=f"bad-{abs(hash(method))}")
    assert res.returncode == 2 and res.stdout == "", res
    last = res.stderr.strip().splitlines()[-1]  # before it: what the plugin printed at import (stderr)
    assert last.startswith("error: --method") and repr(method.split(",")[-1]) in last
    assert not (here / f"bad-{abs(hash(method))}").exists()


def test_a_per_method_time_limit(here):
    t0 = time.monotonic()
    res = identify(here, "trustcases:sleeper,hull", "--method-timeout", "2", out="slow")
    assert res.returncode == 4, res.stderr
    assert time.monotonic() - t0 < 60  # the plugin sleeps 120 s
    m = strict_json(res.stdout)["methods"]
    assert "timeout" in m["trustcases:sleeper"]["message"] and m["hull"]["status"] == "ok"
    bad = identify(here, "hull", "--method-timeout", "-1", out="slow2")
    assert bad.returncode == 2 and "--method-timeout" in bad.stderr


# ------------------------------------------------------------------------------------------- entry points
@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """Installed plugins: one that exits at import, a name given by two distributions, unusable names, and a
    name with rich markup."""
    root = tmp_path_factory.mktemp("site")
    ok = "from h4bench import ident\n\ndef estimate(W, y, bound, prior):\n    return ident.estimate(W, y, bound, prior)\n"
    fake_distribution(root, "trustone", {"dup": "trustep:estimate", "exiter": "trustexit:estimate",
                                         "a,b": "trustep:estimate", "x:y": "trustep:estimate",
                                         "x[/b]": "trustep:estimate"},
                      {"trustep": ok, "trustexit": EXIT_AT_IMPORT})
    fake_distribution(root, "trusttwo", {"dup": "trustep:estimate"})
    return {"PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}


def test_estimators_loads_each_plugin_in_isolation_and_names_collisions(here, site):
    res = h4(here, "estimators", "--json", env=site)
    assert res.returncode == 0, res.stderr
    found = strict_json(res.stdout)
    broken = {b["name"]: b["error"] for b in found["broken"]}
    assert "os._exit(3)" in broken["exiter"]
    assert "2 entry points" in broken["dup"] and "trustone" in broken["dup"] and "trusttwo" in broken["dup"]
    assert "not a usable method name" in broken["a,b"] and "not a usable method name" in broken["x:y"]
    usable = {e["name"] for e in found["estimators"]}
    assert {"hull", "x[/b]"} <= usable and not {"dup", "a,b", "x:y", "exiter"} & usable
    text = h4(here, "estimators", env=site)
    assert text.returncode == 0 and "exiter" in text.stdout and "BROKEN" in text.stdout


def test_a_name_with_rich_markup_is_printed_as_it_is(here, site):
    """Also: the installed entry point that exits at import (``exiter``) is never loaded when not asked for."""
    res = h4(here, "identify", "log.csv", "--bound", "1.5", "--method", "x[/b],hull", "--out", "markup", env=site)
    assert res.returncode == 0, res.stderr
    assert "x[/b] lower" in res.stdout and "MarkupError" not in res.stderr


# ---------------------------------------------------------------------------------------------- exit 3
@pytest.mark.slow
def test_the_exit_3_bound_is_in_the_units_of_bound_and_is_consistent(here):
    res = identify(here, "hull", bound="0.9", out="low")
    assert res.returncode == 3
    sc = strict_json(res.stdout)["inconsistency"]["smallest_consistent"]
    last = res.stderr.strip().splitlines()[-1]
    assert f"in --bound's units (raw rows) is {sc['raw_max']:.6g} N m" in last and f"{sc['processed']:.6g}" in last
    # oracle: the command itself, at the printed raw bound (consistent) and 0.1 % below (inconsistent)
    assert identify(here, "hull", bound=repr(sc["raw_max"]), out="at").returncode == 0
    assert identify(here, "hull", bound=repr(sc["raw_max"] * 0.999), out="below").returncode == 3
    # the processed figure is not in --bound's units: it is the raw one times about the filter's gain
    assert sc["processed"] > 1.03 * sc["raw_max"] and abs(sc["processed"] / sc["raw_max"] - sc["gain"]) < 0.01


@pytest.mark.slow
def test_the_exit_3_bounds_per_joint_are_consistent(here):
    res = identify(here, "hull", bound="0.9,0.5,0.9,0.9", out="low4")
    assert res.returncode == 3
    sc = strict_json(res.stdout)["inconsistency"]["smallest_consistent"]
    per = ",".join(repr(v) for v in sc["raw"])
    assert "per joint" in res.stderr and f"--bound {','.join(f'{v:.6g}' for v in sc['raw'])}" in res.stderr
    assert identify(here, "hull", bound=per, out="at4").returncode == 0


def test_asking_a_plugin_for_its_context_does_not_import_it_here(tmp_path, monkeypatch):
    """The experiment asks each method whether it takes the instruments; for a plugin the answer comes from a child
    process, so its import code (here: a print) never runs in the campaign worker (whose stdout is the --json
    document's)."""
    from h4bench.scenarios import experiment
    from tests.scenarios.plugin_cases import write_plugin

    write_plugin(tmp_path, name="ctxprobe")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert experiment._takes("ctxprobe:shrunk", "instruments") is False
    assert experiment._takes("iv", "instruments") is True
    assert experiment._takes("nosuchmodule_xyz:f", "instruments") is False
    assert "ctxprobe" not in sys.modules
