"""Inverse-dynamics regressor of a serial robot read from a URDF (pinocchio), and its base parameters.

A second provider of ``(W, y, bound)`` for the robot-agnostic estimators of :mod:`ident` (the first is the H4's
:mod:`ident.robots.h4`). For ``n_joints`` actuated joints the torque model is linear in the standard parameters:

    tau_i = Y_i(q, qd, qdd) . pi  +  fv_i qd_i + fs_i sign(qd_i) + Ia_i qdd_i + off_i   (+ coupled-wrist terms)

* ``pi``: the 10 standard inertial parameters of every moving link, in pinocchio's order
  ``m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz`` (mass [kg], first moment ``m c`` [kg m], inertia about the
  JOINT frame origin in the joint frame [kg m^2]); ``Y`` is ``pinocchio.computeJointTorqueRegressor``.
* per joint: viscous ``fv`` [N m s/rad], Coulomb ``fs`` [N m], actuator (rotor) inertia reflected to the
  joint ``Ia`` [kg m^2], torque offset ``off`` [N m] (current-sensor offset, gravity of unmodelled cables).
* coupled wrist (``coupled_wrist=(a, b)``, 0-based joints): the motor of joint b also turns with joint a, so
  its motor angle is ``r_b (q_a + q_b)`` (the Staubli TX40: a = 4, b = 5). The motor's rotor inertia, viscous
  and Coulomb friction act on ``qd_a + qd_b`` and, by the power balance ``tau_joint = R^T tau_motor``, load
  rows a and b equally: columns ``Iam`` (``qdd_a + qdd_b``), ``fvm`` (``qd_a + qd_b``) and ``fsm``
  (``sign(qd_a + qd_b)``) on both rows, all reflected to the joint side (multiplied by ``r_b^2`` resp.
  ``r_b``). The FIGAROH TX40 example puts ``qdd_b`` on row a and ``qdd_a`` on row b instead (and likewise
  for the viscous term); the two column sets span the same space (its ``Ia_a`` is ours plus ``Iam``), so
  torques and base-parameter fits agree; ours keeps every extra parameter a non-negative physical quantity.

Rows are stacked sample k, joint i -> row ``n_joints * k + i``, as everywhere in :mod:`ident`.

Base parameters (Gautier 1990; Khalil & Dombre, ch. 12). Some standard parameters have no effect on the
torques and others act only in fixed linear combinations. From the stacked regressor ``W`` at random states
(positions uniform within the joint limits, velocities and accelerations Gaussian), a QR decomposition with
column pivoting ``W P = Q R`` gives the numerical rank r (``|R_jj| > tol |R_00|``) and r independent
columns ``I``; every other column is ``W_D = W_I beta`` (least squares; exactly, up to rounding, for a
structural dependence). The base parameters are ``theta_b = theta_I + beta theta_D = B theta`` with the
``(r, p)`` matrix ``B`` (:attr:`BaseParameters.matrix`), and ``W theta = W_I theta_b`` for every theta.
pinocchio is imported lazily: importing this module does not need it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.validation import as_float_array, check_finite
from h4bench.portable import lstsq, matmul, qr_pivoted

__all__ = ["INERTIAL_NAMES", "BaseParameters", "SerialRobot", "base_parameters", "default_reach", "norm3",
           "physical_prior"]

INERTIAL_NAMES = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")  # pinocchio's order
_INERTIAL_UNITS = ("kg", "kg m", "kg m", "kg m") + ("kg m^2",) * 6
_EXTRA_UNITS = {"fv": "N m s/rad", "fs": "N m", "Ia": "kg m^2", "off": "N m",
                "Iam": "kg m^2", "fvm": "N m s/rad", "fsm": "N m"}


def _pinocchio():
    try:
        import pinocchio
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("h4bench.ident.robots.serial needs pinocchio: pip install pin") from exc
    return pinocchio


def _states(x, name: str, n_joints: int) -> np.ndarray:
    arr = as_float_array(x, name)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != n_joints:
        raise ValueError(f"{name} must have shape (n, {n_joints}) (or ({n_joints},)), got {np.shape(x)}")
    check_finite(arr, name)
    return arr


@dataclass(frozen=True)
class BaseParameters:
    """Base (identifiable) parameters as linear combinations of the standard ones.

    independent : (r,) standard columns kept (ascending); dependent : (p - r,) the others; beta : (r, p - r)
    with ``W[:, dependent] = W[:, independent] @ beta``; matrix : (r, p) ``B`` with ``theta_b = B theta``
    (``B[:, independent] = I``, ``B[:, dependent] = beta``); names : (r,) short names (the kept standard
    parameter's name, with ``'`` when it absorbs others); expressions : (r,) the combination as text;
    standard_names : (p,) ; rank_tolerance, singular_gap : the QR's relative threshold and the ratio of the
    last kept ``|R_jj|`` to the first dropped one (a large gap means a clear numerical rank).
    """

    independent: np.ndarray
    dependent: np.ndarray
    beta: np.ndarray
    matrix: np.ndarray
    names: tuple[str, ...]
    expressions: tuple[str, ...]
    standard_names: tuple[str, ...]
    units: tuple[str, ...]
    rank_tolerance: float
    singular_gap: float
    info: dict = field(default_factory=dict, compare=False, repr=False)

    def __len__(self) -> int:
        return self.independent.size

    def from_standard(self, theta) -> np.ndarray:
        """(r,) base parameters ``B theta`` of standard parameters theta (p,) (or (..., p) -> (..., r))."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape[-1] != self.matrix.shape[1]:
            raise ValueError(f"theta must have {self.matrix.shape[1]} standard parameters (last axis), got "
                             f"shape {theta.shape}")
        return matmul(theta, self.matrix.T)

    def regressor(self, W) -> np.ndarray:
        """(m, r) base regressor: the independent columns of a standard regressor W (m, p)."""
        W = np.asarray(W, dtype=float)
        if W.ndim != 2 or W.shape[1] != self.matrix.shape[1]:
            raise ValueError(f"W must have shape (m, {self.matrix.shape[1]}), got {W.shape}")
        return W[:, self.independent]

    def box_from_standard(self, lower, upper) -> tuple[np.ndarray, np.ndarray]:
        """Hull of ``{B theta : lower <= theta <= upper}`` (exact for a linear map: mid +- |B| rad), rounded out."""
        lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        p = self.matrix.shape[1]
        if lower.shape != (p,) or upper.shape != (p,) or np.any(lower > upper):
            raise ValueError(f"lower, upper must be (p,) = ({p},) with lower <= upper, got {lower.shape}, {upper.shape}")
        mid, rad = 0.5 * (lower + upper), 0.5 * (upper - lower)
        c, r = matmul(self.matrix, mid), matmul(np.abs(self.matrix), rad)
        big = np.maximum(np.abs(lower), np.abs(upper))
        slack = 4.0 * p * np.finfo(float).eps * matmul(np.abs(self.matrix), big)
        return np.nextafter(c - r - slack, -np.inf), np.nextafter(c + r + slack, np.inf)


