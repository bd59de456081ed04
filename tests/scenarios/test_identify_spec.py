"""``h4bench identify --urdf ... --spec FILE`` and the TX40's derived error model (``run tx40 --error-model derived``).

Oracles: a synthetic TX40 log (tests/ident/test_serial_certified.py: analytic motion, pinocchio torques at a known
theta, a square-wave torque error of the stated amplitude) written as CSV: the certified box must hold the true
base parameters; the motor-to-joint position error against brute force over the corners of the motor-side error
box; ``json.loads`` of stdout; exit code 2 with the option named for bad input.
"""

from __future__ import annotations

import itertools
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from h4bench.ident.robots import tx40
from h4bench.scenarios.cli import app

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "ident"))
from test_serial_certified import DT, _log, spec_toml  # noqa: E402

URDF = str(tx40.urdf_path())


@pytest.fixture(scope="module")
def synthetic_csv(tmp_path_factory):
    robot = tx40.robot()
    traj, theta, q, tau, spec = _log(robot, T=1.2)
    d = tmp_path_factory.mktemp("spec")
    csv = d / "log.csv"
    with open(csv, "w") as f:
        f.write("t," + ",".join(f"q{i + 1}" for i in range(6)) + "," + ",".join(f"tau{i + 1}" for i in range(6)) + "\n")
        for k in range(q.shape[0]):
            f.write(",".join(repr(float(x)) for x in [k * DT, *q[k], *tau[k]]) + "\n")
    toml = d / "spec.toml"
    toml.write_text(spec_toml(spec, kernel_steps=80, stride=40, refine=1))
    return csv, toml, robot.base(200, 0).from_standard(theta), d


def test_identify_spec_encloses_the_truth(synthetic_csv):
    csv, toml, theta, d = synthetic_csv
    res = CliRunner().invoke(app, ["identify", str(csv), "--urdf", URDF, "--coupled-wrist", "5,6", "--spec",
                                   str(toml), "--out", str(d / "out"), "--json"])
    assert res.exit_code == 0, res.output
    r = json.loads(res.stdout)
    m = r["methods"]["certified"]
    assert m["status"] == "ok" and r["consistent"] is True
    assert all(lo <= t <= hi for lo, t, hi in zip(m["lower"], theta, m["upper"]))
    assert m["narrowed_parameters"] > 0
    budget = {k: m["info"][k] for k in ("lp_limit_hits", "lp_retries", "lp_fallbacks", "lp_fallback_parameters")}
    assert budget == {"lp_limit_hits": 0, "lp_retries": 0, "lp_fallbacks": 0, "lp_fallback_parameters": []}
    assert m["info"]["lp_solves"] > 0
    assert r["error_model"]["file"] == str(toml) and r["error_model"]["torque_error"] == [0.5] * 6
    assert r["error_model"]["sources"]["torque_error"].startswith("the synthetic")
    assert r["certified"]["spec_check"]["contradicted"] == [] and r["certified"]["rows"] > 0
    assert json.loads((d / "out" / "result.json").read_text())["methods"]["certified"]["lower"] == m["lower"]
    # what rests on statements is listed with its source; the row radius is named by its parts
    assert r["error_model"]["sources"]["regressor_float"].startswith("stated, not proven")
    rr = r["certified"]["row_radius"]
    assert rr["torque_side_max"] <= rr["total_max"] and rr["torque_side_median"] <= rr["total_median"]
    # the parameters left at the prior are named with the term that dominates and what would help
    diag = r["certified"]["prior_diagnosis"]
    at_prior = [n for n, w in zip(r["parameters"], m["relative_width_to_prior"]) if w >= 0.99]
    assert diag["parameters"] == at_prior and diag["dominant"] in r["certified"]["terms"]
    if at_prior:
        assert diag["message"].startswith(f"{len(at_prior)} of {len(theta)} parameters stay at the prior")
        assert f"dominated by the {diag['dominant']} term" in diag["message"] and "What would help" in diag["message"]


