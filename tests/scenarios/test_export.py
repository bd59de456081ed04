"""``h4bench export``: a run's dataset as the CSV ``identify`` reads, with the run's true error specification.

Oracles: the run folder's own files (``dataset.npz`` read by numpy, ``trajectory.npz``, ``result.json``'s truth and
noise bound), the exported CSV read back by ``numpy.loadtxt`` (not h4bench's reader).
"""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from typer.testing import CliRunner

from h4bench.scenarios.cli import app


@pytest.fixture(scope="module")
def exported(paper_quick_cli, tmp_path_factory):
    run_dir, _ = paper_quick_cli
    d = tmp_path_factory.mktemp("export")
    res = CliRunner().invoke(app, ["export", str(run_dir), str(d / "log.csv")])
    assert res.exit_code == 0, res.output
    return run_dir, d, res.output


def test_the_csv_rows_are_the_dataset(exported):
    run_dir, d, output = exported
    assert f"identify {d / 'log.csv'} --spec {d / 'spec.toml'}" in output
    with np.load(run_dir / "dataset.npz") as z:
        t, q, tau = z["t"], z["q"], z["tau"]
    header = (d / "log.csv").read_text().splitlines()[0]
    assert header == "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4"
    rows = np.loadtxt(d / "log.csv", delimiter=",", skiprows=1)
    assert rows.shape == (t.size, 9)
    assert np.array_equal(rows[:, 0], t) and np.array_equal(rows[:, 1:5], q) and np.array_equal(rows[:, 5:], tau)


def test_the_spec_is_the_runs_true_specification(exported):
    """The spec states the simulator's settings and the certified scenario's motion bounds (1.25 x / 2.0 x the
    reference's peaks, scenarios/certified.toml), read here from the run folder's files."""
    run_dir, d, _ = exported
    spec = tomllib.loads((d / "spec.toml").read_text())
    em = spec["error_model"]
    result = json.loads((run_dir / "result.json").read_text())
    meta = json.loads((run_dir / "dataset.json").read_text())
    with np.load(run_dir / "trajectory.npz") as z:
        qd_ref, qdd_ref = np.abs(z["qd"]).max(axis=0), np.abs(z["qdd"]).max(axis=0)
    with np.load(run_dir / "dataset.npz") as z:
        dt = float(np.median(np.diff(z["t"])))
        tau_max = float(np.max(np.abs(z["tau"])))
    assert em["sample_period"] == dt
    assert em["counts_per_turn"] == meta["encoder_counts"] == 20000
    assert em["torque_timing"] == "hold"
    # the injected error's bound plus the float rounding of command + error (scenarios.certificate)
    bound = result["noise"]["bound"]
    assert np.all(np.asarray(em["torque_error"]) > bound)
    assert np.all(np.asarray(em["torque_error"]) - bound <= 2.0**-51 * (tau_max + bound))
    assert "float rounding" in em["sources"]["torque_error"]
    assert np.allclose(em["qd_max"], 1.25 * qd_ref, rtol=1e-15) and np.allclose(em["qdd_max"], 2.0 * qdd_ref,
                                                                                  rtol=1e-15)
    # the simulator's soft friction: Coulomb's only above (qdd_max + R Fs_max) / b (sim.friction, the shipped model,
    # Fs_max the prior's upper bound 2 N m)
    from h4bench.sim.friction import friction_band
    from h4bench.sim.model import load_model

    np.testing.assert_array_equal(em["friction_band"], friction_band(load_model(), em["qdd_max"], 2.0))
    assert "soft friction" in em["sources"]["friction_band"]
    # the certified scenario's [certified] table: kernel_steps 0, every kernel of the family
    assert spec["certified"]["kernel_steps"] == 0 and "sources" in em