def norm3(v) -> float:
    """The Euclidean norm of a short vector without BLAS (its dot product's kernel differs by CPU)."""
    v = np.asarray(v, dtype=float)
    return float(np.sqrt(np.einsum("i,i->", v, v)))


def _expression(i_col: int, dep: np.ndarray, row: np.ndarray, names) -> str:
    terms = [names[i_col]]
    for j, c in zip(dep, row):
        if c != 0.0:
            terms.append(f"{'+' if c > 0 else '-'} {abs(c):.6g} {names[j]}")
    return " ".join(terms)


def base_parameters(W, names, units=None, *, tol: float = 1e-8, clean: float = 1e-10) -> BaseParameters:
    """Base parameters from a stacked standard regressor W (m, p) at generic states (module docstring).

    names : (p,) standard names; units : (p,) or None; tol : rank threshold relative to ``|R_00|`` of the
    column-pivoted QR; clean : coefficients of beta below ``clean`` (relative to the largest entry of its row
    and to 1) are set to 0 (rounding residue of exact structural dependences).
    """
    W = np.asarray(W, dtype=float)
    if W.ndim != 2 or W.shape[0] < W.shape[1]:
        raise ValueError(f"W must have shape (m, p) with m >= p (enough random states), got {W.shape}")
    names = tuple(names)
    p = W.shape[1]
    if len(names) != p:
        raise ValueError(f"names must have {p} entries to match W's columns, got {len(names)}")
    units = tuple(units) if units is not None else ("",) * p
    # no LAPACK/BLAS (h4bench.portable): the base, its matrix and the prior it maps are the same bits on any CPU
    # and thread count, and equal columns are ordered by name, not by rounding
    d, piv = qr_pivoted(W)
    if d[0] == 0.0:
        raise ValueError("W is zero: no parameter affects the torques")
    r = int(np.sum(d > tol * d[0]))
    gap = float(d[r - 1] / d[r]) if r < p and d[r] > 0 else math.inf
    independent = np.sort(piv[:r])
    dependent = np.sort(piv[r:])
    WI = W[:, independent]
    beta = (lstsq(WI, W[:, dependent], rcond=float(np.finfo(float).eps * max(W.shape))) if dependent.size
            else np.zeros((r, 0)))
    scale = np.maximum(np.abs(beta).max(axis=1, keepdims=True, initial=0.0), 1.0)
    beta = np.where(np.abs(beta) < clean * scale, 0.0, beta)
    B = np.zeros((r, p))
    B[np.arange(r), independent] = 1.0
    B[:, dependent] = beta
    resid = float(np.max(np.abs(W[:, dependent] - matmul(WI, beta)), initial=0.0)) / float(np.max(np.abs(W)))
    base_names = tuple(names[i] + ("'" if np.any(beta[k]) else "") for k, i in enumerate(independent))
    expr = tuple(_expression(i, dependent, beta[k], names) for k, i in enumerate(independent))
    return BaseParameters(independent=independent, dependent=dependent, beta=beta, matrix=B, names=base_names,
                          expressions=expr, standard_names=names, units=tuple(units[i] for i in independent),
                          rank_tolerance=tol, singular_gap=gap, info={"relative_residual": resid})


