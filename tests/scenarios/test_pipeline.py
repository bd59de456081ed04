"""End to end: trajectory -> 1 kHz closed loop -> the paper's processing -> guaranteed boxes, and the error
budget that explains the oracle residual."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench import sim
from h4bench.scenarios.budget import error_budget
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.spec import load_spec


@pytest.fixture(scope="module")
def ten_seconds():
    spec = load_spec("paper")  # full size: 10 s
    spec["replay"]["enabled"] = False
    return run_experiment(spec, seed=3)


def test_ten_seconds_processed_hull_encloses_the_truth(ten_seconds):
    run = ten_seconds
    assert run.dataset.t[-1] - run.dataset.t[0] > 9.9
    r = run.residual
    assert np.all(np.abs(r) <= run.equation.bound)  # the derived bound covers the oracle residual
    for method in ("hull", "cgsp"):
        assert run.boxes[method].contains(run.theta_true).all(), method
    # the bound the estimators used is the raw claim propagated through the FIR (||h||_1), never less
    assert run.equation.bound.min() >= run.bound_raw * run.equation.info["l1_norm"] * (1 - 1e-12)


def test_error_budget_parts_add_up(ten_seconds):
    run = ten_seconds
    b = run.budget
    parts = [b["raw"][k]["max"] for k in ("noise", "derivatives", "model")]
    assert b["total_raw_max"] <= sum(parts) + 1e-9  # triangle inequality on exact linear parts
    assert b["raw"]["noise"]["max"] <= run.spec["noise"]["bound"] + 1e-12
    assert b["total_processed_max"] == pytest.approx(float(np.abs(run.residual).max()), rel=1e-9)


def test_error_budget_is_an_exact_split():
    """Independent check of linearity: with no noise the noise part vanishes and the rest is the total."""
    spec = load_spec("paper", quick=True)
    spec["noise"]["shape"], spec["noise"]["bound"] = "none", 0.0
    spec["bound"]["allowance"] = 1.0
    run = run_experiment(spec, seed=1, estimate=False)
    b = error_budget(run.geometry, run.dataset, run.truth, run.settings)
    assert b["raw"]["noise"]["max"] == 0.0
    assert b["processed"]["noise"]["max"] == 0.0


def test_exact_states_boxes_shrink_with_the_record(ten_seconds):
    """With the simulator's exact states (no filtering, no differentiation error), the hull under the
    injected noise bound (plus a small allowance for the soft loops) shrinks as the record grows."""
    run = ten_seconds
    tr, ds = run.truth, run.dataset
    end = tr.qd + tr.h * tr.qdd  # friction loss acts on the end-of-step velocity: same sign as qd, not small
    keep_rows = ((np.abs(tr.qd) > 0.05) & (np.abs(end) > 0.05) & (np.sign(end) == np.sign(tr.qd))).reshape(-1)
    delta = run.spec["noise"]["bound"] + 0.05  # injected noise bound + soft-loop allowance (models/README.md)
    prior = run.prior
    widths = {}
    for seconds in (2.0, 5.0, 10.0):
        n = int(np.searchsorted(ds.t - ds.t[0], seconds))
        w = ident.regressor(run.geometry, tr.q[:n], tr.qd[:n], tr.qdd[:n])
        y = ds.tau[:n].reshape(-1)
        rows = np.flatnonzero(keep_rows[: 4 * n])
        assert np.abs(y[rows] - w[rows] @ run.theta_true).max() <= delta
        box = ident.estimate(w[rows], y[rows], delta, prior)
        assert box.contains(run.theta_true).all()
        widths[seconds] = box.width
    mean = {k: float(np.mean(v / run.theta_true)) for k, v in widths.items()}
    assert mean[5.0] < mean[2.0] and mean[10.0] < mean[5.0], mean
    assert np.all(widths[10.0] <= widths[2.0] + 1e-12)


def test_identify_a_csv_log(tmp_path, ten_seconds):
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    ds = ten_seconds.dataset
    path = tmp_path / "log.csv"
    header = "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4"
    np.savetxt(path, np.column_stack([ds.t, ds.q, ds.tau]), delimiter=",", header=header, comments="", fmt="%.17g")
    res = CliRunner().invoke(app, ["identify", str(path), "--bound", "1.5", "--out", str(tmp_path / "id"), "--json"])
    assert res.exit_code == 0, res.output
    import json

    result = json.loads(res.output)
    box = result["methods"]["hull"]
    assert box["status"] == "ok"
    assert np.all(np.asarray(box["lower"]) <= ten_seconds.theta_true)
    assert np.all(ten_seconds.theta_true <= np.asarray(box["upper"]))
    assert (tmp_path / "id" / "result.json").is_file()
    res = CliRunner().invoke(app, ["identify", str(path), "--bound", "-1"])
    assert res.exit_code == 2 and "bound must be" in res.output
