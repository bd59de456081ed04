"""Ground truth: the 14 parameters of the paper's model computed from the compiled MuJoCo model.

Order as ``ident.PARAMETER_NAMES`` (this module does not import ``ident``):
Imot1..4, Mnac, Ibc, Fv1..4, Fs1..4.
"""

from __future__ import annotations

import mujoco
import numpy as np

from h4bench.portable import matmul  # no BLAS: the true parameters are the same bits on any CPU
from h4bench.sim.model import FOREARM_RODS, MOTOR_JOINTS, ModelError

# a forearm rod counts as the paper's massless forearm (its mass lumped at A_i on the nacelle) when its centre
# of mass is its far end and its own inertia is below this [kg m^2] (the MJCF's 1e-12: MuJoCo needs > 0)
POINT_MASS_INERTIA = 1e-9
POINT_MASS_OFFSET = 1e-12  # [m] centre of mass to rod end

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
    return matmul(matmul(rot, np.diag(model.body_inertia[body])), rot.T)


def _rods(model) -> list[tuple[int, int]]:
    """(rod body, lateral body carrying A_i) per chain; raises unless each rod is a point mass at its far end."""
    out = []
    for i, name in enumerate(FOREARM_RODS):
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        end = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"rod_end{i + 1}")
        a = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"A{i + 1}")
        if (np.abs(model.body_ipos[body] - model.site_pos[end]).max() > POINT_MASS_OFFSET
                or model.body_inertia[body].max() > POINT_MASS_INERTIA):
            raise ModelError(f"forearm rod {name!r} must be a point mass at its far end 'rod_end{i + 1}' (the paper's "
                             f"massless forearm with its lower half lumped at A_i); got centre of mass "
                             f"{model.body_ipos[body].tolist()} and inertia {model.body_inertia[body].tolist()} - "
                             "pass the truth explicitly (e.g. sim.broken_hypotheses_model's)")
        out.append((body, model.site_bodyid[a]))
    return out


def nacelle_mass_matrix(model: mujoco.MjModel) -> np.ndarray:
    """The nacelle's 4x4 kinetic-energy matrix in (xd, yd, zd, thetad) at qpos0, lateral bars translating,
    including the forearm rods' point masses at the attachment points A_i (they move with their lateral bar).

    The paper's model holds when it is diag(Mnac, Mnac, Mnac, Ibc) (checked by a test).

    Parameters
    ----------
    model : mujoco.MjModel of the H4

    Returns
    -------
    (4, 4) kinetic-energy matrix [kg; kg m for the couplings; kg m^2 for theta]
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
        m4 += mass * matmul(jv.T, jv)
        m4[3, 3] += w_izz
    for rod, bar in _rods(model):  # a point at A_i on a translating bar moves like the bar's origin C_k
        jv = np.column_stack([np.eye(3), np.cross(z, data.xpos[bar] - origin)])
        m4 += model.body_mass[rod] * matmul(jv.T, jv)
    return m4


def true_parameters(model: mujoco.MjModel) -> np.ndarray:
    """The 14 true parameter values (SI) of the paper's model, from the compiled model.

    Imot_i = armature_i + inertia of the arm body about the motor axis (the arm's inertial lumps the upper
    half of the forearm); Mnac, Ibc from the nacelle's kinetic energy (:func:`nacelle_mass_matrix`, with the
    forearm rods' point masses at A_i);
    Fv_i = joint damping; Fs_i = joint frictionloss.

    Parameters
    ----------
    model : mujoco.MjModel of the H4

    Returns
    -------
    (14,) true parameters in the order of TRUE_PARAMETER_ORDER (SI units)
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    imot, fv, fs = [], [], []
    rods = {b for rod, _ in _rods(model) for b in _subtree_bodies(model, rod)}
    for name in MOTOR_JOINTS:
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        dof = model.jnt_dofadr[j]
        axis, anchor = data.xaxis[j], data.xanchor[j]
        inertia = 0.0
        for b in _subtree_bodies(model, model.jnt_bodyid[j]):
            if b in rods:  # counted on the nacelle (nacelle_mass_matrix)
                continue
            if model.body_jntnum[b] and b != model.jnt_bodyid[j]:
                raise ModelError(f"the arm of {name} must be a single rigid body (found a jointed child body)")
            r = data.xipos[b] - anchor
            r_perp = r - np.einsum("a,a->", r, axis) * axis
            inertia += (np.einsum("a,ab,b->", axis, _inertia_world(data, b, model), axis)
                        + model.body_mass[b] * np.einsum("a,a->", r_perp, r_perp))
        imot.append(model.dof_armature[dof] + inertia)
        fv.append(model.dof_damping[dof])
        fs.append(model.dof_frictionloss[dof])
    m4 = nacelle_mass_matrix(model)
    return np.array(imot + [m4[0, 0], m4[3, 3]] + fv + fs, dtype=float)