def test_identify_spec_reports_its_progress(synthetic_csv):
    """The equation's windows and the hull's rounds reach the progress callable (the command line's bar)."""
    from h4bench.scenarios.identify_serial_certified import identify_urdf_spec

    csv, toml, theta, d = synthetic_csv
    seen = []
    r = identify_urdf_spec(csv, URDF, toml, coupled_wrist=(4, 5), out=d / "progress",
                           progress=lambda stage, done, total: seen.append((stage, done, total)))
    assert r["methods"]["certified"]["status"] == "ok"
    eq = [(dn, t) for s, dn, t in seen if s == "certified equation"]
    hull = [(dn, t) for s, dn, t in seen if s.startswith("certified hull")]
    assert eq and eq[-1][0] == eq[-1][1] and all(0 < dn <= t for dn, t in eq)
    assert [dn for dn, _ in hull] == list(range(1, len(hull) + 1))
    assert len(hull) == r["methods"]["certified"]["info"]["refinements"] + 1 and hull[0][1] == 2  # refine = 1


@pytest.mark.parametrize("extra, spec_text, word", [
    (["--bound", "1"], None, "--bound does not apply with --spec"),
    (["--method", "cgsp"], None, "--method does not apply"),
    ([], "[error_model]\nsample_period = 0.002\ncounts_per_turn = 1000\ntorque_error = 1\nqd_max = 1\nqdd_max = 1\n",
     "sample_period"),
    ([], "[error_model]\nsample_period = 0.001\ntorque_error = 1\nqd_max = 1\nqdd_max = 1\n", "position_resolution"),
    ([], "[error_model]\nsample_period = 0.001\ncounts_per_turn = 1000\ntorque_error = 1\nqd_max = 1\n"
         "qdd_max = 1\n[certified]\ncurvature_every = 10\n", "[certified]"),
    ([], "[error_model]\nsample_period = 0.001\ncounts_per_turn = 1000\ntorque_error = 1\nqd_max = 1\n"
         "qdd_max = 1\n[certified]\nkernel_steps = 81\n", "kernel_steps"),
])
def test_identify_spec_errors_name_the_option_and_file(synthetic_csv, tmp_path, extra, spec_text, word):
    csv, toml, _, _ = synthetic_csv
    if spec_text is not None:
        toml = tmp_path / "bad.toml"
        toml.write_text(spec_text)
    res = CliRunner().invoke(app, ["identify", str(csv), "--urdf", URDF, "--spec", str(toml),
                                   "--out", str(tmp_path / "o"), *extra])
    assert res.exit_code == 2
    assert word in res.output and "--" in res.output
    if spec_text is not None:
        assert str(toml) in res.output


def test_bound_or_spec_is_required(synthetic_csv):
    csv, _, _, _ = synthetic_csv
    res = CliRunner().invoke(app, ["identify", str(csv), "--urdf", URDF])
    assert res.exit_code == 2 and "--bound is required" in res.output


def test_tx40_joint_position_error_against_brute_force():
    """The motor angles' error box mapped through q = R^-1 q_motor: |R^-1| e is the exact half-width of its
    image (a linear map of a box), checked against the box's corners."""
    from h4bench.scenarios import tx40_certified as tc

    spec = tc.error_spec(tc.DEFAULTS["error_model"])
    log = tx40.load_log()
    q_motor = log.q_motor[:50]
    e = tc.joint_position_error(spec, q_motor)
    e_motor = spec.position_error(q_motor)
    Rinv = np.linalg.inv(tx40.ratio_matrix())
    for k in (0, 17, 49):
        corners = np.array(list(itertools.product([-1.0, 1.0], repeat=6))) * e_motor[k]
        brute = np.max(np.abs(corners @ Rinv.T), axis=0)
        np.testing.assert_allclose(e[k], brute, rtol=1e-12)
    assert set(spec.sources) >= {"sample_period", "significant_digits", "torque_error", "qd_max", "qdd_max"}


@pytest.mark.slow
def test_run_tx40_derived_quick(tmp_path):
    res = CliRunner().invoke(app, ["run", "tx40", "--quick", "--error-model", "derived", "--json", "--out",
                                   str(tmp_path / "tx40")])
    assert res.exit_code == 0, res.output
    r = json.loads(res.stdout)
    m = r["methods"]["certified"]
    assert m["status"] == "ok" and m["rigorous"] is True and m["heldout_coverage"] == 1.0
    assert r["error_model"]["significant_digits"] == 5 and r["error_model"]["sources"]["torque_error"]
    c = r["certified"]
    assert set(c["torque_error_sweep"]) == {"0.5", "1", "2"} and c["dominant"] in c["terms"]
    assert c["spec_check"]["contradicted"] == []
    assert "## Certified box" in (tmp_path / "tx40" / "report.md").read_text()
    doc = (Path(__file__).resolve().parents[2] / "docs" / "results.md").read_text()
    undocumented = [k for k in [*c, *m] if f".{k}`" not in doc and f"`{k}`" not in doc]
    assert not undocumented, f"certified keys not in docs/results.md: {undocumented}"


