"""The H4 inverse dynamic model linear in its parameters (paper eqs. 14-18) and its regressor.

    tau = Imot qdd + J^T M (xdd - G) + Fv qd + Fs sign(qd),   M = diag(Mnac, Mnac, Mnac, Ibc),

with ``x = FK(q)``, ``xd = J qd``, ``xdd = J qdd + Jd qd`` (eq. 19) and G the gravity vector (0, 0, -g, 0).
Written ``tau = W(q, qd, qdd) theta`` with theta in :data:`ident.PARAMETER_NAMES` order. Rows are stacked
sample k, joint i -> row ``4 k + i``.

sign(0): numpy's convention, ``sign(0) = 0``. A joint at rest contributes no Coulomb column; its torque then
depends on the unmodelled static friction, so samples with small |qd| should be excluded (see
``ident.processing.filtering``) or handled with an interval regressor ([-1, 1]).

Model structures (``structure=``):
- ``"paper"`` (default): the 14 columns above.
- ``"extended"``: 14 + 8 columns for what the paper neglects:
  ``MXa1..4``, the first moment m_a r_a [kg m] of each arm's mass about its motor axis along the arm
  (an unbalanced arm's gravity torque ``-MXa_i (g . d(e_i cos q + f_i sin q)/dq)``, i.e. ``-MXa g cos q`` here);
  ``mf1..4``, the mass [kg] of each forearm modelled as a uniform thin rod instead of two lumped halves. The
  rod's virtual power minus that of the lumped halves (which the paper's Imot and Mnac already hold) is
  ``-(m_f / 6) (A_dd - B_dd) . (dA/dq - dB/dq)``, gravity cancelling out.
"""

from __future__ import annotations

import numpy as np

from h4bench.portable import matmul

# The 14 base parameters of the H4 inverse dynamic model (paper eq. 18); the order is defined here once,
# every other module refers to PARAMETER_NAMES.
PARAMETER_NAMES: tuple[str, ...] = (
    "Imot1", "Imot2", "Imot3", "Imot4",  # motor + arm + lumped forearm inertia about the motor axis [kg m^2]
    "Mnac",  # nacelle mass [kg]
    "Ibc",  # nacelle inertia about the vertical axis through D [kg m^2]
    "Fv1", "Fv2", "Fv3", "Fv4",  # viscous friction [N m s/rad]
    "Fs1", "Fs2", "Fs3", "Fs4",  # Coulomb friction [N m]
)
PARAMETER_UNITS: tuple[str, ...] = ("kg m^2",) * 4 + ("kg", "kg m^2") + ("N m s/rad",) * 4 + ("N m",) * 4
N_PARAMETERS = len(PARAMETER_NAMES)

# What a designer knows before identification: the paper's a priori values (Table 1: Imot 0.012 kg m^2,
# Mnac 1.0 kg; Ibc taken as 0.003 kg m^2, Table 2's order, since the a priori 0.0008 ignores the lateral bars)
# and frictions of the order of its Table 2. Used for control, feed-forward and trajectory checks; never
# as a truth.
NOMINAL_PARAMETERS: tuple[float, ...] = (0.012, 0.012, 0.012, 0.012, 1.0, 0.003,
                                         0.16, 0.06, 0.09, 0.09, 1.15, 1.10, 0.72, 0.99)

EXTRA_NAMES: tuple[str, ...] = ("MXa1", "MXa2", "MXa3", "MXa4", "mf1", "mf2", "mf3", "mf4")
STRUCTURES = ("paper", "extended")


EXTRA_UNITS: tuple[str, ...] = ("kg m",) * 4 + ("kg",) * 4


def parameter_names(structure: str = "paper") -> tuple[str, ...]:
    """Column names of the regressor for a model structure."""
    _check_structure(structure)
    return PARAMETER_NAMES if structure == "paper" else PARAMETER_NAMES + EXTRA_NAMES


def parameter_units(structure: str = "paper") -> tuple[str, ...]:
    """SI units of the columns, in :func:`parameter_names` order."""
    _check_structure(structure)
    return PARAMETER_UNITS if structure == "paper" else PARAMETER_UNITS + EXTRA_UNITS


def _check_structure(structure) -> None:
    if structure not in STRUCTURES:
        raise ValueError(f"structure must be one of {STRUCTURES}, got {structure!r}")


def _states(q, qd, qdd):
    arrays = []
    for name, value in (("q", q), ("qd", qd), ("qdd", qdd)):
        arr = np.asarray(value, dtype=float)
        if arr.ndim not in (1, 2) or arr.shape[-1] != 4:
            raise ValueError(f"{name} must have shape (4,) or (n, 4), got {arr.shape}")
        arr = np.atleast_2d(arr)
        if not np.all(np.isfinite(arr)):
            bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
            raise ValueError(f"{name} must be finite, got NaN/inf at sample(s) {bad[:10].tolist()}")
        arrays.append(arr)
    n = arrays[0].shape[0]
    for name, arr in zip(("qd", "qdd"), arrays[1:]):
        if arr.shape[0] != n:
            raise ValueError(f"{name} must have the same number of samples as q ({n}), got {arr.shape[0]}")
    return arrays