class SerialRobot:
    """Standard-parameter regressor of a serial robot from a URDF (pinocchio), with friction, rotor inertia,
    torque offsets and an optional coupled wrist (module docstring).

    urdf : path to the URDF; friction, rotor_inertia, offset : include the per-joint ``fv, fs``, ``Ia``, ``off``
    columns; coupled_wrist : None or a pair (a, b) of 0-based joints (motor of b turns with a).
    The model must have one degree of freedom per joint (revolute or prismatic; nq == nv).

    Attributes: n_joints, joint_names, names (p,), units (p,), n_inertial (= 10 n_joints).
    """

    def __init__(self, urdf: str | os.PathLike, *, friction: bool = True, rotor_inertia: bool = True,
                 offset: bool = True, coupled_wrist: tuple[int, int] | None = None) -> None:
        pin = _pinocchio()
        if not isinstance(urdf, (str, os.PathLike)):
            raise TypeError(f"urdf must be a path, got {type(urdf).__name__}")
        if not os.path.isfile(urdf):
            raise ValueError(f"urdf must be an existing file, got {os.fspath(urdf)!r}")
        self.model = pin.buildModelFromUrdf(os.fspath(urdf))
        self.data = self.model.createData()
        nj = self.model.njoints - 1
        if self.model.nq != nj or self.model.nv != nj:
            raise ValueError(f"urdf must describe a serial chain of 1-dof joints (nq == nv == joints), got nq = "
                             f"{self.model.nq}, nv = {self.model.nv}, {nj} joints")
        self.n_joints = nj
        self.joint_names = tuple(self.model.names[i] for i in range(1, nj + 1))
        self.friction, self.rotor_inertia, self.offset = bool(friction), bool(rotor_inertia), bool(offset)
        if coupled_wrist is not None:
            a, b = (int(v) for v in coupled_wrist)
            if not (0 <= a < nj and 0 <= b < nj and a != b):
                raise ValueError(f"coupled_wrist must be two distinct joints in [0, {nj}), got {coupled_wrist!r}")
            coupled_wrist = (a, b)
        self.coupled_wrist = coupled_wrist
        names, units = [], []
        for i in range(nj):
            names += [f"{n}{i + 1}" for n in INERTIAL_NAMES]
            units += list(_INERTIAL_UNITS)
        self.n_inertial = len(names)
        self._extras = [k for k, on in (("fv", friction), ("fs", friction), ("Ia", rotor_inertia), ("off", offset))
                        if on]
        for k in self._extras:
            names += [f"{k}{i + 1}" for i in range(nj)]
            units += [_EXTRA_UNITS[k]] * nj
        if coupled_wrist is not None:
            b = coupled_wrist[1] + 1
            names += [f"Iam{b}", f"fvm{b}", f"fsm{b}"]
            units += [_EXTRA_UNITS["Iam"], _EXTRA_UNITS["fvm"], _EXTRA_UNITS["fsm"]]
        self.names: tuple[str, ...] = tuple(names)
        self.units: tuple[str, ...] = tuple(units)

    # ------------------------------------------------------------------------------------------ regressor
    @property
    def n_parameters(self) -> int:
        return len(self.names)

    def inertial_regressor(self, q, qd, qdd) -> np.ndarray:
        """(n_joints n, 10 n_joints) ``computeJointTorqueRegressor`` stacked sample-major. q, qd, qdd : (n, nj)."""
        pin = _pinocchio()
        nj = self.n_joints
        q, qd, qdd = (_states(x, nm, nj) for x, nm in ((q, "q"), (qd, "qd"), (qdd, "qdd")))
        if not (q.shape == qd.shape == qdd.shape):
            raise ValueError(f"q, qd, qdd must have the same shape, got {q.shape}, {qd.shape}, {qdd.shape}")
        n = q.shape[0]
        out = np.empty((n, nj, 10 * nj))
        m, d = self.model, self.data
        for k in range(n):
            out[k] = pin.computeJointTorqueRegressor(m, d, q[k], qd[k], qdd[k])
        return out.reshape(n * nj, 10 * nj)

    def extra_columns(self, qd, qdd) -> np.ndarray:
        """(n_joints n, p - 10 n_joints) the friction, rotor-inertia, offset and coupled-wrist columns."""
        nj = self.n_joints
        qd, qdd = _states(qd, "qd", nj), _states(qdd, "qdd", nj)
        if qd.shape != qdd.shape:
            raise ValueError(f"qd, qdd must have the same shape, got {qd.shape}, {qdd.shape}")
        n = qd.shape[0]
        blocks = {"fv": qd, "fs": np.sign(qd), "Ia": qdd, "off": np.ones_like(qd)}
        cols = []
        eye = np.eye(nj)
        for k in self._extras:
            cols.append(blocks[k][:, :, None] * eye[None, :, :])  # (n, nj rows, nj cols): diagonal per sample
        if self.coupled_wrist is not None:
            a, b = self.coupled_wrist
            c = np.zeros((n, nj, 3))
            for row in (a, b):
                c[:, row, 0] = qdd[:, a] + qdd[:, b]
                c[:, row, 1] = qd[:, a] + qd[:, b]
                c[:, row, 2] = np.sign(qd[:, a] + qd[:, b])
            cols.append(c)
        if not cols:
            return np.zeros((n * nj, 0))
        return np.concatenate(cols, axis=2).reshape(n * nj, -1)

    def regressor(self, q, qd, qdd, columns=None) -> np.ndarray:
        """(n_joints n, p) standard regressor, rows ``n_joints k + i``; ``columns`` (indices) selects some
        columns (e.g. :attr:`BaseParameters.independent`) without holding the full matrix."""
        W = np.concatenate([self.inertial_regressor(q, qd, qdd), self.extra_columns(qd, qdd)], axis=1)
        return W if columns is None else W[:, np.asarray(columns)]

    # ------------------------------------------------------------------------------------------ parameters
    def urdf_parameters(self, extras: dict | None = None) -> np.ndarray:
        """(p,) standard parameters: the URDF's inertias (pinocchio ``toDynamicParameters``) and the extras.

        extras : {prefix: value or (n_joints,) values} for ``fv, fs, Ia, off`` and scalars for ``Iam, fvm,
        fsm``; missing ones are 0.
        """
        extras = dict(extras or {})
        theta = np.zeros(self.n_parameters)
        for i in range(self.n_joints):
            theta[10 * i: 10 * i + 10] = self.model.inertias[i + 1].toDynamicParameters()
        col = self.n_inertial
        for k in self._extras:
            theta[col: col + self.n_joints] = np.broadcast_to(np.asarray(extras.pop(k, 0.0), float), (self.n_joints,))
            col += self.n_joints
        if self.coupled_wrist is not None:
            for k in ("Iam", "fvm", "fsm"):
                theta[col] = float(extras.pop(k, 0.0))
                col += 1
        if extras:
            raise ValueError(f"extras has unknown keys {sorted(extras)}; expected some of {self._extras} "
                             f"{'+ Iam, fvm, fsm' if self.coupled_wrist else ''}")
        return theta

    def random_states(self, n: int, seed: int = 0, speed: float = 1.0, accel: float = 5.0):
        """n random states (q uniform within the URDF limits, clipped to +-pi; qd ~ N(0, speed^2) [rad/s],
        qdd ~ N(0, accel^2) [rad/s^2]); returns (q, qd, qdd), each (n, n_joints)."""
        rng = np.random.default_rng(seed)
        lo = np.maximum(np.asarray(self.model.lowerPositionLimit), -np.pi)
        hi = np.minimum(np.asarray(self.model.upperPositionLimit), np.pi)
        lo = np.where(hi > lo, lo, -np.pi)
        hi = np.where(hi > lo, hi, np.pi)
        q = rng.uniform(lo, hi, size=(n, self.n_joints))
        return q, rng.normal(0, speed, (n, self.n_joints)), rng.normal(0, accel, (n, self.n_joints))

    def base(self, n_samples: int = 200, seed: int = 0, tol: float = 1e-8) -> BaseParameters:
        """Base parameters by QR with column pivoting on ``n_samples`` random states (module docstring)."""
        if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) or n_samples < 1:
            raise ValueError(f"n_samples must be an integer >= 1, got {n_samples!r}")
        q, qd, qdd = self.random_states(int(n_samples), seed)
        return base_parameters(self.regressor(q, qd, qdd), self.names, self.units, tol=tol)



