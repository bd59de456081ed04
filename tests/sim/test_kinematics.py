"""Kinematics against MuJoCo (the oracle for loop closure) and finite differences."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from h4bench import sim
from tests.conftest import random_workspace_poses


@pytest.fixture(scope="module")
def poses():
    return random_workspace_poses(np.random.default_rng(42), 200)


def test_inverse_kinematics_closes_mujocos_loops(model, geometry, poses):
    q = sim.inverse_kinematics(geometry, poses)
    qpos = geometry.qpos(q, poses)
    d = mujoco.MjData(model)
    worst = 0.0
    for row in qpos:
        d.qpos[:] = row
        mujoco.mj_forward(model, d)
        eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        worst = max(worst, np.abs(d.efc_pos[eq]).max())
        # MuJoCo's nacelle frame is where the pose says
        np.testing.assert_allclose(geometry.nacelle_pose(d.qpos), geometry.nacelle_pose(row))
    assert worst < 1e-9, worst


def test_home_pose_gives_zero_motor_angles(geometry):
    np.testing.assert_allclose(sim.inverse_kinematics(geometry, geometry.x_home), 0.0, atol=1e-14)


def test_forward_inverse_round_trip(geometry, poses):
    q = sim.inverse_kinematics(geometry, poses)
    x = sim.forward_kinematics(geometry, q)
    assert np.abs(x - poses).max() < 1e-9
    assert sim.forward_kinematics(geometry, q[0]).shape == (4,)


def test_jacobian_matches_finite_differences_of_forward_kinematics(geometry, poses):
    q = sim.inverse_kinematics(geometry, poses[:40])
    jac = sim.jacobians(geometry, q)
    h = 1e-6
    fd = np.empty_like(jac.J)
    for j in range(4):
        dq = np.zeros(4)
        dq[j] = h
        fd[:, :, j] = (sim.forward_kinematics(geometry, q + dq) - sim.forward_kinematics(geometry, q - dq)) / (2 * h)
    rel = np.abs(fd - jac.J).max(axis=(1, 2)) / np.abs(jac.J).max(axis=(1, 2))
    assert rel.max() < 1e-6, rel.max()


def test_jacobian_dot_matches_finite_differences(geometry, poses):
    rng = np.random.default_rng(5)
    q = sim.inverse_kinematics(geometry, poses[:40])
    qd = rng.uniform(-2, 2, q.shape)
    jd = sim.jacobian_dot(geometry, q, qd)
    h = 1e-6
    fd = (sim.jacobians(geometry, q + h * qd).J - sim.jacobians(geometry, q - h * qd).J) / (2 * h)
    rel = np.abs(fd - jd).max(axis=(1, 2)) / np.abs(jd).max(axis=(1, 2))
    assert rel.max() < 1e-5, rel.max()


def test_cartesian_acceleration_matches_mujoco(exact_recording, geometry):
    """xdd = J qdd + Jd qd against MuJoCo's own nacelle acceleration (soft loops: small, O(h) mismatch)."""
    r = exact_recording
    x, xd, xdd = sim.cartesian_motion(geometry, r["q"], r["qd"], r["qdd"])
    assert np.abs(x - r["x"]).max() < 1e-4
    scale = np.abs(r["xdd"]).max(axis=0)
    assert np.all(np.median(np.abs(xdd - r["xdd"]), axis=0) < 1e-3 * scale)


def test_ten_seconds_of_random_torques_keep_the_loops_closed(model, geometry):
    d = mujoco.MjData(model)
    rng = np.random.default_rng(11)
    hold = np.zeros(4)
    worst_violation, worst_pos, worst_theta = 0.0, 0.0, 0.0
    steps = int(10.0 / model.opt.timestep)
    for k in range(steps):
        if k % 100 == 0:
            hold = rng.uniform(-3.0, 3.0, 4)
        q, qd = d.qpos[geometry.qpos_motor], d.qvel[geometry.dof_motor]
        d.ctrl[:] = np.clip(40.0 * (0.0 - q) - 2.0 * qd + hold, -15.0, 15.0)
        mujoco.mj_step(model, d)
        if k % 20 == 0:
            eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
            worst_violation = max(worst_violation, np.abs(d.efc_pos[eq]).max())
            x_fk = sim.forward_kinematics(geometry, d.qpos[geometry.qpos_motor])
            x_mj = geometry.nacelle_pose(d.qpos)
            worst_pos = max(worst_pos, np.abs(x_fk[:3] - x_mj[:3]).max())
            worst_theta = max(worst_theta, abs(x_fk[3] - x_mj[3]))
    assert worst_violation < 1e-5
    # the nacelle pose from MuJoCo's motor angles agrees with MuJoCo's within the loop violation
    # (theta turned into a displacement at the lateral bars' lever arm |DC|)
    lever = np.linalg.norm(geometry.bar_offset, axis=1).max()
    assert worst_pos <= 10 * worst_violation
    assert worst_theta * lever <= 10 * worst_violation


def test_outside_workspace_is_reported_with_sample_and_chain(geometry):
    x = np.array([geometry.x_home, [0.0, 0.0, -1.5, 0.0]])
    with pytest.raises(sim.KinematicsError, match=r"sample 1 .*chain"):
        sim.inverse_kinematics(geometry, x)


@pytest.mark.parametrize("bad, match", [
    (np.zeros(3), r"x must have shape \(4,\) or \(n, 4\), got \(3,\)"),
    (np.zeros((2, 5)), r"got \(2, 5\)"),
    (np.array([0.0, np.nan, -0.5, 0.0]), "finite"),
])
def test_bad_poses(geometry, bad, match):
    with pytest.raises(ValueError, match=match):
        sim.inverse_kinematics(geometry, bad)


def test_bad_motor_angles(geometry):
    with pytest.raises(ValueError, match=r"q must have shape"):
        sim.forward_kinematics(geometry, np.zeros((4, 3)))
    with pytest.raises(ValueError, match="finite"):
        sim.forward_kinematics(geometry, np.array([np.inf, 0, 0, 0]))
    with pytest.raises(sim.KinematicsError, match="did not converge|outside"):
        sim.forward_kinematics(geometry, np.array([3.0, -3.0, 3.0, -3.0]))
    with pytest.raises(TypeError, match="geometry must be"):
        sim.forward_kinematics("h4", np.zeros(4))