def test_identify_spec_on_the_export_encloses_the_truth(exported, tmp_path):
    """The two commands: the certified box of the exported log holds the run's true parameters."""
    run_dir, d, _ = exported
    res = CliRunner().invoke(app, ["identify", str(d / "log.csv"), "--spec", str(d / "spec.toml"), "--json",
                                   "--out", str(tmp_path / "id")])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    truth = json.loads((run_dir / "result.json").read_text())
    assert out["parameters"] == truth["parameters"]
    box = out["methods"]["certified"]
    assert box["status"] == "ok"
    true = np.asarray(truth["true"])
    lo, hi = np.asarray(box["lower"]), np.asarray(box["upper"])
    inside = (lo <= true) & (true <= hi)
    assert inside.all(), [n for n, ok in zip(out["parameters"], inside) if not ok]
    assert np.all(hi - lo < 2.0)  # narrower than the prior [0, 2] on every parameter


def test_export_refuses_a_file_it_did_not_write(exported, tmp_path):
    run_dir, _, _ = exported
    mine = tmp_path / "log.csv"
    mine.write_text("my own log\n")
    res = CliRunner().invoke(app, ["export", str(run_dir), str(mine)])
    assert res.exit_code == 2 and "LOG_CSV" in res.output and "did not write" in res.output
    assert mine.read_text() == "my own log\n"
    # its own file is replaced; an edited one is the user's
    other = tmp_path / "b" / "log.csv"
    other.parent.mkdir()
    assert CliRunner().invoke(app, ["export", str(run_dir), str(other)]).exit_code == 0
    assert CliRunner().invoke(app, ["export", str(run_dir), str(other)]).exit_code == 0
    (other.parent / "spec.toml").write_text((other.parent / "spec.toml").read_text() + "# edited\n")
    res = CliRunner().invoke(app, ["export", str(run_dir), str(other)])
    assert res.exit_code == 2 and "--spec" in res.output


def test_export_needs_a_run_folder(tmp_path):
    res = CliRunner().invoke(app, ["export", str(tmp_path), str(tmp_path / "log.csv")])
    assert res.exit_code == 2 and "RUN_DIR" in res.output and not (tmp_path / "log.csv").exists()


def test_a_certified_runs_own_error_model_is_exported(tmp_path):
    """A run whose result.json holds its error_model (kind certified) exports that specification: read back by
    ErrorSpec.from_toml it is the same entry for entry, the equation's stated assumptions (in the run's sources, not
    entries of a specification) left out (a small hand-made run folder, no simulation)."""
    from h4bench import sim
    from h4bench.ident.processing.errorspec import ErrorSpec
    from h4bench.scenarios.export import export_run

    spec = ErrorSpec(n_joints=4, sample_period=1e-3, position_resolution=2 * np.pi / 20000, torque_error=1.3,
                     qd_max=[7.0, 8.0, 9.0, 10.0], qdd_max=[300.0, 310.0, 320.0, 330.0], model_error=0.01,
                     sources={"torque_error": 'the injected error\'s bound "noise.bound"'})
    run = tmp_path / "run"
    run.mkdir()
    t = np.arange(50) * 1e-3
    sim.Dataset(t, np.sin(t)[:, None] * np.ones(4), np.cos(t)[:, None] * np.ones(4), {"encoder_counts": 20000}).save(
        run / "dataset")
    # as `run certified` writes it: the equation's stated-not-proven assumptions beside the spec's sources
    own = spec.to_dict()
    own["sources"] = dict(own["sources"], assembly_mode="stated, not proven: ...", sin_cos="stated, not proven: ...",
                          curvature_factor="stated, not proven: ...", not_proven_1="stated, not proven: ...")
    (run / "result.json").write_text(json.dumps({"error_model": own, "noise": {"bound": 1.3}}))
    written = export_run(run, tmp_path / "log.csv", tmp_path / "em.toml")
    back = ErrorSpec.from_toml(tmp_path / "em.toml", 4)
    assert back.to_dict() == spec.to_dict() == written["error_model"]
    assert tomllib.loads((tmp_path / "em.toml").read_text())["error_model"]["counts_per_turn"] == 20000
