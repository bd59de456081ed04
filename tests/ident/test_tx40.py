"""The shipped TX40 log (data/tx40): files, conversion to the joint side, and the least-squares estimate against
FIGAROH's regressor (PyPI ``figaroh``, Apache-2.0) when it is installed."""

from __future__ import annotations

import gzip
import hashlib

import numpy as np
import pytest

from h4bench.ident.robots import tx40

pytest.importorskip("pinocchio")


def test_shipped_files_are_the_documented_ones():
    """SHA-256 of the decompressed CSVs as stated in data/tx40/README.md (computed on the original files)."""
    readme = (tx40.DATA_DIR / "README.md").read_text()
    for name in ("pos_read_data.csv", "curr_data.csv"):
        digest = hashlib.sha256(gzip.decompress((tx40.DATA_DIR / f"{name}.gz").read_bytes())).hexdigest()
        assert digest in readme, name
    assert "Apache License" in (tx40.DATA_DIR / "LICENSE-Apache-2.0.txt").read_text()


def test_log_shape_and_conversion():
    log = tx40.load_log()
    assert log.q.shape == log.tau.shape == (45000, 6) and log.dt == 2e-4
    # first row of pos_read_data.csv: joint 2 reads 50.265 (= 1.5708 x 32) -> q2 = 50.265/32 - pi/2 ~ 0
    assert log.q_motor[0, 1] == 50.265
    assert abs(log.q[0, 1] - (50.265 / 32 - np.pi / 2)) < 1e-15
    # motor angles back from joint angles: q_motor = R (q - offsets), with the wrist coupling row by hand
    q = log.q - np.asarray(tx40.OFFSETS)
    back = q * np.asarray(tx40.RATIOS)
    back[:, 5] += 32.0 * q[:, 4]
    assert np.allclose(back, log.q_motor, rtol=0, atol=1e-12 * np.max(np.abs(log.q_motor)))
    # power balance: tau . qd (joint side) equals tau_motor . qd_motor (motor side), sample by sample
    qd = np.gradient(log.q, log.dt, axis=0)
    qd_m = np.gradient(log.q_motor, log.dt, axis=0)
    p_joint = np.einsum("ij,ij->i", log.tau, qd)
    p_motor = np.einsum("ij,ij->i", log.tau_motor, qd_m)
    assert np.allclose(p_joint, p_motor, rtol=1e-9, atol=1e-9 * np.max(np.abs(p_motor)))


def test_load_log_rejects_missing_directory(tmp_path):
    with pytest.raises(ValueError, match="directory"):
        tx40.load_log(tmp_path)


def test_prior_contains_the_urdf_and_example_values():
    robot = tx40.robot()
    lo, hi = tx40.standard_prior(robot)
    theta = robot.urdf_parameters({k: v for k, v in tx40.A_PRIORI.items()})
    assert np.all(lo <= theta) and np.all(theta <= hi)


def _figaroh_regressor(q, qd, qdd, model):
    """FIGAROH's standard regressor with friction, actuator inertia, offsets (rows joint-major, j N + k) and the
    TX40 example's coupling columns (row 5: a6, v6, sign(v5 + v6); row 6: a5, v5, sign(v5 + v6))."""
    from types import SimpleNamespace

    from figaroh.tools.regressor import build_regressor_basic

    robot = SimpleNamespace(model=model, data=model.createData())
    cfg = {"act_idxv": list(range(6)), "has_friction": True, "has_actuator_inertia": True, "has_joint_offset": True,
           "is_joint_torques": True, "is_external_wrench": False}
    W = build_regressor_basic(robot, q, qd, qdd, cfg)
    N = q.shape[0]
    W = np.c_[W, np.zeros((W.shape[0], 3))]
    W[4 * N:5 * N, -3], W[4 * N:5 * N, -2] = qdd[:, 5], qd[:, 5]
    W[5 * N:6 * N, -3], W[5 * N:6 * N, -2] = qdd[:, 4], qd[:, 4]
    W[4 * N:5 * N, -1] = W[5 * N:6 * N, -1] = np.sign(qd[:, 4] + qd[:, 5])
    return W


