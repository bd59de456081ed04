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
from test_serial_certified import DT, _log  # noqa: E402

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
    toml.write_text(f"""[error_model]
sample_period = {DT}
counts_per_turn = {2**17}
torque_timing = "sample"
torque_error = 0.5
torque_rate = {[float(v) for v in spec.torque_rate]}
qd_max = {[float(v) for v in spec.qd_max]}
qdd_max = {[float(v) for v in spec.qdd_max]}

[error_model.sources]
torque_error = "the synthetic log's square-wave amplitude"

[certified]
kernel_steps = 80
stride = 40
refine = 1
""")
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
