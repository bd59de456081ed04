"""Exciting trajectories: a finite Fourier series in the nacelle's pose, traversed slowly then fast, with
coefficients optimised for the condition number of the paper's regressor.

Path (Swevers, Ganseman, Tukel, De Schutter & Van Brussel 1997, ASME J. Manuf. Sci. Eng. 119(4A):611), per axis
of the nacelle pose x = (x, y, z, theta) (or per motor angle with ``space="joint"``), over a phase phi [cycles]::

    x(phi) = x_home + sum_k a_k sin(2 pi k phi) + b_k (cos(2 pi k phi) - 1),    k = 1..H

so ``x(0) = x(integer) = x_home``. The joint reference follows by the closed-form IK, ``qd = J^-1 xd`` and
``qdd = J^-1 (xdd - Jd qd)`` (J = Jx^-1 Jq, paper eq. 13; exact, no differencing). Cartesian space is the
default: a joint-space series spins the nacelle's theta (small Jacobian column) into singularities.

Time-warp (the slow and fast phases). The path is traversed at the phase speed ``phid(t)`` [cycles/s], a
piecewise quintic-smoothstep schedule (C2: continuous phidd, so qdd is continuous)::

    0 --ramp--> rho v --slow--> rho v --transition--> v --fast--> v --ramp--> 0

(rho = ``slow_ratio``). Why a time-warp rather than a window or a second series: (i) the rest conditions are
exact, phid = phidd = 0 at both ends gives xd = xdd = 0 and hence qd = qdd = 0, without distorting the path;
(ii) the slow phase traverses the *same* Fourier path as the fast phase, so the position-dependent columns of W
(gravity through Mnac, the Jacobians) are shared while the speed-dependent ones (Fv qd, Fs sign qd) are seen at
speeds 1/rho apart, and the torque is friction-dominated there: this separates friction from inertia and
gravity; (iii) a uniform slow-down (:func:`trajectories.slow_down`) is the same schedule stretched. The fast
speed v is set so that the path makes a whole number of cycles (x(T) = x_home); the fundamental frequency in
the fast phase is ``base_hz`` rounded accordingly (``parameters["base_hz"]``).

Objective: ``log cond(W diag(theta_nominal))`` with W (4N, 14) the paper's regressor on a coarse time grid
(``grid_per_period`` = 12 samples per period of the highest harmonic in the fast phase): each column is then the
torque its parameter contributes at its nominal value, so the condition number measures how relative errors
of the parameters are amplified (``cond_W_normalised``, unit-norm columns, is reported beside it). In the
optimiser the Coulomb columns use tanh(qd / 0.05 rad/s) for sign(qd). Constraints: workspace box, reach, joint
range, cond(Jx), speed, acceleration and nominal torque, each limit multiplied by ``design_factor`` on the
coarse grid; SLSQP (scipy) with gradients by the chain rule through per-sample finite differences
(:mod:`trajectories.design`). The start is a seeded random series (``np.random.default_rng(seed)``, amplitudes
~ 1/k), scaled to 0.9 x its largest feasible amplitude. With ``criterion="h"`` the objective is instead the bounded-error one of :mod:`trajectories.bounded` (smooth max
of the relative half-widths h_j / target_j of the feasible set's geometry; Pronzato & Walter 1989), which
rewards amplitude where cond(W) cannot see it; the grid then has at least 36 samples per second.
The result is checked on every sample
(:func:`trajectories.check_trajectory`) with the real limits and its amplitude reduced by 3 % steps if a peak
fell between grid samples.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from h4bench import ident
from h4bench import sim
from h4bench.portable import matmul
from h4bench.ident.processing.filtering import ProcessingSettings
# unchecked, vectorised (no re-validation)
from h4bench.sim.kinematics import ik_unchecked, jacobian_dot_unchecked, jacobians_unchecked
from h4bench.trajectories.bounded import HalfwidthProblem, as_targets
from h4bench.trajectories.checks import check_samples
from h4bench.trajectories.design import CoefficientProblem
from h4bench.trajectories.limits import InfeasibleTrajectoryError, Limits, as_limits, as_theta
from h4bench.trajectories.trajectory import Trajectory

SPACES = ("cartesian", "joint")
CRITERIA = ("cond", "h")
OBJECTIVES = {"cond": "cond(W diag(theta_nominal)), paper's 14-column W on a coarse grid",
              "h": "smooth max of h_j / target_j (bounded-error half-widths of the processed regressor) on a grid"}
#: Typical amplitude per axis for the random start [m, m, m, rad] (Cartesian) and per joint [rad] (joint space).
START_SCALE = {"cartesian": np.array([0.05, 0.05, 0.06, 0.25]), "joint": np.full(4, 0.2)}


def _smoothstep(u):
    """Quintic smoothstep S(u) = 10u^3 - 15u^4 + 6u^5, its derivative and its integral from 0 to u."""
    u2 = u * u
    return u2 * u * (10 - 15 * u + 6 * u2), 30 * u2 * (1 - u) ** 2, u2 * u2 * (2.5 - 3 * u + u2)


@dataclass(frozen=True)
class PhaseSchedule:
    """Phase speed schedule: ``phid`` goes from ``levels[j]`` to ``levels[j + 1]`` [cycles/s] on
    ``[knots[j], knots[j + 1]]`` [s] along a quintic smoothstep. ``phi(0) = 0``."""

    knots: np.ndarray
    levels: np.ndarray

    @classmethod
    def slow_fast(cls, duration, slow_fraction, slow_ratio, ramp_s, transition_s, fast_speed=1.0):
        T = float(duration)
        t_slow_end = ramp_s + slow_fraction * T
        knots = np.array([0.0, ramp_s, t_slow_end, t_slow_end + transition_s, T - ramp_s, T])
        levels = fast_speed * np.array([0.0, slow_ratio, slow_ratio, 1.0, 1.0, 0.0])
        keep = np.concatenate([[True], np.diff(knots) > 0])  # drop empty segments (slow_fraction = 0)
        return cls(knots[keep], levels[keep])

    @property
    def total(self) -> float:
        """phi at the end [cycles] (a smoothstep segment integrates to h (v0 + v1) / 2)."""
        return float(np.sum(np.diff(self.knots) * 0.5 * (self.levels[:-1] + self.levels[1:])))

    def __call__(self, t):
        """phi [cycles], phid [cycles/s], phidd [cycles/s^2] at times t (n,)."""
        h = np.diff(self.knots)
        start = np.concatenate([[0.0], np.cumsum(h * 0.5 * (self.levels[:-1] + self.levels[1:]))])
        j = np.clip(np.searchsorted(self.knots, t, side="right") - 1, 0, h.size - 1)
        u = np.clip((t - self.knots[j]) / h[j], 0.0, 1.0)
        s, ds, integral = _smoothstep(u)
        v0, dv = self.levels[j], self.levels[j + 1] - self.levels[j]
        return start[j] + h[j] * (v0 * u + dv * integral), v0 + dv * s, dv * ds / h[j]


def fourier_basis(harmonics: int, phi):
    """((sin, cos - 1), d/dphi, d2/dphi2) of the basis, each an (n, H) pair at phases phi (n,) [cycles]."""
    w = 2 * np.pi * np.arange(1, harmonics + 1)
    ang = np.outer(phi, w)
    s, c = np.sin(ang), np.cos(ang)
    return (s, c - 1.0), (c * w, -s * w), (-s * w**2, -c * w**2)


def fourier_path(a, b, phi):
    """P(phi), dP/dphi, d2P/dphi2 (each (n, 4)) of ``sum_k a_k sin(2 pi k phi) + b_k (cos(2 pi k phi) - 1)``.

    a, b : (H, 4) coefficients; phi : (n,) phase [cycles].
    """
    return tuple(matmul(ba, a) + matmul(bb, b) for ba, bb in fourier_basis(a.shape[0], phi))


@dataclass(frozen=True)
class FourierDesign:
    """A Fourier path (a, b (H, 4); centre (4,)) in ``space`` traversed along ``schedule``."""

    a: np.ndarray
    b: np.ndarray
    centre: np.ndarray
    space: str
    schedule: PhaseSchedule

    def motion(self, geometry, t) -> dict:
        """Reference at times t (n,): x, q, qd, qdd (n, 4) and the IK reach ratio |c/rho| (n, 4)."""
        phi, phid, phidd = self.schedule(t)
        p, p1, p2 = fourier_path(self.a, self.b, phi)
        pos = self.centre + p
        vel = p1 * phid[:, None]
        acc = p2 * (phid**2)[:, None] + p1 * phidd[:, None]
        if self.space == "joint":
            x = sim.forward_kinematics(geometry, pos)
            return {"x": x, "q": pos, "qd": vel, "qdd": acc, "ratio": np.abs(ik_unchecked(geometry, x)[1])}
        return joint_motion(geometry, pos, vel, acc)


def joint_motion(geometry, x, xd, xdd) -> dict:
    """Joint reference from a nacelle reference (each (n, 4)): q = IK(x), qd = J^-1 xd,
    qdd = J^-1 (xdd - Jd qd) with J^-1 = diag(1/Jq) Jx. Also returns the reach ratio |c/rho| (n, 4)."""
    q, ratio = ik_unchecked(geometry, x)
    with np.errstate(divide="ignore", invalid="ignore"):  # Jq = 0 (arm singular) gives inf: caught by callers
        jac = jacobians_unchecked(geometry, q, x)
        qd = np.einsum("nab,nb->na", jac.Jx, xd) / jac.Jq
        jd = jacobian_dot_unchecked(geometry, jac, qd) if np.all(np.isfinite(qd)) else np.full_like(jac.J, np.nan)
        qdd = np.einsum("nab,nb->na", jac.Jx, xdd - np.einsum("nab,nb->na", jd, qd)) / jac.Jq
    return {"x": x, "q": q, "qd": qd, "qdd": qdd, "ratio": np.abs(ratio)}


def design_from_parameters(parameters: dict, duration=None) -> FourierDesign:
    """Rebuild the design stored in a Fourier trajectory's ``parameters`` (optionally stretched uniformly to
    another ``duration``: same path, same cycles, every schedule knot scaled)."""
    p = parameters
    T = p["duration"] if duration is None else float(duration)
    k = T / p["duration"]
    schedule = PhaseSchedule(np.asarray(p["schedule_knots"]) * k, np.asarray(p["schedule_levels"]) / k)
    return FourierDesign(np.asarray(p["a"]), np.asarray(p["b"]), np.asarray(p["centre"]), p["space"], schedule)


def as_processing(processing, dt: float) -> ProcessingSettings:
    """``ProcessingSettings`` from None (defaults at ``dt``), an instance, or a dict of its fields."""
    if processing is None:
        return ProcessingSettings(dt=dt)
    if isinstance(processing, ProcessingSettings):
        return processing
    if isinstance(processing, dict):
        try:
            return ProcessingSettings(**{"dt": dt, **processing})
        except TypeError as exc:
            raise ValueError(f"processing must hold ProcessingSettings fields, got keys {sorted(processing)}: "
                             f"{exc}") from exc
    raise TypeError(f"processing must be None, an ident.processing.filtering.ProcessingSettings or a dict, got "
                    f"{type(processing).__name__}")


def _time_grid(duration: float, dt: float) -> np.ndarray:
    n = int(round(duration / dt)) + 1
    return np.arange(n) * dt


def _check_args(duration, harmonics, base_hz, seed, dt, slow_ratio, slow_fraction, ramp_s, transition_s, space,
                design_factor, max_iter, criterion="cond"):
    def number(name, value, ok, expected):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value) or not ok(value):
            raise ValueError(f"{name} must be {expected}, got {value!r}")

    number("duration", duration, lambda v: v > 0, "a finite number > 0 [s]")
    number("base_hz", base_hz, lambda v: v > 0, "a finite number > 0 [Hz]")
    number("dt", dt, lambda v: 0 < v <= duration / 10, f"a finite number in (0, duration/10 = {duration / 10:g}] [s]")
    number("slow_ratio", slow_ratio, lambda v: 0 < v <= 1, "in (0, 1]")
    number("ramp_s", ramp_s, lambda v: v > 0, "a finite number > 0 [s]")
    number("transition_s", transition_s, lambda v: v > 0, "a finite number > 0 [s]")
    number("slow_fraction", slow_fraction, lambda v: 0 <= v and ramp_s * 2 + transition_s + v * duration < duration,
           f"in [0, 1) with 2 ramp_s + transition_s + slow_fraction duration < duration = {duration:g} s")
    number("design_factor", design_factor, lambda v: 0 < v <= 1, "in (0, 1]")
    for name, value, low in (("harmonics", harmonics, 1), ("max_iter", max_iter, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
        raise TypeError(f"seed must be an int or None, got {seed!r}")
    if space not in SPACES:
        raise ValueError(f"space must be one of {SPACES}, got {space!r}")
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")


START_DRAWS = 8  # random starts tried (from the seed's generator) until the criterion is finite


def fourier_excitation(geometry, duration: float = 10.0, harmonics: int = 5, base_hz: float = 0.5, seed: int = 0,
                       optimise: bool = True, limits=None, theta_nominal=None, *, dt: float = 1e-3,
                       slow_ratio: float = 0.2, slow_fraction: float = 0.3, ramp_s: float = 0.5,
                       transition_s: float = 0.5, space: str = "cartesian", design_factor: float = 0.95,
                       max_iter: int = 60, grid_per_period: int = 12, criterion: str = "cond", processing=None,
                       targets=None) -> Trajectory:
    """An exciting trajectory of ``duration`` [s] sampled at ``dt`` [s] (see the module docstring).

    harmonics : H, number of harmonics per axis; base_hz : wanted fundamental frequency in the fast phase [Hz]
    (rounded so that the path closes); seed : seeds the random start; optimise : False returns the (feasible)
    start; limits : :class:`trajectories.Limits` (default ``Limits()``); theta_nominal : (14,) nominal parameters
    for the torque check and the column scaling (default :func:`trajectories.nominal_parameters`);
    slow_ratio, slow_fraction : phase speed of the slow phase relative to the fast one, and its share of the
    duration; ramp_s, transition_s : durations of the rest-to-slow / fast-to-rest ramps and of the slow-to-fast
    transition [s]; space : ``"cartesian"`` (default) or ``"joint"``; design_factor : limits are multiplied by
    it on the optimiser's coarse grid; max_iter : SLSQP iterations; grid_per_period : coarse-grid samples per
    period of the highest harmonic in the fast phase; criterion : ``"cond"`` (log cond(W diag(theta_nominal)),
    the default) or ``"h"`` (bounded-error: smooth max of the relative half-widths h_j / targets_j,
    :mod:`trajectories.bounded`); processing : ``ident.processing.filtering.ProcessingSettings`` or a dict of its fields
    (the identification's speed threshold and filter window, used by ``"h"``); targets : (14,) for ``"h"``
    (default the nominal parameters).

    Returns a :class:`Trajectory` (kind ``"fourier"``) that passed :func:`trajectories.check_trajectory`; its
    ``parameters`` hold the coefficients, the schedule, the seed, the limits and the optimisation record
    (``cond_start``, ``cond_optimised``: cond(W diag(theta_nominal)) on the coarse grid with the tanh surrogate;
    the full-resolution figure is ``checks["cond_W_scaled"]``; seconds, iterations, amplitude scales).
    Raises :class:`InfeasibleTrajectoryError` when no feasible amplitude is found.
    """
    if not isinstance(geometry, sim.H4Geometry):
        raise TypeError(f"geometry must be a sim.H4Geometry, got {type(geometry).__name__}")
    _check_args(duration, harmonics, base_hz, seed, dt, slow_ratio, slow_fraction, ramp_s, transition_s, space,
                design_factor, max_iter, criterion)
    limits, theta = as_limits(limits), as_theta(theta_nominal)
    t_start = time.perf_counter()
    t_full = _time_grid(duration, dt)
    T = float(t_full[-1])
    shape = PhaseSchedule.slow_fast(T, slow_fraction, slow_ratio, ramp_s, transition_s)
    cycles = max(1, int(round(base_hz * shape.total)))
    schedule = PhaseSchedule.slow_fast(T, slow_fraction, slow_ratio, ramp_s, transition_s, cycles / shape.total)
    fast_hz = float(schedule.levels.max())
    n_grid = max(100, int(math.ceil(grid_per_period * harmonics * fast_hz * T)) + 1)
    if criterion == "h":  # h_j is a supremum over the rows: keep >= 36 rows/s per joint (tests: within ~20 %)
        n_grid = max(n_grid, int(math.ceil(36 * T)) + 1)
    t_grid = np.linspace(0.0, T, n_grid)
    centre = np.asarray(geometry.x_home, float) if space == "cartesian" else \
        sim.inverse_kinematics(geometry, geometry.x_home)
    scale = START_SCALE[space]
    phi, phid, phidd = schedule(t_grid)
    args = (geometry, space, centre, fourier_basis(harmonics, phi), phid, phidd, scale, limits, theta, design_factor)
    if criterion == "cond":
        prob = CoefficientProblem(*args)
    else:
        settings = as_processing(processing, dt)
        prob = HalfwidthProblem(*args, targets=as_targets(targets, len(ident.PARAMETER_NAMES)),
                                speed_threshold=settings.speed_threshold,
                                half_window_s=0.5 * (settings.taps().size - 1) * dt)

    def design(z):
        ab = np.asarray(z).reshape(2, harmonics, 4) * scale
        return FourierDesign(ab[0], ab[1], centre, space, schedule)

    rng = np.random.default_rng(seed)
    decay = 1.0 / np.arange(1, harmonics + 1)
    for draw in range(1, START_DRAWS + 1):
        z0 = (rng.standard_normal((2, harmonics, 4)) * decay[None, :, None]).ravel()
        s0 = prob.largest_feasible_scale(z0)
        if s0 == 0.0:
            raise InfeasibleTrajectoryError("no feasible amplitude found for the random start: the limits leave no "
                                            "room around home (check limits and theta_nominal)")
        z_start = 0.9 * s0 * z0  # strictly inside the constraints
        crit_start = prob.log_cond(z_start)
        # an infinite criterion: the "h" start keeps too few processed rows (slow joints under the speed threshold
        # for a whole filter window) and the optimiser would stop at once: draw another start from the same seed
        if math.isfinite(crit_start):
            break
    else:
        raise InfeasibleTrajectoryError(
            f"no random start of seed {seed} gives a finite {criterion!r} criterion in {START_DRAWS} draws: too few "
            f"processed rows move faster than the speed threshold over a whole filter window (lower "
            f"processing.speed_threshold or numtaps, or lengthen the trajectory)")
    record = {"criterion": criterion, "criterion_start": crit_start, "start_scale": 0.9 * s0,
              "start_draws": draw, "optimised": bool(optimise)}
    z = z_start
    if optimise and max_iter > 0:
        res = prob.optimise(z_start, max_iter)
        z = res.x
        if not prob.feasible(z):  # SLSQP's last iterate may sit slightly outside: shrink onto the feasible side
            record["shrink_after_optimisation"] = prob.largest_feasible_scale(z, s_max=1.0)
            z = record["shrink_after_optimisation"] * z
        if prob.log_cond(z) >= crit_start:  # keep the start if the optimiser did not improve it
            z = z_start
        record.update(nit=int(res.nit), nfev=int(res.nfev), message=str(res.message))
    record["criterion_optimised"] = prob.log_cond(z)
    if criterion == "cond":
        record["cond_start"], record["cond_optimised"] = math.exp(crit_start), math.exp(record["criterion_optimised"])

    final_scale = 1.0
    for _attempt in range(20):  # the coarse grid can miss peaks between its samples
        des = design(final_scale * z)
        m = des.motion(geometry, t_full)
        report = check_samples(geometry, t_full, m["x"], m["q"], m["qd"], m["qdd"], limits, theta,
                               raise_on_violation=False)
        if report["feasible"]:
            break
        final_scale *= 0.97
    else:
        check_samples(geometry, t_full, m["x"], m["q"], m["qd"], m["qdd"], limits, theta)  # raises with details
    record["final_scale"] = final_scale
    record["seconds"] = time.perf_counter() - t_start
    parameters = {
        "space": space, "harmonics": harmonics, "a": des.a, "b": des.b, "centre": des.centre,
        "duration": T, "dt": dt, "cycles": cycles, "base_hz_requested": float(base_hz), "base_hz": fast_hz,
        "slow_ratio": slow_ratio, "slow_fraction": slow_fraction, "ramp_s": ramp_s, "transition_s": transition_s,
        "schedule_knots": schedule.knots, "schedule_levels": schedule.levels, "seed": seed,
        "objective": OBJECTIVES[criterion], "criterion": criterion, "grid_points": n_grid,
        "design_factor": design_factor, "optimisation": record, "limits": limits.to_dict(),
        "theta_nominal": theta, "parameter_names": list(ident.PARAMETER_NAMES),
    }
    return Trajectory(t=t_full, x=m["x"], q=m["q"], qd=m["qd"], qdd=m["qdd"], kind="fourier",
                      parameters=parameters, checks=report)


def fourier_trajectory(geometry, parameters: dict, duration=None, dt=None, kind="fourier") -> Trajectory:
    """Re-evaluate a Fourier trajectory from its ``parameters`` (e.g. a loaded file's), optionally stretched to
    ``duration`` [s] (a uniform slow-down) or resampled at ``dt``; checked (no raise: see ``checks``)."""
    if not isinstance(geometry, sim.H4Geometry):
        raise TypeError(f"geometry must be a sim.H4Geometry, got {type(geometry).__name__}")
    missing = [k for k in ("a", "b", "centre", "space", "duration", "dt", "schedule_knots", "schedule_levels",
                           "limits", "theta_nominal") if k not in parameters]
    if missing:
        raise ValueError(f"parameters must be a Fourier trajectory's parameters, missing {missing}")
    duration = parameters["duration"] if duration is None else duration
    dt = parameters["dt"] if dt is None else dt
    for name, value in (("duration", duration), ("dt", dt)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value) or value <= 0:
            raise ValueError(f"{name} must be a finite number > 0 [s], got {value!r}")
    if dt > duration / 10:
        raise ValueError(f"dt must be <= duration / 10 = {duration / 10:g} s, got {dt!r}")
    dt = float(dt)
    t = _time_grid(float(duration), dt)
    design = design_from_parameters(parameters, float(t[-1]))
    m = design.motion(geometry, t)
    report = check_samples(geometry, t, m["x"], m["q"], m["qd"], m["qdd"], Limits.from_dict(parameters["limits"]),
                           parameters["theta_nominal"], raise_on_violation=False)
    params = dict(parameters, duration=float(t[-1]), dt=dt, schedule_knots=design.schedule.knots,
                  schedule_levels=design.schedule.levels, base_hz=float(design.schedule.levels.max()))
    return Trajectory(t=t, x=m["x"], q=m["q"], qd=m["qd"], qdd=m["qdd"], kind=kind, parameters=params, checks=report)
