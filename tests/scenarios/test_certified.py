"""The certified path on a simulated run: the certificate holds, and it can fail (a spec that understates the
motion or the encoder error is caught by the truth); no allowance is read."""

import copy
import json
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from h4bench.ident.robots.h4_certified import certified_equation
from h4bench.scenarios.certificate import certify, check_certificate, processing_of, simulated_error_spec
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.registry import load_spec
from h4bench.sim.friction import friction_band


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
    # the scenario's encoder (20000 counts per turn) against its stated qdd_max: every step's encoder bounds are its
    # motion tube's ("auto", ident.robots.h4_certified.encoder_from_tube), and the certificate holds on them
    assert eq["encoder_jets"] == "auto" and eq["encoder_boxes_from_tube"] == eq["steps"]
    # every key the certified path adds is documented in docs/results.md (section `certified`)
    from tests.test_docs import documented

    doc = documented("`certified`")
    keys = {f"certificate.{k}" for k in cert} | {"error_model", "width_vs_tuned", "width_vs_tuned_geomean"}
    assert keys <= set(doc), sorted(keys - set(doc))


def test_certificate_catches_an_understated_spec(run_and_spec):
    run_, spec = run_and_spec
    assert _short(run_, spec)["violations"] == 0
    # qdd_max far below the truth (and the friction band stated from it): the motion bound is reported broken, and
    # the sign/truncation radii fail (on the first 1.5 s: the first 0.6 s move slowly, their radii hold at 1 rad/s^2
    # once the band covers the soft friction near rest)
    slow = _short(run_, spec, n=1500, qdd_max=np.full(4, 1.0),
                  friction_band=friction_band(run_.model, 1.0, spec["prior"]["upper"]))
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
    # --only re-runs one index with its certified box: the campaign's own run, the same box and certificate
    again = run_scenario("enclosure", quick=True, out=tmp_path / "enc", workers=2, error_model="derived", only=1)
    saved = json.loads((tmp_path / "enc" / "runs" / "0001.json").read_text())
    assert again["methods"]["certified"]["lower"] == saved["methods"]["certified"]["lower"]
    assert again["methods"]["certified"]["upper"] == saved["methods"]["certified"]["upper"]
    assert again["certificate"]["status"] == saved["certificate"]["status"]


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


def _h4_log(run_, tmp_path, n=None):
    ds = run_.dataset
    n = n or len(ds)
    log = tmp_path / "log.csv"
    np.savetxt(log, np.column_stack([ds.t[:n], ds.q[:n], ds.tau[:n]]), delimiter=",", comments="", fmt="%.17g",
               header="t,q1,q2,q3,q4,tau1,tau2,tau3,tau4")
    return log


def _h4_spec(tmp_path, run_, spec, counts=20000, certified="kernel_steps = 100\ncurvature_every = 20", **stated):
    es = simulated_error_spec(spec, run_.reference, run_.dataset.dt, run_.noise_bound)
    qd, qdd = stated.get("qd_max", es.qd_max), stated.get("qdd_max", es.qdd_max)
    path = tmp_path / "spec.toml"
    path.write_text(f"[error_model]\nsample_period = 0.001\ncounts_per_turn = {counts}\n"
                    f"torque_error = {run_.noise_bound!r}\nqd_max = {list(map(float, qd))}\n"
                    f"qdd_max = {list(map(float, qdd))}\n[certified]\n{certified}\n")
    return path


@pytest.mark.parametrize("entry, factor", [("qdd_max", None), ("qdd_max", 0.7), ("qd_max", 0.7)])
def test_identify_h4_refuses_an_understated_motion_bound(run_and_spec, tmp_path, entry, factor):
    """qdd_max = 10 rad/s^2 (the truth reaches 400-660) or 0.7 x the true peak: exit 3, every joint named with
    the stated value and the proven bound (which never exceeds the truth); result.json without a box (the H4's
    identify --spec once exited 0 here, status ok)."""
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    run_, spec = run_and_spec
    true = np.abs(run_.truth.qdd if entry == "qdd_max" else run_.truth.qd).max(axis=0)  # read only to check
    stated = np.full(4, 10.0) if factor is None else factor * true
    spec_file = _h4_spec(tmp_path, run_, spec, **{entry: stated})
    res = CliRunner().invoke(app, ["identify", str(_h4_log(run_, tmp_path)), "--spec", str(spec_file), "--out",
                                   str(tmp_path / "o")])
    assert res.exit_code == 3, res.output
    unit = "rad/s^2" if entry == "qdd_max" else "rad/s"
    out = " ".join(res.output.split())
    for j in range(4):
        assert (f"--spec {spec_file}: {entry} of joint {j + 1} = {stated[j]:.6g} {unit} is contradicted by the data: "
                f"the positions prove max |{entry[:-4]}| >= ") in out
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    assert r["methods"]["certified"]["status"] == "spec_contradicted" and "lower" not in r["methods"]["certified"]
    assert r["consistent"] is False
    proven = np.asarray(r["certified"]["spec_check"][entry[:-4] + "_lower"])
    assert np.all(proven <= true) and np.all(proven > 0.85 * true)