# ------------------------------------------------------------------------------------------------- prior
def parameter_joint(name: str) -> tuple[str, int]:
    """A standard parameter's kind and 0-based joint (or link) index: ``"Izz3"`` -> ``("Izz", 2)``,
    ``"fsm6"`` -> ``("fsm", 5)``. ValueError for a name without a trailing joint number."""
    prefix = name.rstrip("0123456789")
    if prefix == name or not prefix:
        raise ValueError(f"name must be a parameter kind followed by its joint number (e.g. 'fv2'), got {name!r}")
    return prefix, int(name[len(prefix):]) - 1


def physical_prior(robot: SerialRobot, total_mass: float, reach: float, *, rotor_inertia_max: float | None = None,
                   ratios=None, offset_fraction: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """A physically meaningful, wide prior box on a serial robot's standard parameters: (lower (p,), upper (p,)).

    total_mass M [kg] bounds every link's mass, reach r [m] the distance of any of its points from its joint
    origin. Every link: ``0 <= m_i <= M``; its centre of mass lies within r of its joint origin, so ``|m c| <=
    M r``; the inertia about the joint origin of a body within radius r obeys ``0 <= I_aa <= M r^2`` and
    ``|I_ab| <= M r^2 / 2`` (``|ab| <= (a^2 + b^2)/2``). Joint i, with the URDF's effort limit ``E_i`` [N m]
    and velocity limit ``V_i`` [rad/s]: Coulomb ``0 <= fs_i <= E_i``, viscous ``0 <= fv_i <= E_i / V_i``
    (friction cannot exceed what the drive delivers at full speed), rotor inertia reflected to the joint
    ``0 <= Ia_i <= J k_i^2`` with J = ``rotor_inertia_max`` [kg m^2] (motor side) and ``k_i = |ratios[i]|``
    (reduction ratio; ``ratios=None``: all 1, J is then a joint-side bound; ``rotor_inertia_max=None``: J =
    ``M r^2``, the links' own inertia bound), offset ``|off_i| <= offset_fraction E_i`` (a larger
    current-sensor offset would be a drive fault). Coupled wrist motor of joint b: ``Iam <= J k_b^2``,
    ``fvm <= E_b / V_b``, ``fsm <= E_b``. Wide on purpose: it only excludes the unphysical.
    Raises ValueError for non-positive M, r, J, a negative offset_fraction, ratios of the wrong length or
    non-positive effort or velocity limits a friction or offset bound needs.
    """
    M = _positive(total_mass, "total_mass")
    r = _positive(reach, "reach")
    J = M * r * r if rotor_inertia_max is None else _positive(rotor_inertia_max, "rotor_inertia_max")
    frac = float(offset_fraction)
    if not (math.isfinite(frac) and frac >= 0):
        raise ValueError(f"offset_fraction must be a finite number >= 0, got {offset_fraction!r}")
    nj = robot.n_joints
    k = np.ones(nj) if ratios is None else np.abs(np.asarray(ratios, dtype=float))
    if k.shape != (nj,) or not np.all(np.isfinite(k)) or np.any(k == 0):
        raise ValueError(f"ratios must be None or {nj} finite non-zero numbers, got {ratios!r}")
    effort = np.asarray(robot.model.effortLimit, dtype=float)
    vmax = np.asarray(robot.model.velocityLimit, dtype=float)
    p = robot.n_parameters
    lo, hi = np.zeros(p), np.zeros(p)
    mr, mr2 = M * r, M * r * r
    inertial = {"m": (0.0, M), "mx": (-mr, mr), "my": (-mr, mr), "mz": (-mr, mr),
                "Ixx": (0.0, mr2), "Iyy": (0.0, mr2), "Izz": (0.0, mr2),
                "Ixy": (-mr2 / 2, mr2 / 2), "Ixz": (-mr2 / 2, mr2 / 2), "Iyz": (-mr2 / 2, mr2 / 2)}

    def limit(i, what, name):
        e = effort[i]
        v = vmax[i]
        if not (math.isfinite(e) and e > 0) or (what == "viscous" and not (math.isfinite(v) and v > 0)):
            raise ValueError(f"robot's URDF must give joint {i + 1} a positive finite effort (and velocity) limit "
                             f"for the {name} bound, got effort = {e!r}, velocity = {v!r}")
        return e / v if what == "viscous" else e

    for j, name in enumerate(robot.names):
        prefix, i = parameter_joint(name)
        if prefix in inertial:
            lo[j], hi[j] = inertial[prefix]
        elif prefix in ("fv", "fvm"):
            hi[j] = limit(i, "viscous", name)
        elif prefix in ("fs", "fsm"):
            hi[j] = limit(i, "coulomb", name)
        elif prefix in ("Ia", "Iam"):
            hi[j] = J * k[i] ** 2
        elif prefix == "off":
            e = limit(i, "coulomb", name)
            lo[j], hi[j] = -frac * e, frac * e
        else:
            raise ValueError(f"robot has a parameter {name!r} the physical prior does not know")
    return lo, hi


def _positive(x, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number > 0, got {x!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {x!r}")
    return v


def default_reach(robot: SerialRobot) -> float:
    """A reach bound [m] from the URDF alone: the sum of the joint-origin offsets (``|t|`` of every joint's
    placement in its parent, joint 1's from the base included) plus the distance of the last link's centre of
    mass from its joint origin. At any configuration every link's joint origin and centre of mass are within
    this distance of any other joint origin along the chain (triangle inequality over the segments)."""
    model = robot.model
    segments = sum(norm3(model.jointPlacements[i].translation) for i in range(1, model.njoints))
    last = norm3(model.inertias[model.njoints - 1].lever)
    return segments + last

# ---------------------------------------------------------------------------------------------- processing
def rich_friction_columns(qd, v_s: float) -> tuple[np.ndarray, tuple[str, ...]]:
    """Columns of a richer friction law, per joint i: ``|qd_i|`` (direction-dependent viscous: with ``fv``,
    ``fv+ != fv-``), ``sign(qd_i) exp(-|qd_i| / v_s)`` (Stribeck: static friction above Coulomb at low speed),
    ``qd_i |qd_i|`` (quadratic, lubricant drag). qd : (n, nj) [rad/s]; v_s [rad/s] > 0.
    Returns ((n, nj, 3 nj) block-diagonal columns, names ``fva_i, fst_i, fvq_i``)."""
    qd = np.asarray(qd, dtype=float)
    if not (isinstance(v_s, (int, float)) and math.isfinite(v_s) and v_s > 0):
        raise ValueError(f"v_s must be a finite number > 0 [rad/s], got {v_s!r}")
    nj = qd.shape[1]
    eye = np.eye(nj)
    a = np.abs(qd)
    blocks = [a, np.sign(qd) * np.exp(-a / v_s), qd * a]
    cols = np.concatenate([blk[:, :, None] * eye[None] for blk in blocks], axis=2)
    names = tuple(f"{k}{i + 1}" for k in ("fva", "fst", "fvq") for i in range(nj))
    return cols, names


@dataclass(frozen=True)
class SerialEquation:
    """Processed equation ``y = W theta + e`` of an n-joint log, ``|e_r| <= gain * b_joint(r) + rounding_r``.

    W : (m, r) filtered, decimated regressor (base columns); y : (m,) filtered torques [N m]; gain : ``||h||_1``
    of the parallel filter (rounded up), the factor by which a raw-row bound ``b`` grows (``|h| * b = gain b``
    for a per-joint constant b); rounding : (m,) rigorous floating-point error of the filter for theta in the
    prior (``|h| |y|`` and ``|h| |W| |theta|_max`` terms); sample : (m,) centre sample of each row's window;
    joint : (m,) joint of each row; names : (r,) columns; window : (m, 2) first and last raw sample used.
    """

    W: np.ndarray
    y: np.ndarray
    gain: float
    rounding: np.ndarray
    sample: np.ndarray
    joint: np.ndarray
    names: tuple[str, ...]
    window: np.ndarray
    info: dict = field(default_factory=dict, compare=False, repr=False)

    def __len__(self) -> int:
        return self.y.size

    def bound(self, raw_bound) -> np.ndarray:
        """(m,) rigorous bound of the filtered rows for a raw-row bound: scalar or (n_joints,) per joint [N m]."""
        b = np.asarray(raw_bound, dtype=float)
        nj = int(self.joint.max()) + 1 if self.joint.size else 0
        b = np.broadcast_to(b, (nj,)) if b.ndim == 0 else b
        if b.ndim != 1 or b.size < nj or np.any(~np.isfinite(b)) or np.any(b < 0):
            raise ValueError(f"raw_bound must be a finite scalar or ({nj},) per joint, >= 0, got {raw_bound!r}")
        raw = b[self.joint] * self.gain + self.rounding
        return np.nextafter(raw * (1.0 + 4.0 * np.finfo(float).eps), np.inf)

    def subset(self, rows) -> SerialEquation:
        rows = np.asarray(rows)
        return SerialEquation(self.W[rows], self.y[rows], self.gain, self.rounding[rows], self.sample[rows],
                              self.joint[rows], self.names, self.window[rows], dict(self.info))


def process(robot: SerialRobot, base: BaseParameters, q, tau, dt: float, *, cutoff_hz: float, decimation: int,
            numtaps: int | None = None, fir_cutoff: float = 0.8, speed_threshold: float = 0.05,
            theta_abs_max=None, butter_order: int = 4, first_sample: int = 0, rich_friction: float | None = None,
            keep_raw: bool = False, torque_timing: str = "hold") -> SerialEquation:
    """The paper's processing chain (:mod:`ident.processing.processing`) for an n-joint serial robot.

    q : (n, nj) measured joint angles [rad]; tau : (n, nj) joint torques [N m]; dt [s]; cutoff_hz : zero-phase
    Butterworth cut-off on q (one pass) [Hz]; derivatives by central differences (:func:`ident.processing.filtering.derivatives`,
    transient samples dropped); the base regressor; rows whose joint speed (for coupled-wrist rows also
    ``|qd_a + qd_b|``, the argument of ``sign`` in ``fsm``) is below ``speed_threshold`` [rad/s] are marked;
    parallel filtering (:func:`ident.processing.filtering.parallel_filter`, FIR of :func:`ident.processing.filtering.decimation_fir`)
    and decimation, an output row kept iff its whole window is free of marked rows. theta_abs_max : (r,) max
    ``|theta_b|`` over the prior, folds the filter's rounding on W into :attr:`SerialEquation.rounding`.
    first_sample : index of q[0] in the whole log (for ``sample``). rich_friction : None, or a Stribeck velocity
    ``v_s`` [rad/s]: append per joint the columns of a richer friction law (:func:`rich_friction_columns`), to
    measure how much of the residual the standard law leaves (they are not standard parameters); their
    entries of ``theta_abs_max`` must then be given too. keep_raw : keep the unfiltered equation in
    ``info['raw']`` (``W`` (n', nj, r), ``y`` (n', nj), ``sample`` (n',)) for residual spectra. torque_timing :
    ``"hold"`` (the library's default, :data:`ident.processing.filtering.DEFAULT_TORQUE_TIMING`: each torque a
    command held over its step, the regressor at mid-step) or ``"sample"`` (torques measured at the sampling
    instants, the regressor there), see :func:`ident.processing.filtering.derivatives`.
    The chain's functions work on any number of joints (column by column), so all nj joints go through one
    call of each.
    """
    from h4bench.ident.processing.filtering import (
        decimation_fir,
        default_edge_samples,
        derivatives,
        exclude_low_speed,
        parallel_filter,
    )

    nj = robot.n_joints
    q = _states(q, "q", nj)
    tau = _states(tau, "tau", nj)
    if q.shape != tau.shape:
        raise ValueError(f"q and tau must have the same shape, got {q.shape}, {tau.shape}")
    est = derivatives(q, dt, cutoff_hz, butter_order, timing=torque_timing)
    valid = est.valid
    qf, qd, qdd = est.q[valid], est.qd[valid], est.qdd[valid]
    samples = np.arange(q.shape[0])[valid] + int(first_sample)
    n = qf.shape[0]
    W = robot.regressor(qf, qd, qdd, columns=base.independent).reshape(n, nj, len(base))
    names = base.names
    if rich_friction is not None:
        extra, extra_names = rich_friction_columns(qd, rich_friction)
        W = np.concatenate([W, extra], axis=2)
        names = names + extra_names
    y = tau[valid]
    fast = exclude_low_speed(qd, speed_threshold).reshape(n, nj)  # the shared chain's marking, (n, nj)
    if robot.coupled_wrist is not None:
        a, b = robot.coupled_wrist
        s = np.abs(qd[:, a] + qd[:, b]) < speed_threshold
        fast[:, a] &= ~s
        fast[:, b] &= ~s
    taps = decimation_fir(decimation, numtaps, fir_cutoff)
    L = taps.size
    t_abs = None if theta_abs_max is None else np.asarray(theta_abs_max, dtype=float)
    fe = parallel_filter(W.reshape(nj * n, -1), y.reshape(-1), 0.0, decimation, taps=taps, theta_abs_max=t_abs,
                         joints=nj)
    gain, start = fe.l1_norm, fe.window_start
    m = start.size
    rows = np.flatnonzero(fe.propagate_mask(fast.reshape(-1)))  # kept iff the whole window moves fast enough
    k_idx, j_idx = rows // nj, rows % nj
    centre = samples[start + (L - 1) // 2]
    window = np.stack([samples[start], samples[start + L - 1]], axis=1)
    info = {"raw_samples": int(q.shape[0]), "valid_samples": int(n), "edge_samples": int(valid.start),
            "taps": int(L), "decimation": int(decimation), "filtered_rows": int(m * nj), "rows_kept": int(rows.size),
            "rows_slow": int((~fast).sum()), "butterworth_padding": default_edge_samples(dt, cutoff_hz),
            "rounding_includes_W": t_abs is not None}
    if keep_raw:
        info["raw"] = {"W": W, "y": y, "sample": samples}
    return SerialEquation(W=fe.W[rows], y=fe.y[rows], gain=float(gain), rounding=fe.bound[rows],
                          sample=centre[k_idx], joint=j_idx, names=names, window=window[k_idx], info=info)


# ------------------------------------------------------------------------------------- prediction envelope
def prediction_envelope(W, y, bound, lower, upper, W_new, *, center=None, lp_tol: float = 1e-9):
    """Rigorous ``[min, max]`` of ``W_new_k theta`` over ``S = {theta in [lower, upper] : |y - W theta| <= bound}``
    for every row k of W_new: the guaranteed prediction of new rows' model torque.

    The generic estimator :func:`ident.estimators.envelope.envelope_lp` (two warm-started LPs per row, safe
    dual bounds, intersected with the interval evaluation over the box). W : (m, p); y : (m,); bound : scalar
    or (m,) > 0; lower, upper : (p,) finite box containing S (the prior or a hull of S); W_new : (k, p);
    center : (p,) point near S (LP origin; default least squares). Returns (lo (k,), hi (k,), info
    {'lp_solves', 'lp_failures', 'seconds'}).
    """
    from h4bench.ident.estimators.envelope import envelope_lp

    return envelope_lp(W, y, bound, lower, upper, W_new, center=center, lp_tol=lp_tol)
