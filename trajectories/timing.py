"""Time parameterisation: time-optimal timing of a Cartesian waypoint path with toppra, and the slow-down that
makes an infeasible trajectory feasible (uniform time scaling, or toppra capped at the original speed).

toppra (Pham & Pham 2018, "A new approach to time-optimal path parameterization based on reachability analysis",
IEEE Trans. Robotics 34(3):645) times a joint path q(s) under

- joint speed ``|q'(s) sd| <= qd_max`` and acceleration ``|q'(s) sdd + q''(s) sd^2| <= qdd_max``;
- motor torque ``|tau| <= torque_margin tau_max`` with the paper's model on the nominal parameters, written in
  toppra's form ``tau = a(s) sdd + b(s) sd^2 + c(s)`` (:class:`NominalTorqueConstraint`, a
  ``toppra.constraint.JointTorqueConstraint``): inertia and gravity in ``inv_dyn``, Coulomb friction as
  ``fs_coef`` (toppra adds ``Fs sign(q'(s))``). Viscous friction ``Fv qd`` is linear in sd, which toppra's form
  cannot hold: the torque bound is lowered by ``Fv qd_max`` (its largest value under the speed limit).

Every limit is multiplied by ``limit_scale`` (0.98: toppra's results overshoot by about 1 %), and the sampled
result is checked sample by sample (:func:`trajectories.check_trajectory`); on a speed/acceleration/torque
violation the scale is lowered by 3 % and toppra runs again (recorded in ``parameters["timing"]``).
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import math
import time

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint
from toppra.constraint import DiscretizationType, JointTorqueConstraint, LinearConstraint

from h4bench import ident
from h4bench import sim
from h4bench.trajectories.checks import TIMING_CHECKS, check_samples
from h4bench.trajectories.limits import InfeasibleTrajectoryError, Limits, as_limits, as_theta
from h4bench.trajectories.trajectory import Trajectory

TOPPRA_VERSION = importlib.metadata.version("toppra")
# the friction parameters by their role (name), not by their position in ident.PARAMETER_NAMES
_FV = np.array([ident.PARAMETER_NAMES.index(f"Fv{i}") for i in range(1, 5)])  # viscous, joints 1..4
_FS = np.array([ident.PARAMETER_NAMES.index(f"Fs{i}") for i in range(1, 5)])  # Coulomb, joints 1..4


class NominalTorqueConstraint(JointTorqueConstraint):
    """toppra's joint torque constraint on the paper's model (``ident.inverse_dynamics`` on ``theta`` without
    friction) with Coulomb friction ``fs_coef = Fs``. Same coefficients as the base class (a test compares),
    computed for all gridpoints in one vectorised call instead of 3 calls per gridpoint.

    tau_lim : (4, 2) lower and upper torque bounds [N m].
    """

    def __init__(self, geometry, theta, tau_lim):
        theta = np.asarray(theta, dtype=float)
        self.geometry = geometry
        self.theta_no_friction = theta.copy()
        self.theta_no_friction[_FV] = 0.0
        self.theta_no_friction[_FS] = 0.0
        super().__init__(self.inv_dyn, tau_lim, theta[_FS])

    def inv_dyn(self, q, qd, qdd):
        """Torques (4,) or (n, 4) [N m] of inertia and gravity: ``ident.inverse_dynamics`` without friction."""
        return ident.inverse_dynamics(self.geometry, self.theta_no_friction, q, qd, qdd)

    def compute_constraint_params(self, path, gridpoints):
        if path.dof != self.get_dof():
            raise ValueError(f"Wrong dimension: constraint dof ({self.get_dof()}) not equal to path dof ({path.dof})")
        p, ps, pss = path(gridpoints), path(gridpoints, 1), path(gridpoints, 2)
        x = sim.forward_kinematics(self.geometry, p)
        zero = np.zeros_like(p)
        inv = lambda v, a: ident.inverse_dynamics(self.geometry, self.theta_no_friction, p, v, a, x=x)  # noqa: E731
        c = inv(zero, zero)
        a = inv(zero, ps) - c
        b = inv(ps, pss) - c
        c = c + self.fs_coef[None] * np.sign(ps)
        dof = self.dof
        F = np.vstack([np.eye(dof), -np.eye(dof)])
        g = np.concatenate([self.tau_lim[:, 1], -self.tau_lim[:, 0]])
        if self.discretization_type == DiscretizationType.Collocation:
            return a, b, c, F, g, None, None
        return toppra.constraint.linear_constraint.canlinear_colloc_to_interpolate(
            a, b, c, F, g, None, None, gridpoints, identical=True)


class PathSpeedCap(LinearConstraint):
    """``sd <= sd_max`` (a bound on x = sd^2): never traverse the path faster than its own parameter."""

    def __init__(self, dof: int, sd_max: float = 1.0):
        super().__init__()
        self.dof, self.sd_max = dof, float(sd_max)
        self._format_string = f"    Path speed cap: sd <= {self.sd_max}\n"

    def compute_constraint_params(self, path, gridpoints):
        xbound = np.zeros((len(gridpoints), 2))
        xbound[:, 1] = self.sd_max**2
        return None, None, None, None, None, None, xbound


def _constraints(geometry, limits: Limits, theta, scale: float) -> list:
    vmax = scale * np.asarray(limits.qd_max)
    amax = scale * np.asarray(limits.qdd_max)
    tmax = scale * limits.tau_allowed - theta[_FV] * vmax  # viscous friction's worst case under the speed limit
    if np.any(tmax <= 0):
        raise InfeasibleTrajectoryError(f"the torque limit {limits.tau_allowed.tolist()} N m leaves nothing after "
                                        f"the viscous margin Fv qd_max = {(theta[_FV] * vmax).tolist()} N m")
    return [toppra.constraint.JointVelocityConstraint(np.column_stack([-vmax, vmax])),
            toppra.constraint.JointAccelerationConstraint(np.column_stack([-amax, amax])),
            NominalTorqueConstraint(geometry, theta, np.column_stack([-tmax, tmax]))]


def _toppra(path, constraints, gridpoints):
    """Run TOPPRA; return (timed path, gridpoint times (N+1,)) or None when infeasible."""
    algo = toppra.algorithm.TOPPRA(constraints, path, gridpoints=gridpoints, parametrizer="ParametrizeConstAccel")
    timed = algo.compute_trajectory(0.0, 0.0)
    if timed is None:
        return None
    sd = algo.problem_data.sd_vec
    t_grid = np.concatenate([[0.0], np.cumsum(2.0 * np.diff(gridpoints) / (sd[:-1] + sd[1:]))])
    return timed, t_grid


def _sample(timed, dt: float) -> tuple[np.ndarray, ...]:
    """Sample a timed path every dt from 0 until at rest at its end: t (n,), q, qd, qdd (n, 4).
    Samples at or after the end (there is one: n = ceil(duration / dt) + 1) hold the final pose at rest."""
    duration = float(timed.duration)
    n = int(math.ceil(duration / dt - 1e-9)) + 1
    t = np.arange(n) * dt
    te = np.minimum(t, duration)
    q, qd, qdd = timed(te), timed(te, 1), timed(te, 2)
    rest = t >= duration
    qd[rest] = 0.0
    qdd[rest] = 0.0
    return t, q, qd, qdd


def _timed_trajectory(geometry, path, gridpoints, limits, theta, dt, limit_scale, what, extra=()):
    """Time ``path`` with toppra, sample, check; lower the limit scale on speed/acceleration/torque violations."""
    tries = []
    scale = limit_scale
    for _attempt in range(6):
        t0 = time.perf_counter()
        out = _toppra(path, _constraints(geometry, limits, theta, scale) + list(extra), gridpoints)
        if out is None:
            raise InfeasibleTrajectoryError(
                f"toppra found no feasible time parameterisation of {what} (limit scale {scale:.3g}): at some point "
                "of the path even standing still violates the torque limit (gravity + Coulomb friction)")
        timed, t_grid = out
        t, q, qd, qdd = _sample(timed, dt)
        x = sim.forward_kinematics(geometry, q)
        report = check_samples(geometry, t, x, q, qd, qdd, limits, theta, raise_on_violation=False)
        tries.append({"limit_scale": scale, "duration": float(timed.duration), "seconds": time.perf_counter() - t0,
                      "violations": report["violations"]})
        if report["feasible"]:
            return t, x, q, qd, qdd, report, t_grid, tries
        if set(report["violations"]) - set(TIMING_CHECKS):
            check_samples(geometry, t, x, q, qd, qdd, limits, theta)  # raises: the path itself is infeasible
        scale *= 0.97
    check_samples(geometry, t, x, q, qd, qdd, limits, theta)  # raises with the last violation
    raise AssertionError("unreachable")


def _as_waypoints(waypoints_x) -> np.ndarray:
    try:
        w = np.asarray(waypoints_x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"waypoints_x must be an array-like of shape (m, 4), got {type(waypoints_x).__name__}") \
            from exc
    if w.ndim != 2 or w.shape[1] != 4 or w.shape[0] < 2:
        raise ValueError(f"waypoints_x must have shape (m, 4) with m >= 2 (x, y, z, theta per row), got {w.shape}")
    if not np.all(np.isfinite(w)):
        bad = np.flatnonzero(~np.all(np.isfinite(w), axis=1))
        raise ValueError(f"waypoints_x must be finite, got NaN/inf in row(s) {bad.tolist()}")
    return w


def waypoint_trajectory(geometry, waypoints_x, limits=None, dt: float = 1e-3, theta_nominal=None, *,
                        limit_scale: float = 0.98, grid_points: int = 1000) -> Trajectory:
    """Time-optimal motion through Cartesian waypoints (e.g. a pick-and-place path), timed by toppra.

    waypoints_x : (m, 4) nacelle poses (x, y, z, theta) [m, m, m, rad], m >= 2, inside the workspace box;
    they are mapped to joint space by the IK and joined by a cubic spline in joint space
    (``toppra.SplineInterpolator``, clamped: zero path derivative at both ends, so the motion starts and ends
    with qd = qdd = 0), parameterised by the cumulative joint-space distance [rad]. The spline leaves the
    Cartesian segments between waypoints; the result is checked on every sample against the workspace, the
    singularity margin and the limits. dt : sampling period [s]; grid_points : toppra's uniform gridpoints
    (the waypoints are added to them).

    Returns a :class:`Trajectory` of kind ``"waypoints"`` whose ``parameters["waypoint_times"]`` give when each
    waypoint is passed (exact: they are gridpoints). Raises :class:`InfeasibleTrajectoryError` (a ``ValueError``)
    naming the waypoint or sample that violates a limit.
    """
    if not isinstance(geometry, sim.H4Geometry):
        raise TypeError(f"geometry must be a sim.H4Geometry, got {type(geometry).__name__}")
    w = _as_waypoints(waypoints_x)
    limits, theta = as_limits(limits), as_theta(theta_nominal)
    _check_positive("dt", dt)
    _check_positive("limit_scale", limit_scale, upper=1.0)
    if isinstance(grid_points, bool) or not isinstance(grid_points, (int, np.integer)) or grid_points < 10:
        raise ValueError(f"grid_points must be an int >= 10, got {grid_points!r}")
    lo, hi = np.asarray(limits.x_lower), np.asarray(limits.x_upper)
    outside = (w < lo) | (w > hi)
    if outside.any():
        k, j = np.argwhere(outside)[0]
        raise InfeasibleTrajectoryError(
            f"waypoints_x[{k}] = {w[k].tolist()} is outside the workspace box: {('x', 'y', 'z', 'theta')[j]} = "
            f"{w[k, j]:.6g} not in [{lo[j]:.6g}, {hi[j]:.6g}]", check="workspace", index=int(k),
            label=("x", "y", "z", "theta")[j], value=float(w[k, j]), lower=float(lo[j]), upper=float(hi[j]))
    try:
        q_wp = sim.inverse_kinematics(geometry, w)
    except sim.KinematicsError as exc:
        raise InfeasibleTrajectoryError(f"waypoints_x: {exc}", check="reach") from exc
    step = np.linalg.norm(np.diff(q_wp, axis=0), axis=1)
    if np.any(step < 1e-9):
        k = int(np.flatnonzero(step < 1e-9)[0])
        raise ValueError(f"waypoints_x rows {k} and {k + 1} coincide (consecutive waypoints must differ)")
    ss = np.concatenate([[0.0], np.cumsum(step)])
    path = toppra.SplineInterpolator(ss, q_wp, bc_type="clamped")
    gridpoints = np.union1d(np.linspace(0.0, ss[-1], grid_points), ss)
    t, x, q, qd, qdd, report, t_grid, tries = _timed_trajectory(geometry, path, gridpoints, limits, theta, dt,
                                                                limit_scale, "the waypoint path")
    waypoint_times = t_grid[np.searchsorted(gridpoints, ss)]
    parameters = {
        "waypoints_x": w, "waypoints_q": q_wp, "path_s": ss, "waypoint_times": waypoint_times, "dt": dt,
        "timing": {"method": "toppra", "toppra_version": TOPPRA_VERSION, "parametrizer": "ParametrizeConstAccel",
                   "gridpoints": int(gridpoints.size), "spline": "joint-space cubic, clamped",
                   "viscous_margin": "tau bound lowered by Fv qd_max", "tries": tries},
        "limits": limits.to_dict(), "theta_nominal": theta, "parameter_names": list(ident.PARAMETER_NAMES),
    }
    return Trajectory(t=t, x=x, q=q, qd=qd, qdd=qdd, kind="waypoints", parameters=parameters, checks=report)


def _check_positive(name, value, upper=None):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0 or (upper is not None and value > upper):
        rng = f"in (0, {upper}]" if upper is not None else "> 0"
        raise ValueError(f"{name} must be a finite number {rng}, got {value!r}")


def slow_down(geometry, traj: Trajectory, limits=None, theta_nominal=None, method: str = "uniform") -> Trajectory:
    """Slow an infeasible trajectory down until it meets the speed, acceleration and torque limits.

    method ``"uniform"`` (Fourier trajectories): the smallest time-scaling factor k >= 1 (bisection to 0.5 %) with
    which the stretched trajectory (same path, same slow/fast schedule, every time multiplied by k: speeds / k,
    accelerations / k^2) passes every check; evaluated exactly from the Fourier coefficients.
    method ``"toppra"`` (any trajectory): toppra on the trajectory's own joint path (parameter s = its original
    time, cubic spline through its samples every 5 ms) with the extra constraint sd <= 1, so it is slowed down
    only where a limit requires it and never made faster than designed (the slow phases stay slow).

    Workspace, reach, joint range and singularity violations cannot be cured by timing: they raise
    :class:`InfeasibleTrajectoryError`. Returns a new :class:`Trajectory` (kind ``"<kind>+<method>-slowdown"``)
    with ``parameters["slow_down"]``: method, factor (new/old duration), durations, violations before.
    A feasible trajectory is returned unchanged (factor 1).
    """
    if not isinstance(geometry, sim.H4Geometry):
        raise TypeError(f"geometry must be a sim.H4Geometry, got {type(geometry).__name__}")
    if not isinstance(traj, Trajectory):
        raise TypeError(f"traj must be a trajectories.Trajectory, got {type(traj).__name__}")
    if method not in ("uniform", "toppra"):
        raise ValueError(f"method must be 'uniform' or 'toppra', got {method!r}")
    if limits is None and "limits" in traj.parameters:
        limits = Limits.from_dict(traj.parameters["limits"])
    limits = as_limits(limits)
    theta = as_theta(theta_nominal if theta_nominal is not None else traj.parameters.get("theta_nominal"))
    before = check_samples(geometry, traj.t, traj.x, traj.q, traj.qd, traj.qdd, limits, theta,
                           raise_on_violation=False)
    if before["feasible"]:
        return traj
    if set(before["violations"]) - set(TIMING_CHECKS):
        geometric_only = dataclasses.replace(limits, qd_max=1e300, qdd_max=1e300, tau_max=1e300)
        try:
            check_samples(geometry, traj.t, traj.x, traj.q, traj.qd, traj.qdd, geometric_only, theta)
        except InfeasibleTrajectoryError as exc:
            raise InfeasibleTrajectoryError(f"slow_down cannot repair the path itself: {exc}", check=exc.check,
                                            index=exc.index, time=exc.time, label=exc.label, value=exc.value,
                                            lower=exc.lower, upper=exc.upper, violations=exc.violations) from exc
    t0 = time.perf_counter()
    params = dict(traj.parameters, limits=limits.to_dict(), theta_nominal=theta)
    if method == "uniform":
        new, info = _uniform(geometry, traj, params)
    else:
        new, info = _toppra_slowdown(geometry, traj, limits, theta, params)
    info.update(method=method, duration_before=traj.duration, duration_after=new.duration,
                factor=new.duration / traj.duration, violations_before=before["violations"],
                usage_before=before["usage"], usage_after=new.checks["usage"], seconds=time.perf_counter() - t0)
    parameters = dict(new.parameters, slow_down=info)
    return dataclasses.replace(new, kind=f"{traj.kind}+{method}-slowdown", parameters=parameters)


def _uniform(geometry, traj, params):
    from h4bench.trajectories.fourier import fourier_trajectory  # noqa: PLC0415

    if "schedule_knots" not in params:
        raise ValueError(f"method='uniform' needs a Fourier trajectory (its coefficients), got kind {traj.kind!r}; "
                         "use method='toppra'")
    T, dt = params["duration"], params["dt"]
    coarse = max(dt, 5e-3)

    def feasible(k, step):
        duration = math.ceil(k * T / dt - 1e-9) * dt
        cand = fourier_trajectory(geometry, params, duration=duration, dt=step)
        return cand.checks["feasible"], cand

    usage = traj.checks.get("usage") or {}
    k_lo = 1.0
    k_hi = max(1.0, usage.get("speed", 1.0), math.sqrt(max(usage.get("acceleration", 1.0), 0.0))) * 1.01
    while not feasible(k_hi, coarse)[0]:
        k_lo, k_hi = k_hi, 2.0 * k_hi
        if k_hi > 64:
            raise InfeasibleTrajectoryError("no uniform slow-down up to 64x makes the trajectory feasible: the torque "
                                            "at rest (gravity + Coulomb friction) exceeds the limit")
    while k_hi - k_lo > 5e-3 * k_hi:
        mid = 0.5 * (k_lo + k_hi)
        if feasible(mid, coarse)[0]:
            k_hi = mid
        else:
            k_lo = mid
    for _ in range(20):  # confirm on the full sampling (peaks between coarse samples)
        ok, cand = feasible(k_hi, dt)
        if ok:
            return cand, {"time_scale": k_hi, "search_dt": coarse}
        k_hi *= 1.005
    raise InfeasibleTrajectoryError(f"uniform slow-down by {k_hi:.4g} still violates {cand.checks['violations']}")


def _toppra_slowdown(geometry, traj, limits, theta, params):
    stride = max(1, int(round(5e-3 / traj.dt)))
    idx = np.unique(np.concatenate([np.arange(0, traj.n, stride), [traj.n - 1]]))
    knots_t = traj.t[idx] - traj.t[0]
    path = toppra.SplineInterpolator(knots_t, traj.q[idx], bc_type="clamped")
    t, x, q, qd, qdd, report, t_grid, tries = _timed_trajectory(
        geometry, path, knots_t, limits, theta, traj.dt, 0.98, "the trajectory's path", extra=[PathSpeedCap(4, 1.0)])
    params = dict(params, dt=traj.dt)
    for key in ("duration", "schedule_knots", "schedule_levels"):
        params.pop(key, None)  # the Fourier schedule no longer describes the timing
    info = {"toppra_version": TOPPRA_VERSION, "parametrizer": "ParametrizeConstAccel", "gridpoints": int(idx.size),
            "spline": "joint-space cubic through samples every 5 ms, clamped", "sd_max": 1.0, "tries": tries,
            "viscous_margin": "tau bound lowered by Fv qd_max"}
    return Trajectory(t=t, x=x, q=q, qd=qd, qdd=qdd, kind=traj.kind, parameters=params, checks=report), info