def _spec_with(toml, tmp_path, **entries):
    """The synthetic log's spec file with [error_model] entries replaced."""
    text = toml.read_text()
    for key, value in entries.items():
        lines = [line for line in text.splitlines() if not line.startswith(f"{key} =")]
        i = lines.index("[error_model]") + 1
        lines.insert(i, f"{key} = {value}")
        text = "\n".join(lines) + "\n"
    path = tmp_path / "spec.toml"
    path.write_text(text)
    return path


def _true_peaks():
    """The synthetic log's true max |qd|, |qdd| per joint (the analytic motion on a 100x finer grid)."""
    from test_serial_certified import _trajectory

    traj, _, _ = _trajectory(0)
    _, qd, qdd = traj(np.linspace(0, 1.2, 120001))
    return np.abs(qd).max(axis=0), np.abs(qdd).max(axis=0)


@pytest.mark.parametrize("entry", ["qdd_max", "qd_max"])
def test_an_understated_motion_bound_exits_3_naming_it(synthetic_csv, tmp_path, entry):
    """qdd_max (or qd_max) stated at 0.7 x the true peak: refused with exit 3 on every joint, the message naming
    --spec, the file, the entry, the joint, the stated value and the proven bound; result.json written with
    status spec_contradicted and no box (the check once used spans of 3 steps only and proved 0 rad/s^2)."""
    csv, toml, _, _ = synthetic_csv
    qd_true, qdd_true = _true_peaks()
    stated = 0.7 * (qdd_true if entry == "qdd_max" else qd_true)
    spec = _spec_with(toml, tmp_path, **{entry: [float(v) for v in stated]})
    res = CliRunner().invoke(app, ["identify", str(csv), "--urdf", URDF, "--coupled-wrist", "5,6", "--spec",
                                   str(spec), "--out", str(tmp_path / "o")])
    assert res.exit_code == 3, res.output
    unit = "rad/s^2" if entry == "qdd_max" else "rad/s"
    for j in range(6):
        assert (f"--spec {spec}: {entry} of joint {j + 1} = {stated[j]:.6g} {unit} is contradicted by the data: "
                f"the positions prove max |{entry[:-4]}| >= ") in res.output
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    m = r["methods"]["certified"]
    assert m["status"] == "spec_contradicted" and "lower" not in m and r["consistent"] is False
    check = r["certified"]["spec_check"]
    lower = np.asarray(check["qdd_lower" if entry == "qdd_max" else "qd_lower"])
    truth = qdd_true if entry == "qdd_max" else qd_true
    assert np.all(lower <= truth) and np.all(lower >= 0.9 * truth)  # every joint proven, none overstated


@pytest.mark.parametrize("table, key", [("kernel_shape = 'box'", "kernel_shape"), ("stride = 0", "stride"),
                                        ("refine = -1", "refine"), ("kernel_steps = 2", "kernel_steps")])
def test_certified_table_errors_name_spec_file_and_key(synthetic_csv, tmp_path, table, key):
    csv, toml, _, _ = synthetic_csv
    text = toml.read_text().replace("[certified]\n", f"[certified]\n{table}\n")
    text = "\n".join(line for line in text.splitlines() if not (line.startswith(f"{key} =") and line != table))
    bad = tmp_path / "bad.toml"
    bad.write_text(text + "\n")
    res = CliRunner().invoke(app, ["identify", str(csv), "--urdf", URDF, "--spec", str(bad), "--out",
                                   str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    assert f"--spec {bad}" in " ".join(res.output.split()) and f"[certified].{key}" in res.output


def test_too_few_rows_for_the_parameters_are_refused(synthetic_csv, tmp_path):
    csv, toml, _, _ = synthetic_csv
    spec = tmp_path / "spec.toml"
    spec.write_text(toml.read_text().replace("stride = 40", "stride = 5000"))
    res = CliRunner().invoke(app, ["identify", str(csv), "--urdf", URDF, "--coupled-wrist", "5,6", "--spec",
                                   str(spec), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "must exceed the" in res.output and "base parameters" in res.output
