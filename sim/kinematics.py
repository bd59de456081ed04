"""H4 kinematics (paper section 2.1): closed-form inverse kinematics, iterative forward kinematics (eq. 10),
the Jacobians Jx, Jq and J = Jx^-1 Jq (eqs. 11-13), J-dot and a singularity measure. All vectorised.

Conventions: ``x = (x, y, z, theta)`` is the nacelle pose in the world frame (D's position [m] and the
central bar's rotation about the vertical [rad]); ``q`` are the 4 motor angles [rad] in MuJoCo's convention
(q = 0 arm horizontal pointing outward, q > 0 lowers the arm tip). Functions accept ``(4,)`` or ``(n, 4)``
and return the matching shape.

Loop closure of chain i: ``|B_i(q_i) - A_i(x)| = l_i``. Differentiating gives ``Jx xd = Jq qd`` with rows
``Jx_i = [AB_i^T, (DC_i x AB_i)_z]`` (AB_i = B_i - A_i, DC_i = Rz(theta) bar_offset_i) and
``Jq = diag(u_i . (P_iB_i x AB_i))``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench.portable import arccos, atan2, matmul, solve4
from h4bench.sim.model import H4Geometry, arm_tips, nacelle_points  # the chain points live with the geometry


class KinematicsError(ValueError):
    """A pose is outside the workspace, singular, or the forward kinematics did not converge."""


def _as_samples(name: str, value, width: int = 4) -> tuple[np.ndarray, bool]:
    arr = np.asarray(value, dtype=float)
    if arr.ndim not in (1, 2) or arr.shape[-1] != width:
        raise ValueError(f"{name} must have shape ({width},) or (n, {width}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.all(np.isfinite(np.atleast_2d(arr)), axis=1))
        raise ValueError(f"{name} must be finite, got NaN/inf at sample(s) {bad[:10].tolist()}")
    return np.atleast_2d(arr), arr.ndim == 1


def _check_geometry(geometry) -> None:
    if not isinstance(geometry, H4Geometry):
        raise TypeError(f"geometry must be an sim.H4Geometry, got {type(geometry).__name__}")


def _ik(geometry: H4Geometry, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unchecked IK: q (n, 4) and the ratio c/rho (n, 4) whose |.| > 1 means unreachable."""
    a_pts, _ = nacelle_points(geometry, x)
    w = a_pts - geometry.motor_pos[None]  # P_i -> A_i
    e, f = geometry.arm_dir, np.cross(geometry.motor_axis, geometry.arm_dir)
    a = np.einsum("nia,ia->ni", w, e)
    b = np.einsum("nia,ia->ni", w, f)
    L, l = geometry.arm_length, geometry.forearm_length
    c = (L**2 + np.einsum("nia,nia->ni", w, w) - l**2) / (2.0 * L)
    rho = np.hypot(a, b)
    ratio = c / rho
    q = atan2(b, a) - arccos(np.clip(ratio, -1.0, 1.0))
    q = (q + np.pi) % (2.0 * np.pi) - np.pi
    return q, ratio


def inverse_kinematics(geometry: H4Geometry, x) -> np.ndarray:
    """Motor angles q [rad] for nacelle poses x = (x, y, z, theta), closed form per chain.

    Chain i: ``cos q a_i + sin q b_i = c_i`` with a_i, b_i the components of P_iA_i along e_i and u_i x e_i and
    ``c_i = (L^2 + |P_iA_i|^2 - l^2) / 2L``. Of the two solutions we take ``q = atan2(b, a) - acos(c / rho)``:
    the 'elbow out' branch, whose arm tip stays outward of the forearm (q = 0 at the home pose). Raises
    :class:`KinematicsError` naming the samples and chains a forearm cannot reach (|c/rho| > 1).

    Parameters
    ----------
    geometry : H4Geometry
    x : (n, 4) or (4,) nacelle poses (x, y, z [m], theta [rad])

    Returns
    -------
    (n, 4) or (4,) motor angles q [rad] (the shape of x)
    """
    _check_geometry(geometry)
    x2, single = _as_samples("x", x)
    q, ratio = _ik(geometry, x2)
    bad = np.abs(ratio) > 1.0
    if bad.any():
        k, i = np.argwhere(bad)[0]
        raise KinematicsError(
            f"x is outside the workspace: sample {k} (x = {x2[k].tolist()}) is out of reach of chain {i + 1} "
            f"(|c/rho| = {abs(ratio[k, i]):.4g} > 1); {int(bad.any(axis=1).sum())} sample(s) unreachable"
        )
    return q[0] if single else q


