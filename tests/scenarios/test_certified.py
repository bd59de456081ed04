"""The certified path on a simulated run: the certificate holds, and it can fail (a spec that understates the
motion or the encoder error is caught by the truth); no allowance is read."""

import copy
import json
import dataclasses

import numpy as np
import pytest

from h4bench.ident.robots.h4_certified import certified_equation
from h4bench.scenarios.certificate import certify, check_certificate, processing_of, simulated_error_spec
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.registry import load_spec


@pytest.fixture(scope="module")
def run_and_spec():
    spec = load_spec("certified", quick=True)
    return run_experiment(spec, 0, estimate=False), spec


def _short(run_, spec, n=600, **change):
    """The certificate on the first n samples with ErrorSpec fields changed."""
    es = simulated_error_spec(spec, run_.reference, run_.dataset.dt, run_.noise_bound)
    es = dataclasses.replace(es, **change)
    proc = dataclasses.replace(processing_of(spec), curvature_every=20)
    truth = copy.copy(run_.truth)
    for f in ("q", "qd", "qdd", "tau_applied"):
        setattr(truth, f, getattr(run_.truth, f)[:n])
    ceq = certified_equation(run_.geometry, run_.dataset.q[:n], run_.dataset.tau[:n], es, proc)
    return check_certificate(run_.geometry, ceq, truth, run_.dataset.tau[:n], es, proc, run_.theta_true)


def test_certified_box_encloses_and_the_certificate_holds_without_an_allowance(run_and_spec):
    run_, spec = run_and_spec
    spec = copy.deepcopy(spec)
    del spec["bound"]  # the certified path must not read the tuned allowance
    run_.bound_raw = float("nan")
    out = certify(run_, spec)
    cert, entry = out["certificate"], out["certified_entry"]
    assert cert["rows"] > 0 and cert["violations"] == 0 and cert["min_margin"] >= 0
    assert entry["status"] == "ok" and entry["all_enclosed"]
    assert "allowance" not in out["error_model"] and cert["motion_bounds"]["held"]
    assert cert["terms"]["torque"] == pytest.approx(run_.noise_bound, rel=1e-12)  # kernel of unit integral
    # every term proven: the nacelle columns' boxes all verified, nothing rests on sampled bounds
    eq = cert["equation"]
    assert eq["not_proven"] == [] and eq["encoder_boxes_proven"] == eq["motion_boxes_proven"] == eq["steps"]
    # every key the certified path adds is documented in docs/results.md (section `certified`)
    from tests.test_docs import documented

    doc = documented("`certified`")
    keys = {f"certificate.{k}" for k in cert} | {"error_model", "width_vs_tuned", "width_vs_tuned_geomean"}
    assert keys <= set(doc), sorted(keys - set(doc))


def test_certificate_catches_an_understated_spec(run_and_spec):
    run_, spec = run_and_spec
    assert _short(run_, spec)["violations"] == 0
    # qdd_max far below the truth: the motion bound is reported broken, and the sign/truncation radii fail
    slow = _short(run_, spec, qdd_max=np.full(4, 1.0))
    assert not slow["motion_bounds"]["held"] and slow["checks"]["motion"]["violations"] > 0
    # an encoder 500 x finer than the simulated one: the measurement radii fail against the truth
    fine = _short(run_, spec, position_resolution=np.full(4, 2 * np.pi / 20000 / 500))
    assert fine["checks"]["measurement"]["violations"] > 0
    # a torque error below the injected one
    weak = _short(run_, spec, torque_error=np.full(4, 0.1))
    assert weak["checks"]["torque"]["violations"] > 0


@pytest.mark.slow
def test_enclosure_campaign_with_the_derived_error_model(tmp_path):
    """`h4bench run enclosure --quick --error-model derived`: 0 certificate violations and 0 misses of the
    certified box over the campaign's runs (about 2 min on 2 cores)."""
    from h4bench.scenarios.runner import run_scenario

    result = run_scenario("enclosure", quick=True, out=tmp_path / "enc", workers=2, error_model="derived")
    cert = result["certificate"]
    assert cert["runs"] == result["runs"] == 4 and cert["rows"] > 0
    assert cert["violations"] == 0 and cert["min_margin"] >= 0
    assert result["methods"]["certified"]["misses"] == 0
    assert result["campaign"]["timings"]["stages"]["certified"]["total"] > 0  # its own stage, not 'other'


def test_derived_error_model_is_refused_where_it_is_not_built(tmp_path):
    from h4bench.scenarios.runner import run_scenario
    from h4bench.scenarios.spec import ScenarioError

    with pytest.raises(ScenarioError, match="--error-model derived is available for the kinds"):
        run_scenario("structure", quick=True, out=tmp_path / "s", error_model="derived")
    with pytest.raises(ScenarioError, match="error_model must be 'tuned' or 'derived'"):
        run_scenario("paper", quick=True, out=tmp_path / "p", error_model="guessed")


