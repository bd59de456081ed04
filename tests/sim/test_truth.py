"""Ground-truth parameters against MuJoCo's own joint-space inertia matrix."""

from __future__ import annotations

import mujoco
import numpy as np

import sim
from ident import PARAMETER_NAMES


def test_order_matches_ident(model):
    assert sim.TRUE_PARAMETER_ORDER == PARAMETER_NAMES
    assert sim.true_parameters(model).shape == (14,)


def test_nacelle_kinetic_energy_is_the_papers_diagonal(model):
    m4 = sim.nacelle_mass_matrix(model)
    np.testing.assert_allclose(m4, np.diag(np.diag(m4)), atol=1e-15)
    assert m4[0, 0] == m4[1, 1] == m4[2, 2]


def test_true_parameters_against_mujoco_mass_matrix(model, geometry):
    """Oracle: MuJoCo's joint-space inertia (mj_fullM) at qpos0, reduced to the constrained motion."""
    theta = sim.true_parameters(model)
    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, d, full)
    for i, dof in enumerate(geometry.dof_motor):
        assert abs(full[dof, dof] - theta[i]) < 1e-15  # armature + arm inertia about its axis
    x, y, z, th = geometry.qpos_nacelle  # 1-dof joints: qpos address == dof address here
    for dof in (x, y, z):
        assert abs(full[dof, dof] - theta[4]) < 1e-14
    v = np.zeros(model.nv)
    v[th] = 1.0
    v[geometry.qpos_lateral] = -1.0  # the lateral bars counter-rotate (phi_k = -theta)
    assert abs(v @ full @ v - theta[5]) < 1e-15
    for i, dof in enumerate(geometry.dof_motor):
        assert theta[6 + i] == model.dof_damping[dof]
        assert theta[10 + i] == model.dof_frictionloss[dof]


def test_true_values_near_the_papers_table_2(model):
    theta = sim.true_parameters(model)
    assert np.all((0.01 <= theta[:4]) & (theta[:4] <= 0.025))
    assert 0.8 <= theta[4] <= 1.2 and 0.001 <= theta[5] <= 0.005
    assert np.all((0.04 <= theta[6:10]) & (theta[6:10] <= 0.2))
    assert np.all((0.6 <= theta[10:]) & (theta[10:] <= 1.2))
