"""toppra timing: waypoint paths within the limits (2 %), through the waypoints, no slower than an independently
timed rest-to-rest scaling of the same path; the vectorised torque constraint against toppra's own; slow-downs."""

from __future__ import annotations

import importlib.metadata

import numpy as np
import pytest
import toppra

from h4bench import ident
from h4bench import sim
from h4bench import trajectories as tj
from h4bench.trajectories.checks import check_samples
from h4bench.trajectories.timing import _FS, _FV, NominalTorqueConstraint

PICK_PLACE = np.array([  # home -> above pick -> pick -> above pick -> above place -> place -> home [m, m, m, rad]
    [0.0, 0.0, -0.55, 0.0], [0.08, 0.06, -0.52, 0.3], [0.08, 0.06, -0.64, 0.3], [0.08, 0.06, -0.52, 0.3],
    [-0.08, -0.05, -0.52, -0.3], [-0.08, -0.05, -0.64, -0.3], [0.0, 0.0, -0.55, 0.0]])


@pytest.fixture(scope="module")
def pick_place(geometry):
    return tj.waypoint_trajectory(geometry, PICK_PLACE)


def test_waypoint_timing_respects_speed_and_acceleration_to_two_percent(geometry, pick_place):
    traj = pick_place
    assert np.abs(traj.qd).max(axis=0).max() <= 1.02 * 8.0
    assert np.abs(traj.qdd).max(axis=0).max() <= 1.02 * 150.0
    tau = ident.inverse_dynamics(geometry, tj.nominal_parameters(), traj.q, traj.qd, traj.qdd)
    assert np.abs(tau).max() <= 1.02 * 12.0
    # time-optimal: some limit is reached (within toppra's 0.98 scaling and the sampling)
    usage = traj.checks["usage"]
    assert max(usage["speed"], usage["acceleration"], usage["torque"]) > 0.95
    assert traj.checks["feasible"] and traj.kind == "waypoints"
    assert traj.parameters["timing"]["toppra_version"] == importlib.metadata.version("toppra")


def test_waypoint_path_visits_the_waypoints_and_rests_at_the_ends(geometry, pick_place):
    traj = pick_place
    v_cart = np.linalg.norm(np.diff(traj.x[:, :3], axis=0), axis=1).max()  # largest step between samples [m]
    for wp in PICK_PLACE:
        assert np.linalg.norm(traj.x[:, :3] - wp[:3], axis=1).min() <= v_cart
    # at the recorded waypoint times the joint reference is the waypoint's IK (interpolated between samples)
    q_wp = sim.inverse_kinematics(geometry, PICK_PLACE)
    times = np.array(traj.parameters["waypoint_times"])
    assert np.all(np.diff(times) > 0) and times[0] == 0.0
    q_at = np.column_stack([np.interp(times, traj.t, traj.q[:, j]) for j in range(4)])
    assert np.abs(q_at - q_wp).max() <= np.abs(traj.qd).max() * traj.dt
    for k in (0, -1):
        assert np.all(traj.qd[k] == 0.0) and np.all(traj.qdd[k] == 0.0)
        np.testing.assert_allclose(traj.x[k], PICK_PLACE[k], atol=1e-9)
    np.testing.assert_allclose(sim.inverse_kinematics(geometry, traj.x[::25]), traj.q[::25], atol=1e-9)


def test_toppra_is_no_slower_than_an_independently_timed_scaling(geometry, pick_place):
    """Oracle: the same spline path traversed as s(t) = S sigma(t / T) (quintic rest-to-rest), with the smallest
    T (bisection) that passes the same checks. Time-optimal timing cannot take longer."""
    q_wp = sim.inverse_kinematics(geometry, PICK_PLACE)
    ss = np.array(pick_place.parameters["path_s"])
    path = toppra.SplineInterpolator(ss, q_wp, bc_type="clamped")

    def feasible(T):
        t = np.linspace(0.0, T, int(T / 1e-3) + 1)
        u = t / T
        sig, dsig, ddsig = (u**3 * (10 - 15 * u + 6 * u**2), 30 * u**2 * (1 - u) ** 2 / T,
                            60 * u * (1 - u) * (1 - 2 * u) / T**2)
        s, sd, sdd = ss[-1] * sig, ss[-1] * dsig, ss[-1] * ddsig
        q = path(s)
        qd = path(s, 1) * sd[:, None]
        qdd = path(s, 2) * sd[:, None] ** 2 + path(s, 1) * sdd[:, None]
        x = sim.forward_kinematics(geometry, q)
        return check_samples(geometry, t, x, q, qd, qdd, raise_on_violation=False)["feasible"]

    lo, hi = pick_place.duration * 0.5, pick_place.duration * 4
    assert feasible(hi) and not feasible(lo)
    while hi - lo > 0.01 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if feasible(mid) else (mid, hi)
    assert pick_place.duration <= hi, (pick_place.duration, hi)


def test_friction_slices_follow_the_parameter_names():
    assert [ident.PARAMETER_NAMES[i] for i in _FV] == ["Fv1", "Fv2", "Fv3", "Fv4"]
    assert [ident.PARAMETER_NAMES[i] for i in _FS] == ["Fs1", "Fs2", "Fs3", "Fs4"]


