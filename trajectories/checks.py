"""Sample-by-sample checks of a reference trajectory against :class:`trajectories.Limits`, and its report.

Checks, in the order used to break ties when two fail at the same sample (:data:`CHECKS`):

- ``reach``: every forearm reaches its arm (IK ratio ``|c / rho| <= 1``, ``sim.inverse_kinematics``);
- ``consistency``: the joint reference is the IK of the pose reference, ``|q - IK(x)| <= 1e-6`` rad;
- ``workspace``: ``x_lower <= x <= x_upper`` (the documented box on x, y, z, theta);
- ``joint_range``: ``q_range[:, 0] + q_margin <= q <= q_range[:, 1] - q_margin``;
- ``singularity``: ``cond(Jx) <= max_cond_jx``;
- ``speed``, ``acceleration``: ``|qd| <= qd_max``, ``|qdd| <= qdd_max``;
- ``nacelle_speed``, ``nacelle_acceleration``: ``|xd[:3]| <= xd_max``, ``|xdd[:3]| <= xdd_max`` (Euclidean norms of
  the nacelle's translation, ``xd = J qd``, ``xdd = J qdd + Jd qd``, paper eq. 13; unchecked when infinite);
- ``torque``: ``|tau| <= torque_margin * tau_max`` with ``tau = ident.inverse_dynamics(theta_nominal, q, qd, qdd)``
  (the paper's model, Coulomb friction ``Fs sign(qd)`` included).

The regressor's conditioning is reported three ways on the paper's 14-column W (4n, 14) of the reference:
``cond_W`` (raw, SI units), ``cond_W_scaled`` = cond(W diag(theta_nominal)) (each column is the torque its
parameter contributes at its nominal value: the figure the Fourier design minimises) and ``cond_W_normalised``
(unit-norm columns: a scaling-free figure).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench import ident
from h4bench import sim
from h4bench.portable import cond, matmul
# unchecked: per-sample reach ratio without raising; Jd
from h4bench.sim.kinematics import ik_unchecked, jacobian_dot_unchecked
from h4bench.trajectories.limits import InfeasibleTrajectoryError, Limits, as_limits, as_theta
from h4bench.trajectories.trajectory import Trajectory

CHECKS = ("reach", "consistency", "workspace", "joint_range", "singularity", "speed", "acceleration",
          "nacelle_speed", "nacelle_acceleration", "torque")
#: Checks a re-timing can repair (the geometric path is fine, the timing is not).
TIMING_CHECKS = ("speed", "acceleration", "nacelle_speed", "nacelle_acceleration", "torque")
G0 = 9.80665  # standard gravity [m/s^2], for reporting accelerations in g
CONSISTENCY_TOL = 1e-6  # [rad]
AXES = ("x", "y", "z", "theta")
JOINTS = ("q1", "q2", "q3", "q4")


@dataclass(frozen=True)
class _Check:
    name: str
    values: np.ndarray  # (n, m)
    lower: np.ndarray  # (m,)
    upper: np.ndarray  # (m,)
    labels: tuple[str, ...]
    units: tuple[str, ...]  # per column
    what: str


def condition_numbers(W: np.ndarray, theta_nominal: np.ndarray) -> dict:
    """cond of W (raw), of W diag(theta_nominal) (scaled) and of W with unit-norm columns (normalised)."""
    # one-sided Jacobi (h4bench.portable), not LAPACK: the report is part of a design's content hash
    out = {"cond_W": float(cond(W)), "cond_W_scaled": float(cond(W * theta_nominal[None]))}
    norms = np.sqrt(np.einsum("mj,mj->j", W, W))
    out["cond_W_normalised"] = float(cond(W / norms[None])) if np.all(norms > 0) else float("inf")
    return out


def _evaluate(geometry, x, q, qd, qdd, limits, theta):
    n = q.shape[0]
    q_ik, ratio = ik_unchecked(geometry, x)
    reach = np.abs(ratio)
    dq = (q - q_ik + np.pi) % (2 * np.pi) - np.pi
    q_lo, q_hi = limits.q_bounds(geometry)
    jac = sim.jacobians(geometry, q, x=x)
    cond_jx = cond(jac.Jx)[:, None]
    xd = np.einsum("nab,nb->na", jac.J, qd)
    xdd = np.einsum("nab,nb->na", jac.J, qdd) + np.einsum("nab,nb->na", jacobian_dot_unchecked(geometry, jac, qd), qd)
    cart = np.stack([np.linalg.norm(xd[:, :3], axis=1), np.linalg.norm(xdd[:, :3], axis=1)], axis=1)
    W = ident.regressor(geometry, q, qd, qdd, x=x)
    tau = matmul(W, theta).reshape(n, 4)
    inf4 = np.full(4, np.inf)
    vmax, amax, tmax = np.asarray(limits.qd_max), np.asarray(limits.qdd_max), limits.tau_allowed
    checks = [
        _Check("reach", reach, -inf4, np.ones(4), JOINTS, ("",) * 4, "forearm reach |c/rho| of chain"),
        _Check("consistency", dq, -np.full(4, CONSISTENCY_TOL), np.full(4, CONSISTENCY_TOL), JOINTS, ("rad",) * 4,
               "q - IK(x) of joint"),
        _Check("workspace", x, np.asarray(limits.x_lower), np.asarray(limits.x_upper), AXES,
               ("m", "m", "m", "rad"), "nacelle pose"),
        _Check("joint_range", q, q_lo, q_hi, JOINTS, ("rad",) * 4, "motor angle (joint range minus q_margin)"),
        _Check("singularity", cond_jx, np.array([-np.inf]), np.array([limits.max_cond_jx]), ("cond(Jx)",), ("",),
               "singularity measure"),
        _Check("speed", qd, -vmax, vmax, JOINTS, ("rad/s",) * 4, "joint speed"),
        _Check("acceleration", qdd, -amax, amax, JOINTS, ("rad/s^2",) * 4, "joint acceleration"),
        _Check("nacelle_speed", cart[:, :1], np.array([-np.inf]), np.array([limits.xd_max]), ("|xd|",),
               ("m/s",), "nacelle translational speed"),
        _Check("nacelle_acceleration", cart[:, 1:], np.array([-np.inf]), np.array([limits.xdd_max]), ("|xdd|",),
               ("m/s^2",), "nacelle translational acceleration"),
        _Check("torque", tau, -tmax, tmax, JOINTS, ("N m",) * 4,
               f"motor torque (nominal parameters; limit {limits.torque_margin:g} x tau_max)"),
    ]
    return checks, W, tau, cond_jx[:, 0], reach, cart


def _first_violation(check: _Check):
    bad = (check.values < check.lower[None]) | (check.values > check.upper[None])
    rows = np.flatnonzero(bad.any(axis=1))
    if rows.size == 0:
        return None, 0
    k = int(rows[0])
    j = int(np.flatnonzero(bad[k])[0])
    return (k, j), int(rows.size)


def check_samples(geometry, t, x, q, qd, qdd, limits=None, theta_nominal=None, raise_on_violation=True) -> dict:
    """Check sampled reference motion (t (n,) [s]; x, q, qd, qdd (n, 4)) and return the report dict.

    Raises :class:`InfeasibleTrajectoryError` (a ``ValueError``) naming the first violating sample (index, time),
    the check, the joint or axis, the value and the limit, when ``raise_on_violation``.
    """
    limits, theta = as_limits(limits), as_theta(theta_nominal)
    t = np.asarray(t, dtype=float)
    x, q, qd, qdd = (np.asarray(a, dtype=float) for a in (x, q, qd, qdd))
    checks, W, tau, cond_jx, reach, cart = _evaluate(geometry, x, q, qd, qdd, limits, theta)
    violations, first = {}, None
    for order, check in enumerate(checks):
        where, count = _first_violation(check)
        if count:
            violations[check.name] = count
            if first is None or where[0] < first[0][0]:
                first = (where, check)
    report = _report(t, x, q, qd, qdd, tau, W, cond_jx, reach, limits, theta, geometry)
    report.update(peak_nacelle_speed=float(cart[:, 0].max()), peak_nacelle_acceleration=float(cart[:, 1].max()),
                  peak_nacelle_acceleration_g=float(cart[:, 1].max() / G0),
                  limit_nacelle_speed=limits.to_dict()["xd_max"], limit_nacelle_acceleration=limits.to_dict()["xdd_max"])
    report["violations"] = violations
    report["feasible"] = not violations
    if violations and raise_on_violation:
        (k, j), check = first
        value, lo, hi = float(check.values[k, j]), float(check.lower[j]), float(check.upper[j])
        others = ", ".join(f"{name}: {c} sample(s)" for name, c in violations.items())
        unit = f" {check.units[j]}" if check.units[j] else ""
        limit = f"<= {hi:.6g}" if not np.isfinite(lo) else f"in [{lo:.6g}, {hi:.6g}]"
        raise InfeasibleTrajectoryError(
            f"trajectory violates the {check.name} limit at sample {k} (t = {t[k]:.4f} s): {check.what} "
            f"{check.labels[j]} = {value:.6g}{unit}, limit {limit}{unit} (violations: {others})",
            check=check.name, index=k, time=float(t[k]), label=check.labels[j], value=value, lower=lo, upper=hi,
            violations=violations,
        )
    return report


def _report(t, x, q, qd, qdd, tau, W, cond_jx, reach, limits, theta, geometry) -> dict:
    lo, hi = np.asarray(limits.x_lower), np.asarray(limits.x_upper)
    box_margin = np.minimum(x - lo, hi - x).min(axis=0)
    q_lo, q_hi = limits.q_bounds(geometry)
    rep = {
        "n_samples": int(t.size),
        "duration_s": float(t[-1] - t[0]),
        "dt_s": float(t[1] - t[0]) if t.size > 1 else 0.0,
        **condition_numbers(W, theta),
        "peak_qd": np.abs(qd).max(axis=0).tolist(), "limit_qd": list(limits.qd_max),
        "peak_qdd": np.abs(qdd).max(axis=0).tolist(), "limit_qdd": list(limits.qdd_max),
        "peak_tau": np.abs(tau).max(axis=0).tolist(), "limit_tau": limits.tau_allowed.tolist(),
        "tau_max": list(limits.tau_max),
        "max_cond_jx": float(cond_jx.max()), "limit_cond_jx": limits.max_cond_jx,
        "workspace_margin": dict(zip(AXES, box_margin.tolist())),
        "min_workspace_margin_m": float(box_margin[:3].min()),
        "min_theta_margin_rad": float(box_margin[3]),
        "joint_range_margin_rad": np.minimum(q - q_lo, q_hi - q).min(axis=0).tolist(),
        "reach_margin": float(1.0 - reach.max()),
        "start_at_rest": bool(np.all(qd[0] == 0) and np.all(qdd[0] == 0)),
        "end_at_rest": bool(np.all(qd[-1] == 0) and np.all(qdd[-1] == 0)),
    }
    rep["usage"] = {
        "speed": max(a / b for a, b in zip(rep["peak_qd"], rep["limit_qd"])),
        "acceleration": max(a / b for a, b in zip(rep["peak_qdd"], rep["limit_qdd"])),
        "torque": max(a / b for a, b in zip(rep["peak_tau"], rep["limit_tau"])),
        "cond_jx": rep["max_cond_jx"] / rep["limit_cond_jx"],
    }
    return rep


def check_trajectory(geometry, traj, limits=None, theta_nominal=None, raise_on_violation=True) -> dict:
    """Check every sample of a :class:`trajectories.Trajectory`; return its report (see :func:`check_samples`).

    ``limits``/``theta_nominal`` default to those stored in the trajectory's parameters, else to the defaults.
    """
    if not isinstance(geometry, sim.H4Geometry):
        raise TypeError(f"geometry must be a sim.H4Geometry, got {type(geometry).__name__}")
    if not isinstance(traj, Trajectory):
        raise TypeError(f"traj must be a trajectories.Trajectory, got {type(traj).__name__}")
    if limits is None and "limits" in traj.parameters:
        limits = Limits.from_dict(traj.parameters["limits"])
    if theta_nominal is None and "theta_nominal" in traj.parameters:
        theta_nominal = traj.parameters["theta_nominal"]
    return check_samples(geometry, traj.t, traj.x, traj.q, traj.qd, traj.qdd, limits, theta_nominal,
                         raise_on_violation=raise_on_violation)
