"""Sample-by-sample checks: infeasible trajectories raise naming the first violating sample, its time, the
joint/axis, the value and the limit; the report's figures against direct recomputation; Limits validation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from h4bench import ident
from h4bench import sim
from h4bench import trajectories as tj


def first_bad(values, lower, upper):
    """(sample, column) of the first violation, computed directly."""
    bad = (values < lower) | (values > upper)
    k = int(np.flatnonzero(bad.any(axis=1))[0])
    return k, int(np.flatnonzero(bad[k])[0])


def raised(geometry, traj, limits=None, theta=None) -> tj.InfeasibleTrajectoryError:
    with pytest.raises(tj.InfeasibleTrajectoryError) as info:
        tj.check_trajectory(geometry, traj, limits, theta)
    assert isinstance(info.value, ValueError)
    return info.value


def assert_names(err, k, t, label, limit_text):
    msg = str(err)
    assert f"sample {k} " in msg and f"t = {t:.4f} s" in msg and f" {label} = " in msg and limit_text in msg, msg
    assert err.index == k and err.time == pytest.approx(t) and err.label == label


def test_outside_the_workspace_raises_at_the_first_violating_sample(geometry, short_excitation):
    z_top = short_excitation.x[:, 2].max() - 0.01  # a box whose top the trajectory crosses
    lim = tj.Limits(x_upper=(0.12, 0.12, z_top, 0.5))
    err = raised(geometry, short_excitation, lim)
    k, j = first_bad(short_excitation.x, np.array(lim.x_lower), np.array(lim.x_upper))
    assert err.check == "workspace" and j == 2
    assert_names(err, k, short_excitation.t[k], "z", f"[-0.72, {z_top:.6g}] m")
    assert err.value == short_excitation.x[k, 2] and err.upper == z_top


def test_too_fast_raises_naming_speed_or_acceleration(geometry, short_excitation):
    fast = tj.fourier_trajectory(geometry, short_excitation.parameters, duration=short_excitation.duration / 2)
    assert not fast.checks["feasible"]
    err = raised(geometry, fast)
    lim = tj.Limits()
    k_v, j_v = first_bad(fast.qd, -8.0, 8.0)
    k_a, j_a = first_bad(fast.qdd, -150.0, 150.0)
    if k_a < k_v:
        assert err.check == "acceleration"
        assert_names(err, k_a, fast.t[k_a], f"q{j_a + 1}", "[-150, 150] rad/s^2")
    else:
        assert err.check == "speed"
        assert_names(err, k_v, fast.t[k_v], f"q{j_v + 1}", "[-8, 8] rad/s")
    assert {"speed", "acceleration"} <= set(err.violations) and lim.qd_max == (8.0,) * 4


def test_torque_too_high_raises_with_the_limit(geometry, short_excitation):
    heavy = tj.nominal_parameters()
    heavy[ident.PARAMETER_NAMES.index("Mnac")] = 6.0  # a 6 kg tool
    err = raised(geometry, short_excitation, None, heavy)
    tau = ident.inverse_dynamics(geometry, heavy, short_excitation.q, short_excitation.qd, short_excitation.qdd)
    k, j = first_bad(tau, -12.0, 12.0)
    assert err.check == "torque"
    assert_names(err, k, short_excitation.t[k], f"q{j + 1}", "[-12, 12] N m")
    assert err.value == pytest.approx(tau[k, j], rel=1e-12)


def test_singularity_margin_is_checked(geometry, short_excitation):
    c = sim.singularity_measure(geometry, short_excitation.x)
    err = raised(geometry, short_excitation, tj.Limits(max_cond_jx=float(np.median(c))))
    k = int(np.flatnonzero(c > np.median(c))[0])
    assert err.check == "singularity" and err.index == k and "cond(Jx)" in str(err)


def _manual(geometry, x, q=None):
    n = x.shape[0]
    q = sim.kinematics._ik(geometry, x)[0] if q is None else q
    zeros = np.zeros((n, 4))
    return tj.Trajectory(t=np.arange(n) * 1e-3, x=x, q=q, qd=zeros, qdd=zeros, kind="manual")


def test_unreachable_and_inconsistent_samples_are_named(geometry):
    x = np.tile(geometry.x_home, (5, 1))
    x[3, 2] = -0.2  # forearms cannot reach this high
    err = raised(geometry, _manual(geometry, x))
    assert err.check == "reach" and err.index == 3 and "reach" in str(err)
    x = np.tile(geometry.x_home, (5, 1))
    q = sim.inverse_kinematics(geometry, x)
    q[2, 1] += 1e-3
    err = raised(geometry, _manual(geometry, x, q))
    assert err.check == "consistency" and err.index == 2 and err.label == "q2"


def test_report_figures_match_direct_computation(geometry, short_excitation):
    r = tj.check_trajectory(geometry, short_excitation)
    traj = short_excitation
    np.testing.assert_allclose(r["peak_qd"], np.abs(traj.qd).max(axis=0))
    np.testing.assert_allclose(r["peak_qdd"], np.abs(traj.qdd).max(axis=0))
    tau = ident.inverse_dynamics(geometry, tj.nominal_parameters(), traj.q, traj.qd, traj.qdd)
    np.testing.assert_allclose(r["peak_tau"], np.abs(tau).max(axis=0), rtol=1e-9)
    assert r["max_cond_jx"] == pytest.approx(sim.singularity_measure(geometry, traj.x).max(), rel=1e-9)
    lim = tj.Limits()
    assert r["min_workspace_margin_m"] == pytest.approx(
        np.minimum(traj.x[:, :3] - lim.x_lower[:3], np.array(lim.x_upper[:3]) - traj.x[:, :3]).min())
    W = ident.regressor(geometry, traj.q, traj.qd, traj.qdd)
    assert r["cond_W"] == pytest.approx(np.linalg.cond(W), rel=1e-6)
    assert r["cond_W_normalised"] == pytest.approx(np.linalg.cond(W / np.linalg.norm(W, axis=0)), rel=1e-6)
    assert r["limit_tau"] == [12.0] * 4 and r["feasible"] and r == traj.report()


def test_nominal_parameters_follow_the_documented_order():
    theta = tj.nominal_parameters()
    named = dict(zip(ident.PARAMETER_NAMES, theta))
    assert named["Imot3"] == 0.012 and named["Mnac"] == 1.0 and named["Ibc"] == 0.003
    assert named["Fv1"] == 0.16 and named["Fs4"] == 0.99


@pytest.mark.parametrize("kwargs, match", [
    ({"qd_max": -1.0}, "qd_max"),
    ({"qdd_max": (1.0, 2.0)}, "qdd_max"),
    ({"tau_max": float("nan")}, "tau_max"),
    ({"x_lower": (0.2, -0.12, -0.72, -0.5)}, "x_lower"),
    ({"x_upper": (0.1, 0.1)}, "x_upper"),
    ({"torque_margin": 0.0}, "torque_margin"),
    ({"q_margin": -0.1}, "q_margin"),
    ({"max_cond_jx": float("inf")}, "max_cond_jx"),
])
def test_limits_validation_names_the_field(kwargs, match):
    with pytest.raises(ValueError, match=match):
        tj.Limits(**kwargs)


def test_limits_round_trip_and_per_joint_values():
    lim = tj.Limits(qd_max=(8, 7, 6, 5), torque_margin=0.7)
    assert tj.Limits.from_dict(lim.to_dict()) == lim
    assert lim.qd_max == (8.0, 7.0, 6.0, 5.0)
    np.testing.assert_allclose(lim.tau_allowed, 10.5)
    assert dataclasses.replace(lim, q_margin=0.1).q_margin == 0.1


def test_check_trajectory_input_types(geometry, short_excitation):
    with pytest.raises(TypeError, match="traj"):
        tj.check_trajectory(geometry, {"q": short_excitation.q})
    with pytest.raises(TypeError, match="geometry"):
        tj.check_trajectory(None, short_excitation)