def test_least_squares_fit_agrees_with_figaroh():
    """Same processed states and torques: FIGAROH's regressor (its coupling parametrisation) and ours span the
    same columns, so the least-squares torque fits agree, and so do the parameters both parametrise alike."""
    pytest.importorskip("figaroh")
    from h4bench.ident.processing.filtering import derivatives

    robot = tx40.robot()
    base = robot.base()
    log = tx40.load_log()
    est = derivatives(log.q, log.dt, 100.0)  # all six joints at once
    v = est.valid
    q, qd, qdd = est.q[v][::20], est.qd[v][::20], est.qdd[v][::20]
    tau = log.tau[v][::20]
    Wf = _figaroh_regressor(q, qd, qdd, robot.model)
    y_f = tau.T.reshape(-1)  # joint-major
    theta_f, *_ = np.linalg.lstsq(Wf, y_f, rcond=1e-10)
    fit_f = (Wf @ theta_f).reshape(6, -1).T
    Wb = robot.regressor(q, qd, qdd, columns=base.independent)
    theta_b, *_ = np.linalg.lstsq(Wb, tau.reshape(-1), rcond=None)
    fit_b = (Wb @ theta_b).reshape(-1, 6)
    rel = np.max(np.abs(fit_f - fit_b)) / np.max(np.abs(tau))
    assert rel < 1e-8, rel
    # parameters parametrised alike: fv, fs of joints 1-4 and 6's Coulomb, the motor-6 terms
    names = dict(zip(base.names, theta_b))
    n_in = 60
    for i in range(4):
        assert abs(theta_f[n_in + i] - names[f"fv{i + 1}"]) < 1e-6 * (1 + abs(names[f"fv{i + 1}"]))
    for i in range(6):
        assert abs(theta_f[n_in + 6 + i] - names[f"fs{i + 1}"]) < 1e-6 * (1 + abs(names[f"fs{i + 1}"]))
    assert abs(theta_f[-1] - names["fsm6"]) < 1e-6 * (1 + abs(names["fsm6"]))
    # FIGAROH's fv5 (row 5's own qd5 coefficient) is our fv5 + fvm6; its fvm6 is ours
    assert abs(theta_f[n_in + 4] - (names["fv5"] + names["fvm6"])) < 1e-6 * (1 + abs(names["fv5"]))
    assert abs(theta_f[-2] - names["fvm6"]) < 1e-6 * (1 + abs(names["fvm6"]))


@pytest.mark.slow
def test_tx40_study_quick_invariants():
    """The scenario's study at the quick size, checked against independent computations: the envelope bounds by
    scipy's linprog on a few held-out rows, the WLS prediction inside the model envelope when WLS is inside the
    box, certain outliers infeasible over the relaxed box by linprog, coverage recomputed from the arrays."""
    from scipy.optimize import linprog

    from h4bench.scenarios.kinds.tx40 import SPEC_DEFAULTS, run_tx40

    cfg = {**SPEC_DEFAULTS["tx40"], "decimation": 200, "factors": [1.5], "outlier_q": 2}
    result, art = run_tx40(cfg, 0)
    m = result["methods"]["hull_1.5x"]
    assert m["status"] == "ok"
    env, eq_ho = art["envelope"], art["eq_ho"]
    lo, hi = np.array(m["lower"]), np.array(m["upper"])
    for k in np.linspace(0, len(eq_ho) - 1, 5).astype(int):
        c = eq_ho.W[k]
        bounds = list(zip(lo, hi))
        mn = linprog(c, bounds=bounds, method="highs").fun
        mx = -linprog(-c, bounds=bounds, method="highs").fun
        tol = 1e-9 * (np.abs(c) @ np.maximum(np.abs(lo), np.abs(hi)))
        assert env["lower"][k] <= mn + tol and env["upper"][k] >= mx - tol
        assert mn - env["lower"][k] <= 1e-6 * (1 + abs(mn)) and env["upper"][k] - mx <= 1e-6 * (1 + abs(mx))
    inside = (eq_ho.y >= env["lower"] - env["bound"]) & (eq_ho.y <= env["upper"] + env["bound"])
    assert m["heldout_coverage"] == pytest.approx(np.mean(inside))
    if m["wls_inside"]:
        pred = eq_ho.W @ art["wls_theta"]
        assert np.all(pred >= env["lower"] - 1e-9 * np.abs(pred)) and np.all(pred <= env["upper"] + 1e-9 * np.abs(pred))
    rl = result["relaxed"]
    if rl["status"] == "ok" and rl["certain_rows"]:
        eq = art["eq"]
        rlo, rhi = np.array(rl["lower"]), np.array(rl["upper"])
        for c in rl["certain"][:3]:
            row = eq.W[c["row"]]
            mn = linprog(row, bounds=list(zip(rlo, rhi)), method="highs").fun
            mx = -linprog(-row, bounds=list(zip(rlo, rhi)), method="highs").fun
            y = eq.y[c["row"]]
            assert y + c["bound"] < mn or y - c["bound"] > mx  # the strip misses the box's image
    assert 0.0 <= m["heldout_coverage"] <= 1.0
    assert result["min_consistent_bound"] <= max(result["bound"]) * (1 + 1e-9)