def regressor(geometry, q, qd, qdd, structure: str = "paper", x=None, xdd=None) -> np.ndarray:
    """W (4n, p) such that ``tau = W @ theta`` (rows 4k + i), p = 14 (paper) or 22 (extended).

    geometry : sim.H4Geometry; q, qd, qdd : (n, 4) joint angles [rad], speeds [rad/s], accelerations
    [rad/s^2]; x : optional (n, 4) nacelle poses (computed by forward kinematics when omitted);
    xdd : optional (n, 4) measured nacelle accelerations used instead of eq. 19 (``J qdd + Jd qd``), e.g. a
    simulator's own, to separate the model from the kinematic differentiation.
    """
    from h4bench.sim.kinematics import (arm_tips, forward_kinematics, jacobian_dot_unchecked,  # noqa: PLC0415
                                jacobians_unchecked)

    _check_structure(structure)
    q, qd, qdd = _states(q, qd, qdd)
    n = q.shape[0]
    x = forward_kinematics(geometry, q) if x is None else np.atleast_2d(np.asarray(x, dtype=float))
    if x.shape != (n, 4):
        raise ValueError(f"x must have shape ({n}, 4), got {x.shape}")
    jac = jacobians_unchecked(geometry, q, x)
    jd = jacobian_dot_unchecked(geometry, jac, qd)
    xd = np.einsum("nab,nb->na", jac.J, qd)
    if xdd is None:
        xdd = np.einsum("nab,nb->na", jac.J, qdd) + np.einsum("nab,nb->na", jd, qd)
    else:
        xdd = np.atleast_2d(np.asarray(xdd, dtype=float))
        if xdd.shape != (n, 4):
            raise ValueError(f"xdd must have shape ({n}, 4), got {xdd.shape}")
    g4 = np.concatenate([geometry.gravity, [0.0]])
    p = len(parameter_names(structure))
    w = np.zeros((n, 4, p))
    eye = np.eye(4)[None]
    joint = np.arange(4)
    w[:, joint, joint] = qdd  # Imot_i qdd_i on row i
    w[..., 4] = np.einsum("naj,na->nj", jac.J[:, :3, :], xdd[:, :3] - g4[:3])  # no BLAS (h4bench.portable)
    w[..., 5] = jac.J[:, 3, :] * xdd[:, 3, None]
    w[:, joint, 6 + joint] = qd
    w[:, joint, 10 + joint] = np.sign(qd)
    if structure == "extended":
        u = geometry.motor_axis
        # arm gravity: d/dq of -MXa g . (position of the arm's centre of mass along e_i) per unit MXa
        e, f = geometry.arm_dir, np.cross(u, geometry.arm_dir)
        dpos = -np.sin(q)[..., None] * e[None] + np.cos(q)[..., None] * f[None]  # (n, 4, 3)
        w[..., 14:18] = eye * (-np.einsum("nia,a->ni", dpos, geometry.gravity))[:, :, None]
        # forearm rods: -(1/6) (A_dd - B_dd) . (dA/dq_j - dB/dq_j)
        z = np.array([0.0, 0.0, 1.0])
        pb = arm_tips(geometry, q) - geometry.motor_pos[None]
        b_dd = (np.cross(u[None], pb) * qdd[..., None]
                + np.cross(u[None], np.cross(u[None], pb)) * (qd**2)[..., None])
        dc = jac.DC
        a_dd = (xdd[:, None, :3] + np.cross(z, dc) * xdd[:, 3, None, None]
                + np.cross(z, np.cross(z, dc)) * (xd[:, 3] ** 2)[:, None, None])
        # dA_i/dq_j = (J[:3, j] + J[3, j] z x DC_i); dB_i/dq_j = delta_ij u_i x PB_i
        da = jac.J[:, None, :3, :] + np.cross(z, dc)[..., None] * jac.J[:, None, 3, None, :]  # (n, i, 3, j)
        db = np.cross(u[None], pb)[..., None] * eye[:, :, None, :]  # (n, i, 3, j)
        w[..., 18:22] = -(1.0 / 6.0) * np.einsum("nia,niaj->nji", a_dd - b_dd, da - db)
    return w.reshape(4 * n, p)


def inverse_dynamics(geometry, theta, q, qd, qdd, structure: str = "paper", x=None, xdd=None) -> np.ndarray:
    """Motor torques (n, 4) [N m] = W(q, qd, qdd) theta (the paper's model; toppra-compatible form)."""
    theta = np.asarray(theta, dtype=float).reshape(-1)
    p = len(parameter_names(structure))
    if theta.shape != (p,):
        raise ValueError(f"theta must have shape ({p},) for structure {structure!r}, got {theta.shape}")
    w = regressor(geometry, q, qd, qdd, structure=structure, x=x, xdd=xdd)
    tau = matmul(w, theta).reshape(-1, 4)
    return tau[0] if np.ndim(q) == 1 else tau