@dataclass(frozen=True)
class Jacobians:
    """Kinematic matrices at n samples: Jx (n, 4, 4), Jq (n, 4) (diagonal), J = Jx^-1 Jq (n, 4, 4),
    the forearm vectors AB (n, 4, 3) = B_i - A_i, PB (n, 4, 3) = B_i - P_i and DC (n, 4, 3)."""

    Jx: np.ndarray
    Jq: np.ndarray
    J: np.ndarray
    AB: np.ndarray
    PB: np.ndarray
    DC: np.ndarray


def _jx_jq(geometry: H4Geometry, q: np.ndarray, x: np.ndarray):
    """Jx (n, 4, 4), Jq (n, 4) and the vectors AB, PB, DC (n, 4, 3) of eqs. 11-12."""
    b_pts = arm_tips(geometry, q)
    a_pts, dc = nacelle_points(geometry, x)
    ab = b_pts - a_pts
    pb = b_pts - geometry.motor_pos[None]
    jx = np.empty(q.shape[:1] + (4, 4))
    jx[..., :3] = ab
    jx[..., 3] = dc[..., 0] * ab[..., 1] - dc[..., 1] * ab[..., 0]
    jq = np.einsum("ia,nia->ni", geometry.motor_axis, np.cross(pb, ab))
    return jx, jq, ab, pb, dc


def _jacobians(geometry: H4Geometry, q: np.ndarray, x: np.ndarray) -> Jacobians:
    jx, jq, ab, pb, dc = _jx_jq(geometry, q, x)
    j = solve4(jx, jq[:, :, None] * np.eye(4)[None])  # no LAPACK: the same bits on any CPU (h4bench.portable)
    return Jacobians(Jx=jx, Jq=jq, J=j, AB=ab, PB=pb, DC=dc)


def jacobians(geometry: H4Geometry, q, x=None) -> Jacobians:
    """Jx, Jq and J at motor angles q (n, 4); x (n, 4) is computed by forward kinematics when omitted.

    Parameters
    ----------
    geometry : H4Geometry
    q : (n, 4) motor angles [rad]
    x : (n, 4) nacelle poses (x, y, z [m], theta [rad]), or None (forward kinematics of q)

    Returns
    -------
    Jacobians
        Jx (n, 4, 4), Jq (n, 4) and J = Jx^-1 diag(Jq) (n, 4, 4), ``xd = J qd``.
    """
    _check_geometry(geometry)
    q2, single = _as_samples("q", q)
    x2 = np.atleast_2d(forward_kinematics(geometry, q2)) if x is None else _as_samples("x", x)[0]
    if x2.shape != q2.shape:
        raise ValueError(f"x must have the shape of q {q2.shape}, got {x2.shape}")
    out = _jacobians(geometry, q2, x2)
    if single:
        out = Jacobians(*(np.asarray(getattr(out, f))[0] for f in Jacobians.__dataclass_fields__))
    return out


