"""Ground truth: the 14 parameters of the paper's model computed from the compiled MuJoCo model.

Order as ``ident.PARAMETER_NAMES`` (this module does not import ``ident``):
Imot1..4, Mnac, Ibc, Fv1..4, Fs1..4.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim.model import MOTOR_JOINTS, ModelError

TRUE_PARAMETER_ORDER = ("Imot1", "Imot2", "Imot3", "Imot4", "Mnac", "Ibc",
                        "Fv1", "Fv2", "Fv3", "Fv4", "Fs1", "Fs2", "Fs3", "Fs4")


def _subtree_bodies(model, root: int) -> list[int]:
    return [b for b in range(model.nbody) if _has_ancestor(model, b, root)]


def _has_ancestor(model, body: int, root: int) -> bool:
    while True:
        if body == root:
            return True
        if body == 0:
            return False
        body = model.body_parentid[body]


def _inertia_world(data, body: int, model) -> np.ndarray:
    rot = data.ximat[body].reshape(3, 3)
    return rot @ np.diag(model.body_inertia[body]) @ rot.T


def nacelle_mass_matrix(model: mujoco.MjModel) -> np.ndarray:
    """The nacelle's 4x4 kinetic-energy matrix in (xd, yd, zd, thetad) at qpos0, lateral bars translating.

    The paper's model holds when it is diag(Mnac, Mnac, Mnac, Ibc) (checked by a test).
    """
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    nac = model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "theta")]
    origin = data.xpos[nac]
    m4 = np.zeros((4, 4))
    z = np.array([0.0, 0.0, 1.0])
    for b in _subtree_bodies(model, nac):
        mass = model.body_mass[b]
        r = data.xipos[b] - origin
        if b == nac:  # rotates with theta: v = p_d + theta_d z x r, omega = theta_d z
            jv = np.column_stack([np.eye(3), np.cross(z, r)])
            w_izz = _inertia_world(data, b, model)[2, 2]
        else:  # lateral bars translate with their hinge point C: v = p_d + theta_d z x (C - D)
            c = data.xpos[b] - origin
            jv = np.column_stack([np.eye(3), np.cross(z, c)])
            w_izz = 0.0
        m4 += mass * jv.T @ jv
        m4[3, 3] += w_izz
    return m4


def true_parameters(model: mujoco.MjModel) -> np.ndarray:
    """The 14 true parameter values (SI) of the paper's model, from the compiled model.

    Imot_i = armature_i + inertia of the arm body about the motor axis (the arm's inertial lumps the upper
    half of the forearm); Mnac, Ibc from the nacelle's kinetic energy (:func:`nacelle_mass_matrix`);
    Fv_i = joint damping; Fs_i = joint frictionloss.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    imot, fv, fs = [], [], []
    for name in MOTOR_JOINTS:
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        dof = model.jnt_dofadr[j]
        axis, anchor = data.xaxis[j], data.xanchor[j]
        inertia = 0.0
        for b in _subtree_bodies(model, model.jnt_bodyid[j]):
            if model.body_jntnum[b] and b != model.jnt_bodyid[j]:
                raise ModelError(f"the arm of {name} must be a single rigid body (found a jointed child body)")
            r = data.xipos[b] - anchor
            r_perp = r - np.dot(r, axis) * axis
            inertia += axis @ _inertia_world(data, b, model) @ axis + model.body_mass[b] * r_perp @ r_perp
        imot.append(model.dof_armature[dof] + inertia)
        fv.append(model.dof_damping[dof])
        fs.append(model.dof_frictionloss[dof])
    m4 = nacelle_mass_matrix(model)
    return np.array(imot + [m4[0, 0], m4[3, 3]] + fv + fs, dtype=float)