@pytest.mark.parametrize("table, words", [
    ("kernel_steps = 7", ["kernel_steps must be >= 40", "leave every parameter at its prior"]),
    ("kernel_shape = 'box'", ["kernel_shape must be one of"]),
    ("stride = 0", ["stride must be an integer >= 1"]),
    ("curvature_every = 0", ["curvature_every must be an integer >= 1"]),
    ("encoder_jets = 'sampled'", ["encoder_jets must be one of", "'auto', 'box', 'tube'"]),
])
def test_identify_h4_certified_table_errors_name_spec_file_and_key(run_and_spec, tmp_path, table, words):
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    run_, spec = run_and_spec
    spec_file = _h4_spec(tmp_path, run_, spec, certified=table)
    res = CliRunner().invoke(app, ["identify", str(_h4_log(run_, tmp_path, 300)), "--spec", str(spec_file),
                                   "--out", str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    out = " ".join(res.output.split())
    assert f"--spec {spec_file}: [certified]" in out and all(w in out for w in words), out


def test_identify_h4_with_a_coarse_encoder_says_what_leaves_the_prior(run_and_spec, tmp_path):
    """4 096 counts per turn on a 0.8 s log: the box stays at the prior, and the result says which parameters, which
    radius term dominates (a second-order term of the Mnac and Ibc columns: since wide boxes are split, the
    encoder's over the encoder boxes here, the truncation's over the motion tubes before; radii above 1e2 N m per
    unit parameter), and what would help; the row radius is labelled by its parts (no bare bound_processed); the
    statements are in sources."""
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    run_, spec = run_and_spec
    spec_file = _h4_spec(tmp_path, run_, spec, counts=4096)
    res = CliRunner().invoke(app, ["identify", str(_h4_log(run_, tmp_path, 800)), "--spec", str(spec_file),
                                   "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    diag = r["certified"]["prior_diagnosis"]
    assert len(diag["parameters"]) == 14 and diag["dominant"] in ("truncation", "second_order")
    assert {c["name"] for c in diag["columns"]} <= {"Mnac", "Ibc"}
    # about 575 N m per unit since the pose gradient of a wide box is enclosed over sub-boxes (h4_jets._x_jet's
    # split; about 1e6 before): still far above the torque side's 1.3 N m
    assert max(c["max_radius_per_unit"] for c in diag["columns"]) > 1e2
    out = " ".join(res.output.split())
    assert "warning: 14 of 14 parameters stay at the prior" in out and "finer encoder" in out
    assert "bound_processed" not in r and "bound_processed" not in res.output
    rr = r["certified"]["row_radius"]
    assert rr["torque_side_max"] == pytest.approx(run_.noise_bound, rel=1e-9) and rr["total_median"] > 1e2
    assert "certified row radius: torque side" in out
    src = r["error_model"]["sources"]
    assert src["assembly_mode"].startswith("stated, not proven") and src["sin_cos"].startswith("stated, not proven")
    steps = r["certified"]["steps"]
    assert src["curvature_factor"].endswith(f"times 2; used on 0 of {steps} steps of this equation")


def test_a_failed_certificate_names_the_assumption_first(run_and_spec, tmp_path):
    """qd_max = 3 rad/s (the truth reaches 9-15.5): the certificate's status is failed and names each joint's
    stated and true value; the report's first lines say so; the command's check exits 1."""
    import typer

    from h4bench.scenarios.certificate import verdict_lines
    from h4bench.scenarios.cli_certified import exit_if_certificate_failed

    run_, spec = run_and_spec
    cert = _short(run_, spec, n=3000, qd_max=np.full(4, 3.0))
    true = np.abs(run_.truth.qd[:3000]).max(axis=0)
    assert cert["status"] == "failed"
    for j in range(4):
        assert f"qd_max of joint {j + 1} = 3 rad/s is below the simulated truth's max |qd| = {true[j]:.6g} rad/s" \
            in cert["failed"]
    lines = verdict_lines({"certificate": cert, "methods": {"certified": {"status": "ok", "all_enclosed": True}}})
    assert lines[0].startswith("**Certified box: FAILED**") and lines[2].startswith("- qd_max of joint 1 = 3 rad/s")
    with pytest.raises(typer.Exit) as exc:
        exit_if_certificate_failed({"certificate": cert})
    assert exc.value.exit_code == 1
    held = _short(run_, spec)
    assert held["status"] == "ok" and held["failed"] == []
    assert verdict_lines({"certificate": held, "methods": {"certified": {"status": "ok", "all_enclosed": True}}})[0] \
        .startswith("**Certified box: encloses the truth** (ok); the certificate holds")
    weak = _short(run_, spec, torque_error=np.full(4, 0.1))
    assert any(f.startswith("torque_error of joint 1 = 0.1 N m is below the simulated truth's injected")
               for f in weak["failed"])


@pytest.mark.slow
def test_run_certified_with_an_understated_qd_max_exits_1(tmp_path):
    """`h4bench run certified --quick` with [error_model] qd_max = 3: exit 1, report.md opens with the failure."""
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    toml = tmp_path / "qd3.toml"
    text = (Path(__file__).resolve().parents[2] / "scenarios" / "certified.toml").read_text()
    toml.write_text(text.replace("qd_max = 0.0", "qd_max = 3.0"))
    res = CliRunner().invoke(app, ["run", str(toml), "--quick", "--out", str(tmp_path / "r")])
    assert res.exit_code == 1, res.output
    first = (tmp_path / "r" / "report.md").read_text().splitlines()
    assert first[0].startswith("**Certified box: FAILED**") and first[2].startswith("- qd_max of joint 1 = 3 rad/s")


def test_the_derived_torque_error_covers_the_float_sum_of_a_square_wave_at_its_bound(run_and_spec):
    """The simulator applies ``command + error`` in floating point: a square wave at its bound gives
    ``|applied - logged|`` half an ulp above ``noise.bound`` (the oracle: that difference, formed here as the
    simulator forms it). The derived torque error covers it; without the log it is the bound itself."""
    run_, spec = run_and_spec
    rng = np.random.default_rng(0)
    logged = rng.uniform(-40.0, 40.0, (5000, 4))
    bound = 1.3
    applied = logged + np.where(rng.random((5000, 4)) < 0.5, -bound, bound)
    actual = np.abs(applied - logged).max()
    assert actual > bound  # the float sum: the bound alone would be an understated torque_error
    es = simulated_error_spec(spec, run_.reference, run_.dataset.dt, bound, logged)
    assert np.all(es.torque_error >= actual) and np.all(es.torque_error < bound * (1 + 1e-12))
    assert "float rounding" in es.sources["torque_error"]
    assert np.all(simulated_error_spec(spec, run_.reference, run_.dataset.dt, bound).torque_error == bound)


def test_the_stated_qdd_max_adds_the_torque_errors_acceleration_through_the_nominal_inertia(run_and_spec):
    """torque_error_acceleration against an independent construction (the diagonal is sim.axis_inertia at each
    pose, the inverse numpy's LAPACK); the rule: a slow reference gets its peak plus twice that acceleration, the
    scenario's own (fast) one its margin x peak; the truth's departure from the reference acceleration (MuJoCo's
    closed loop under the injected torque error) stays within the added term; a bad factor is refused by name."""
    from types import SimpleNamespace

    from h4bench import ident, sim
    from h4bench.scenarios.certificate import torque_error_acceleration
    from h4bench.scenarios.spec import ScenarioError
    from h4bench.sim.kinematics import forward_kinematics, jacobians

    run_, spec = run_and_spec
    ref, nominal = run_.reference, np.asarray(ident.NOMINAL_PARAMETERS)
    q = ref.q[::25]
    acc = torque_error_acceleration(run_.geometry, q, 1.3)
    J = jacobians(run_.geometry, q).J
    M = np.einsum("nai,naj->nij", J * np.array([nominal[4]] * 3 + [nominal[5]])[None, :, None], J)
    M[:, np.arange(4), np.arange(4)] += nominal[:4]
    x = np.atleast_2d(forward_kinematics(run_.geometry, q))
    for k in (0, len(q) // 2):
        np.testing.assert_allclose(np.diag(M[k]), sim.axis_inertia(run_.geometry, nominal, x[k]), rtol=1e-12)
    np.testing.assert_allclose(acc, 1.3 * np.abs(np.linalg.inv(M)).sum(axis=2).max(axis=0), rtol=1e-10)

    peak = np.abs(ref.qdd).max(axis=0)
    full = torque_error_acceleration(run_.geometry, ref.q, run_.noise_bound)
    es = simulated_error_spec(spec, ref, run_.dataset.dt, run_.noise_bound)
    np.testing.assert_array_equal(es.qdd_max, 2.0 * peak)  # the fast reference: the margin is the larger
    assert np.all(np.abs(run_.truth.qdd - ref.qdd[:len(run_.truth.qdd)]).max(axis=0) <= 2.0 * full)
    slow = SimpleNamespace(q=ref.q, qd=ref.qd, qdd=ref.qdd / 10)
    es = simulated_error_spec(spec, slow, run_.dataset.dt, run_.noise_bound)
    np.testing.assert_allclose(es.qdd_max, peak / 10 + 2.0 * full, rtol=1e-15)
    assert np.all(es.qdd_max > 2.0 * peak / 10) and "torque error's acceleration" in es.sources["qdd_max"]
    off = copy.deepcopy(spec)
    off["error_model"]["disturbance_factor_qdd"] = 0.0
    np.testing.assert_array_equal(simulated_error_spec(off, slow, run_.dataset.dt, run_.noise_bound).qdd_max,
                                  2.0 * peak / 10)
    off["error_model"]["disturbance_factor_qdd"] = -1.0
    with pytest.raises(ScenarioError, match="error_model.disturbance_factor_qdd must be a number >= 0"):
        simulated_error_spec(off, slow, run_.dataset.dt, run_.noise_bound)