def forward_kinematics(geometry: H4Geometry, q, x0=None, tol: float = 1e-13, max_iter: int = 50) -> np.ndarray:
    """Nacelle pose x for motor angles q by the paper's iteration (eq. 10): ``x <- x + J(x, q_n) (q - q_n)``,
    ``q_n = IK(x)``, started at ``x0`` (default: the home pose), vectorised over samples.

    Converged when ``max |q - q_n| <= tol`` [rad] for every sample; a step that leaves the workspace is halved.
    Raises :class:`KinematicsError` naming the samples that did not converge in ``max_iter`` iterations
    (singular or unreachable motor angles).

    Parameters
    ----------
    geometry : H4Geometry
    q : (n, 4) or (4,) motor angles [rad]
    x0 : start pose(s) (4,) or (n, 4), or None (the home pose)
    tol : convergence tolerance on the motor angles [rad]
    max_iter : iteration limit

    Returns
    -------
    (n, 4) or (4,) nacelle poses (x, y, z [m], theta [rad]) (the shape of q)
    """
    _check_geometry(geometry)
    q2, single = _as_samples("q", q)
    n = q2.shape[0]
    if x0 is None:
        # start from the home pose's linearisation x_home + J_home (q - q_home), or from home where that
        # first guess is out of reach
        home = geometry.x_home[None]
        q_home = _ik(geometry, home)[0]
        x = home + matmul(q2 - q_home, _jacobians(geometry, q_home, home).J[0].T)
        out_of_reach = ~np.all(np.abs(_ik(geometry, x)[1]) <= 1.0, axis=1)
        x[out_of_reach] = geometry.x_home
    else:
        x = np.array(np.broadcast_to(_as_samples("x0", x0)[0], (n, 4)))
    qn, ratio = _ik(geometry, x)
    if np.any(np.abs(ratio) > 1.0):
        raise KinematicsError("x0 must be inside the workspace (every chain in reach)")
    active = np.ones(n, dtype=bool)
    for _ in range(max_iter):
        err = q2 - qn
        active = np.max(np.abs(err), axis=1) > tol
        if not active.any():
            break
        idx = np.flatnonzero(active)
        jx, jq = _jx_jq(geometry, qn[idx], x[idx])[:2]
        step = solve4(jx, jq * err[idx])  # J (q - q_n) = Jx^-1 Jq (q - q_n)
        scale = np.ones(idx.size)
        for _halving in range(30):
            trial = x[idx] + scale[:, None] * step
            q_trial, ratio = _ik(geometry, trial)
            ok = np.all(np.abs(ratio) <= 1.0, axis=1) & np.all(np.isfinite(q_trial), axis=1)
            if ok.all():
                break
            scale[~ok] *= 0.5
        x[idx] = trial
        qn[idx] = q_trial
    else:
        active = np.max(np.abs(q2 - qn), axis=1) > tol
    if active.any():
        bad = np.flatnonzero(active)
        raise KinematicsError(
            f"forward kinematics did not converge for q at sample(s) {bad[:10].tolist()} "
            f"(max |q - IK(x)| = {np.max(np.abs(q2 - qn)[bad]):.3g} rad after {max_iter} iterations): "
            "singular or unreachable motor angles"
        )
    return x[0] if single else x


def jacobian_dot(geometry: H4Geometry, q, qd, x=None) -> np.ndarray:
    """Time derivative of J (n, 4, 4) along the motion (q, qd).

    From ``Jx J = diag(Jq)``: ``Jd = Jx^-1 (diag(Jqd) - Jxd J)``, with Jxd and Jqd the analytic derivatives
    of the rows of eq. 11 and eq. 12 (AB_d = u x PB qd - (pd + thetad z x DC), DC_d = thetad z x DC).

    Parameters
    ----------
    geometry : H4Geometry
    q : (n, 4) motor angles [rad]
    qd : (n, 4) motor velocities [rad/s]
    x : (n, 4) nacelle poses, or None (forward kinematics of q)

    Returns
    -------
    (n, 4, 4) dJ/dt [m/rad/s for the rows x, y, z; 1/s for theta]
    """
    _check_geometry(geometry)
    q2, single = _as_samples("q", q)
    qd2, _ = _as_samples("qd", qd)
    if qd2.shape != q2.shape:
        raise ValueError(f"qd must have the shape of q {q2.shape}, got {qd2.shape}")
    x2 = np.atleast_2d(forward_kinematics(geometry, q2)) if x is None else _as_samples("x", x)[0]
    jac = _jacobians(geometry, q2, x2)
    jd = _jacobian_dot(geometry, jac, qd2)
    return jd[0] if single else jd