def test_vectorised_torque_constraint_equals_toppras_own(geometry):
    q_wp = sim.inverse_kinematics(geometry, PICK_PLACE[:4])
    path = toppra.SplineInterpolator(np.arange(4.0), q_wp, bc_type="clamped")
    grid = np.linspace(0, 3, 31)
    theta = tj.nominal_parameters()
    lim = np.column_stack([-np.full(4, 10.0), np.full(4, 10.0)])
    ours = NominalTorqueConstraint(geometry, theta, lim)
    ref = toppra.constraint.JointTorqueConstraint(ours.inv_dyn, lim, theta[10:14])
    for a, b in zip(ours.compute_constraint_params(path, grid), ref.compute_constraint_params(path, grid)):
        if a is None:
            assert b is None
        else:
            np.testing.assert_allclose(a, b, atol=1e-10)


def test_uniform_slow_down_is_feasible_and_minimal(geometry, short_excitation):
    fast = tj.fourier_trajectory(geometry, short_excitation.parameters, duration=short_excitation.duration / 2)
    slow = tj.slow_down(geometry, fast, method="uniform")
    info = slow.parameters["slow_down"]
    assert slow.checks["feasible"] and slow.kind == "fourier+uniform-slowdown"
    assert info["method"] == "uniform" and info["factor"] == pytest.approx(slow.duration / fast.duration)
    assert {"speed", "acceleration"} & set(info["violations_before"])
    tj.check_trajectory(geometry, slow)  # no raise
    for k in (0, -1):
        assert np.all(slow.qd[k] == 0.0) and np.all(slow.qdd[k] == 0.0)
    # minimal to the search's resolution: 1 % faster is infeasible
    faster = tj.fourier_trajectory(geometry, fast.parameters, duration=0.99 * slow.duration)
    assert not faster.checks["feasible"]


def test_toppra_slow_down_keeps_the_path_and_never_speeds_up(geometry, short_excitation):
    fast = tj.fourier_trajectory(geometry, short_excitation.parameters, duration=short_excitation.duration / 2)
    slow = tj.slow_down(geometry, fast, method="toppra")
    assert slow.checks["feasible"] and slow.parameters["slow_down"]["method"] == "toppra"
    assert fast.duration < slow.duration
    assert slow.parameters["slow_down"]["toppra_version"] == tj.TOPPRA_VERSION
    # the same joint path: every new sample is within one original step of the original samples
    step = np.abs(np.diff(fast.q, axis=0)).max()
    d = np.abs(slow.q[::7, None, :] - fast.q[None, ::1, :]).max(axis=2).min(axis=1)
    assert d.max() <= step
    # the slow phase stays as slow as designed (sd <= 1): its peak speed does not grow
    knots = np.array(fast.parameters["schedule_knots"])
    slow_phase = fast.t < knots[2]
    n_slow = int(np.count_nonzero(slow_phase))
    assert np.abs(slow.qd[:n_slow]).max() <= np.abs(fast.qd[slow_phase]).max() * 1.02


def test_slow_down_leaves_a_feasible_trajectory_alone_and_refuses_geometry(geometry, short_excitation):
    assert tj.slow_down(geometry, short_excitation) is short_excitation
    lim = tj.Limits(x_upper=(0.12, 0.12, short_excitation.x[:, 2].max() - 0.01, 0.5))
    with pytest.raises(tj.InfeasibleTrajectoryError, match="cannot repair.*workspace.*sample"):
        tj.slow_down(geometry, short_excitation, limits=lim)
    with pytest.raises(ValueError, match="method"):
        tj.slow_down(geometry, short_excitation, method="magic")
    wp = tj.waypoint_trajectory(geometry, PICK_PLACE[:3])
    with pytest.raises(ValueError, match="uniform"):
        tj.slow_down(geometry, wp, limits=tj.Limits(qd_max=3.0), method="uniform")


@pytest.mark.parametrize("waypoints, match", [
    (np.zeros(4), "waypoints_x must have shape"),
    (np.zeros((3, 3)), "waypoints_x must have shape"),
    (PICK_PLACE[:1], "waypoints_x must have shape"),
    (np.where(np.arange(28).reshape(7, 4) == 9, np.nan, PICK_PLACE), r"waypoints_x must be finite.*row\(s\) \[2\]"),
    (np.array([[0, 0, -0.55, 0], [0, 0, -0.55, 0]]), "waypoints_x rows 0 and 1 coincide"),
    ("abc", "waypoints_x"),
])
def test_bad_waypoints_name_the_argument(geometry, waypoints, match):
    with pytest.raises((ValueError, TypeError), match=match):
        tj.waypoint_trajectory(geometry, waypoints)


def test_waypoint_outside_the_workspace_is_named(geometry):
    bad = PICK_PLACE.copy()
    bad[2, 2] = -0.30
    with pytest.raises(tj.InfeasibleTrajectoryError, match=r"waypoints_x\[2\].*z = -0.3 not in \[-0.72, -0.4\]"):
        tj.waypoint_trajectory(geometry, bad)
    with pytest.raises(ValueError, match="dt"):
        tj.waypoint_trajectory(geometry, PICK_PLACE, dt=-1e-3)
