"""Ground-truth parameters against MuJoCo's own joint-space inertia matrix."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest

from h4bench import sim
from h4bench.ident import PARAMETER_NAMES
from tests.conftest import random_workspace_poses


def test_order_matches_ident(model):
    assert sim.TRUE_PARAMETER_ORDER == PARAMETER_NAMES
    assert sim.true_parameters(model).shape == (14,)


def test_nacelle_kinetic_energy_is_the_papers_diagonal(model):
    m4 = sim.nacelle_mass_matrix(model)
    np.testing.assert_allclose(m4, np.diag(np.diag(m4)), atol=1e-15)
    assert m4[0, 0] == m4[1, 1] == m4[2, 2]


def _constrained_inertia(model, geometry, q, x):
    """Oracle: MuJoCo's joint-space inertia (mj_fullM) at the closed pose (q, x), reduced to the motion the
    loops allow: W^T M W with W = d(all dofs)/d(motor dofs) (W[motors] = I, W[others] = -pinv(Jc_o) Jc_m,
    Jc = MuJoCo's equality rows of efc_J)."""
    m = copy.copy(model)
    m.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    d = mujoco.MjData(m)
    d.qpos[:] = geometry.qpos(q, x)
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    jc = d.efc_J.reshape(d.nefc, m.nv)[: d.ne]
    act = geometry.dof_motor
    other = np.setdiff1d(np.arange(m.nv), act)
    w = np.zeros((m.nv, 4))
    w[act] = np.eye(4)
    w[other] = -np.linalg.pinv(jc[:, other]) @ jc[:, act]
    return w.T @ full @ w, full


def test_true_parameters_against_mujoco_mass_matrix(model, geometry):
    """The paper's joint-space inertia diag(Imot) + J^T diag(Mnac, Mnac, Mnac, Ibc) J with the true values
    equals MuJoCo's constrained inertia, at home and at random poses."""
    theta = sim.true_parameters(model)
    rng = np.random.default_rng(5)
    poses = np.vstack([geometry.x_home, random_workspace_poses(rng, 5)])
    for x in poses:
        q = sim.inverse_kinematics(geometry, x)
        reduced, _ = _constrained_inertia(model, geometry, q, x)
        j = sim.jacobians(geometry, q, x).J
        paper = np.diag(theta[:4]) + j.T @ np.diag([theta[4]] * 3 + [theta[5]]) @ j
        # atol: the rods' own inertia (1e-12 kg m^2, MuJoCo needs > 0) turns with them
        np.testing.assert_allclose(reduced, paper, rtol=1e-10, atol=1e-12)
    for i, dof in enumerate(geometry.dof_motor):
        assert theta[6 + i] == model.dof_damping[dof]
        assert theta[10 + i] == model.dof_frictionloss[dof]


def test_forearm_rods_must_be_point_masses():
    """A rod with distributed mass is not the paper's massless forearm: the truth refuses to guess."""
    heavy, _ = sim.broken_hypotheses_model(forearm_mass=0.1)
    with pytest.raises(sim.ModelError, match="point mass at its far end"):
        sim.true_parameters(heavy)


def test_true_values_near_the_papers_table_2(model):
    theta = sim.true_parameters(model)
    assert np.all((0.01 <= theta[:4]) & (theta[:4] <= 0.025))
    assert 0.8 <= theta[4] <= 1.2 and 0.001 <= theta[5] <= 0.005
    assert np.all((0.04 <= theta[6:10]) & (theta[6:10] <= 0.2))
    assert np.all((0.6 <= theta[10:]) & (theta[10:] <= 1.2))