def test_identify_with_a_spec_gives_the_certified_box(run_and_spec, tmp_path):
    """`h4bench identify LOG --spec SPEC.toml` on a simulated log: the certified box encloses the simulator's
    truth (read here only to check), result.json carries the specification; --bound with --spec is refused."""
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    run_, spec = run_and_spec
    ds, n = run_.dataset, 1500
    log = tmp_path / "log.csv"
    np.savetxt(log, np.column_stack([ds.t[:n], ds.q[:n], ds.tau[:n]]), delimiter=",", comments="", fmt="%.17g",
               header="t,q1,q2,q3,q4,tau1,tau2,tau3,tau4")
    es = simulated_error_spec(spec, run_.reference, ds.dt, run_.noise_bound)
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        "[error_model]\nsample_period = 0.001\ncounts_per_turn = 20000\n"
        f"torque_error = {run_.noise_bound!r}\nqd_max = {es.qd_max.tolist()}\nqdd_max = {es.qdd_max.tolist()}\n"
        "[error_model.sources]\ntorque_error = 'the simulator: the injected error bound'\n"
        "[certified]\nkernel_steps = 100\ncurvature_every = 20\n")
    res = CliRunner().invoke(app, ["identify", str(log), "--spec", str(spec_file), "--out", str(tmp_path / "o"),
                                   "--json"])
    assert res.exit_code == 0, res.output
    result = json.loads(res.stdout)
    m = result["methods"]["certified"]
    assert m["status"] == "ok" and result["bound"] is None
    assert np.all(np.asarray(m["lower"]) <= run_.theta_true) and np.all(run_.theta_true <= np.asarray(m["upper"]))
    budget = {k: m["info"][k] for k in ("lp_limit_hits", "lp_retries", "lp_fallbacks", "lp_fallback_parameters")}
    assert budget == {"lp_limit_hits": 0, "lp_retries": 0, "lp_fallbacks": 0, "lp_fallback_parameters": []}
    assert result["error_model"]["sources"]["torque_error"].startswith("the simulator")
    assert json.loads((tmp_path / "o" / "result.json").read_text())["rows"] == result["rows"] > 0
    bad = CliRunner().invoke(app, ["identify", str(log), "--spec", str(spec_file), "--bound", "1.5",
                                   "--out", str(tmp_path / "p")])
    assert bad.exit_code == 2 and "--bound does not apply with --spec" in bad.output


@pytest.mark.slow
def test_run_certified_quick_json(tmp_path):
    """`h4bench run certified --quick --json`: one JSON document with the certificate (rows > 0, 0 violations,
    margin >= 0, each term's radius), the error model, the certified method enclosing the truth beside the tuned
    hull, and the width ratio."""
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    res = CliRunner().invoke(app, ["run", "certified", "--quick", "--json", "--out", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    r = json.loads(res.stdout)
    c = r["certificate"]
    assert c["rows"] > 0 and c["violations"] == 0 and c["min_margin"] >= 0
    assert set(c["terms"]) == {"torque", "model", "rounding", "measurement", "second_order", "truncation", "sign"}
    assert r["error_model"]["position_resolution"] == [2 * np.pi / 20000] * 4
    assert r["methods"]["certified"]["all_enclosed"] and r["methods"]["hull"]["status"] == "ok"
    assert 0 < r["width_vs_tuned_geomean"] <= 1.5


def test_sample_instant_torques_add_the_rate_term_or_state_the_assumption(run_and_spec):
    """torque_timing = "sample": the rows' torque side integrates the samples' interpolation, the model term
    grows by torque_rate h / 2 (times the weights' sum, 1), and without a torque_rate the assumption is listed."""
    run_, spec = run_and_spec
    es = simulated_error_spec(spec, run_.reference, run_.dataset.dt, run_.noise_bound)
    q, tau, n = run_.dataset.q, run_.dataset.tau, 800
    hold = certified_equation(run_.geometry, q[:n], tau[:n], es)
    rate = np.array([300.0, 200.0, 100.0, 50.0])
    sampled = certified_equation(run_.geometry, q[:n], tau[:n],
                                 dataclasses.replace(es, torque_timing="sample", torque_rate=rate))
    h = es.sample_period
    np.testing.assert_allclose(sampled.terms["model"] - hold.terms["model"], np.tile(rate * h / 2, hold.y.size // 4),
                               rtol=1e-9)
    assert not np.allclose(sampled.y, hold.y)
    assert not any("torque between samples" in s for s in sampled.info["not_proven"])
    stated = certified_equation(run_.geometry, q[:n], tau[:n], dataclasses.replace(es, torque_timing="sample"))
    assert any("torque between samples" in s for s in stated.info["not_proven"])