def _jacobian_dot(geometry: H4Geometry, jac: Jacobians, qd: np.ndarray) -> np.ndarray:
    xd = np.einsum("nab,nb->na", jac.J, qd)
    z = np.array([0.0, 0.0, 1.0])
    bd = np.cross(geometry.motor_axis[None], jac.PB) * qd[..., None]  # B_i velocity
    dcd = np.cross(z, jac.DC) * xd[:, 3, None, None]
    abd = bd - xd[:, None, :3] - dcd
    jxd = np.empty_like(jac.Jx)
    jxd[..., :3] = abd
    jxd[..., 3] = (dcd[..., 0] * jac.AB[..., 1] + jac.DC[..., 0] * abd[..., 1]
                   - dcd[..., 1] * jac.AB[..., 0] - jac.DC[..., 1] * abd[..., 0])
    jqd = np.einsum("ia,nia->ni", geometry.motor_axis, np.cross(bd, jac.AB) + np.cross(jac.PB, abd))
    rhs = jqd[:, :, None] * np.eye(4)[None] - matmul(jxd, jac.J)
    return solve4(jac.Jx, rhs)


def cartesian_motion(geometry: H4Geometry, q, qd, qdd, x=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nacelle pose, velocity and acceleration (each (n, 4)): x = FK(q), xd = J qd, xdd = J qdd + Jd qd.

    Parameters
    ----------
    geometry : H4Geometry
    q, qd, qdd : (n, 4) motor angles [rad], velocities [rad/s], accelerations [rad/s^2]
    x : (n, 4) nacelle poses, or None (forward kinematics of q)

    Returns
    -------
    (x, xd, xdd) : each (n, 4), pose (x, y, z [m], theta [rad]) and its first and second time derivatives
    """
    _check_geometry(geometry)
    q2, single = _as_samples("q", q)
    qd2, _ = _as_samples("qd", qd)
    qdd2, _ = _as_samples("qdd", qdd)
    for name, arr in (("qd", qd2), ("qdd", qdd2)):
        if arr.shape != q2.shape:
            raise ValueError(f"{name} must have the shape of q {q2.shape}, got {arr.shape}")
    x2 = np.atleast_2d(forward_kinematics(geometry, q2)) if x is None else _as_samples("x", x)[0]
    jac = _jacobians(geometry, q2, x2)
    jd = _jacobian_dot(geometry, jac, qd2)
    xd = np.einsum("nab,nb->na", jac.J, qd2)
    xdd = np.einsum("nab,nb->na", jac.J, qdd2) + np.einsum("nab,nb->na", jd, qd2)
    if single:
        return x2[0], xd[0], xdd[0]
    return x2, xd, xdd


def singularity_measure(geometry: H4Geometry, x) -> np.ndarray:
    """cond(Jx) (2-norm) at poses x: (n,) or scalar. Large values mean close to a singularity.

    Parameters
    ----------
    geometry : H4Geometry
    x : (n, 4) or (4,) nacelle poses (x, y, z [m], theta [rad])

    Returns
    -------
    (n,) or float condition number of Jx (>= 1)
    """
    _check_geometry(geometry)
    x2, single = _as_samples("x", x)
    q, ratio = _ik(geometry, x2)
    if np.any(np.abs(ratio) > 1.0):
        inverse_kinematics(geometry, x2)  # raises with the details
    c = np.linalg.cond(_jacobians(geometry, q, x2).Jx)
    return c[0] if single else c


# Public names of the unchecked, vectorised cores, for callers that validate their inputs once (the regressor,
# trajectory design and checks): no re-validation, no exception on an unreachable pose (its reach ratio > 1).
ik_unchecked = _ik
jacobians_unchecked = _jacobians
jacobian_dot_unchecked = _jacobian_dot
