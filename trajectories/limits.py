"""Limits a reference trajectory of the H4 must respect, and the nominal parameter vector used to check torques.

Every default below is a documented placeholder of the right order for a direct-drive H4 (no public figures):

==================  ==============================  ==========================================================
limit               default                         source / reason
==================  ==============================  ==========================================================
workspace box       |x|, |y| <= 0.12 m,             placeholder: a box around home (0, 0, -0.55, 0) inside the
                    z in [-0.72, -0.40] m,          reachable set of ``models/h4.xml``; cond(Jx) <= 82 in it.
                    |theta| <= 0.5 rad              Reachability by IK is checked as well (top corners are not).
joint range         geometry.q_range shrunk by      MJCF motor joint range (-70, 80 deg); 0.05 rad (2.9 deg)
                    q_margin = 0.05 rad             kept from the hard stops for tracking errors
singularity         cond(Jx) <= 100                 cond(Jx) = 29.7 at home (models/README.md); 100 leaves a
                                                    3x margin before the kinematics lose accuracy
joint speed         |qd| <= 8 rad/s                 placeholder: direct-drive brushless motor, order 1000 rpm
joint acceleration  |qdd| <= 150 rad/s^2            placeholder: 15 N m over ~0.02-0.1 kg m^2 reflected
motor torque        |tau| <= 0.8 x 15 N m           paper sec. 4.2: +-15 N m measurement range; 20 % kept for
                                                    the controller's authority and the error budget
==================  ==============================  ==========================================================

H4-class envelope (:meth:`Limits.h4_class`, used by :func:`trajectories.design_excitation`). The defaults
above reach about 1.1 m/s and 1.3 g, far below what the H4 family does; narrow guaranteed boxes need the
motion's amplitude (the bounded-error half-widths shrink in proportion to it, see
:mod:`trajectories.bounded`). Sources and placeholders:

==================  ==============================  ==========================================================
limit               H4-class value                  source / reason
==================  ==============================  ==========================================================
nacelle speed       |xd[:3]| <= 5.5 m/s             Par4, the H4's successor (Nabat, Company, Krut & Pierrot,
                                                    "Par4: very high speed parallel robot for pick-and-place",
                                                    IROS 2005; IEEE T-RO optimal-design paper): 5.5 m/s reached
nacelle accel.      |xdd[:3]| <= 165 m/s^2 (16.8 g)  same source: 165 m/s^2 reached. No H4 figure was found
                                                    (Pierrot, Marquet, Company & Gil, ICRA 2001 give none we
                                                    could read): the Par4 figures are used as a ceiling
joint speed         |qd| <= 30 rad/s                placeholder: 9 m/s at the 0.3 m arm tip of models/h4.xml,
                                                    enough for the nacelle's 5.5 m/s through J
joint acceleration  |qdd| <= 2000 rad/s^2           placeholder: 600 m/s^2 at the arm tip; in practice the
                                                    torque limit binds first (Imot 0.012 kg m^2 alone needs
                                                    24 N m at 2000 rad/s^2)
motor torque        |tau| <= 0.8 x 15 N m           models/h4.xml actuator ctrlrange/forcerange +-15 N m (the
                                                    paper's measurement range, sec. 4.2); 3 N m kept: 1.5 N m
                                                    for the torque error the bound allows and 1.5 N m of
                                                    feedback authority for the joint controller
workspace box       as above                        placeholder (no public H4 workspace figures)
singularity         cond(Jx) <= 100                 as above (the closed loops' exactness is checked below 100)
==================  ==============================  ==========================================================

The torque check uses the paper's model ``ident.inverse_dynamics`` on a nominal parameter vector
(:func:`nominal_parameters`): the paper's a-priori values (Table 1: Imot = 0.012 kg m^2, Mnac = 1.0 kg),
Ibc = 0.003 kg m^2 (Table 2's estimate 0.0030; Table 1's a-priori 0.0008 is smaller and would under-state the
nacelle's inertial torque) and Table 2's frictions rounded (Fv = 0.16, 0.06, 0.09, 0.09 N m s/rad;
Fs = 1.15, 1.10, 0.72, 0.99 N m).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from h4bench.ident import PARAMETER_NAMES
from h4bench.ident import NOMINAL_PARAMETERS  # the one definition, in ident.robots.h4 (its source is documented there)


def nominal_parameters() -> np.ndarray:
    """The nominal parameter vector (14,) in :data:`ident.PARAMETER_NAMES` order (SI units)."""
    return np.asarray(NOMINAL_PARAMETERS, dtype=float)


def as_theta(theta_nominal) -> np.ndarray:
    """Validate a nominal parameter vector (``None`` -> :func:`nominal_parameters`)."""
    if theta_nominal is None:
        return nominal_parameters()
    theta = np.asarray(theta_nominal, dtype=float)
    if theta.shape != (len(PARAMETER_NAMES),):
        raise ValueError(f"theta_nominal must have shape ({len(PARAMETER_NAMES)},) in ident.PARAMETER_NAMES order, "
                         f"got {theta.shape}")
    if not np.all(np.isfinite(theta)) or np.any(theta < 0):
        raise ValueError(f"theta_nominal must be finite and >= 0, got {theta.tolist()}")
    return theta


class InfeasibleTrajectoryError(ValueError):
    """A trajectory sample violates a limit.

    Attributes: ``check`` (name of the violated check, see :data:`trajectories.checks.CHECKS`), ``index`` and
    ``time`` of the first violating sample, ``label`` (joint or axis), ``value``, ``lower``, ``upper`` (the limit),
    ``violations`` (check name -> number of violating samples, over the whole trajectory).
    """

    def __init__(self, message, *, check=None, index=None, time=None, label=None, value=None, lower=None,
                 upper=None, violations=None):
        super().__init__(message)
        self.check, self.index, self.time, self.label = check, index, time, label
        self.value, self.lower, self.upper = value, lower, upper
        self.violations = dict(violations or {})


def _per_joint(name: str, value) -> tuple[float, float, float, float]:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (4,)) if np.ndim(value) == 0 else np.asarray(value, float)
    if arr.shape != (4,):
        raise ValueError(f"Limits.{name} must be a scalar or have shape (4,), got {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ValueError(f"Limits.{name} must be finite and > 0, got {arr.tolist()}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class Limits:
    """Limits for H4 reference trajectories (defaults: see the module docstring).

    x_lower, x_upper : (4,) workspace box on the nacelle pose (x, y, z, theta) [m, m, m, rad];
    q_margin : distance kept from ``geometry.q_range`` at both ends [rad];
    xd_max, xdd_max : nacelle translational speed [m/s] and acceleration [m/s^2] caps (Euclidean norm of the
    x, y, z part of ``J qd`` and ``J qdd + Jd qd``; default inf: unchecked);
    max_cond_jx : upper bound on cond(Jx) (2-norm);
    qd_max : (4,) or scalar joint speed limit [rad/s]; qdd_max : joint acceleration limit [rad/s^2];
    tau_max : motor torque range [N m]; torque_margin : fraction of ``tau_max`` a trajectory may use.
    """

    x_lower: tuple[float, ...] = (-0.12, -0.12, -0.72, -0.5)
    x_upper: tuple[float, ...] = (0.12, 0.12, -0.40, 0.5)
    q_margin: float = 0.05
    max_cond_jx: float = 100.0
    qd_max: tuple[float, ...] = field(default=(8.0,) * 4)
    qdd_max: tuple[float, ...] = field(default=(150.0,) * 4)
    tau_max: tuple[float, ...] = field(default=(15.0,) * 4)
    torque_margin: float = 0.8
    xd_max: float = math.inf
    xdd_max: float = math.inf

    @classmethod
    def h4_class(cls, **overrides) -> "Limits":
        """The H4-class performance envelope (module docstring: sources and placeholders); keyword overrides."""
        values = dict(qd_max=(30.0,) * 4, qdd_max=(2000.0,) * 4, xd_max=5.5, xdd_max=165.0)
        values.update(overrides)
        return cls(**values)

    def __post_init__(self) -> None:
        for name in ("x_lower", "x_upper"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (4,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"Limits.{name} must be 4 finite values (x, y, z, theta), got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(v) for v in arr))
        if not all(lo < hi for lo, hi in zip(self.x_lower, self.x_upper)):
            raise ValueError(f"Limits.x_lower must be < x_upper on every axis, got {self.x_lower} and {self.x_upper}")
        for name in ("qd_max", "qdd_max", "tau_max"):
            object.__setattr__(self, name, _per_joint(name, getattr(self, name)))
        q_margin, torque_margin = float(self.q_margin), float(self.torque_margin)
        if not 0.0 <= q_margin <= 1.0:
            raise ValueError(f"Limits.q_margin must be in [0, 1] rad, got {self.q_margin!r}")
        if not 0.0 < torque_margin <= 1.0:
            raise ValueError(f"Limits.torque_margin must be in (0, 1], got {self.torque_margin!r}")
        object.__setattr__(self, "q_margin", q_margin)
        object.__setattr__(self, "torque_margin", torque_margin)
        if not (math.isfinite(self.max_cond_jx) and self.max_cond_jx >= 1.0):
            raise ValueError(f"Limits.max_cond_jx must be finite and >= 1, got {self.max_cond_jx!r}")
        object.__setattr__(self, "max_cond_jx", float(self.max_cond_jx))
        for name in ("xd_max", "xdd_max"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or math.isnan(value) or value <= 0:
                raise ValueError(f"Limits.{name} must be a number > 0 (inf: unchecked), got {value!r}")
            object.__setattr__(self, name, float(value))

    @property
    def tau_allowed(self) -> np.ndarray:
        """(4,) peak |tau| a trajectory may use: ``torque_margin * tau_max`` [N m]."""
        return self.torque_margin * np.asarray(self.tau_max)

    def q_bounds(self, geometry) -> tuple[np.ndarray, np.ndarray]:
        """(4,), (4,) allowed motor angles: ``geometry.q_range`` shrunk by ``q_margin`` [rad]."""
        lo = geometry.q_range[:, 0] + self.q_margin
        hi = geometry.q_range[:, 1] - self.q_margin
        if np.any(lo >= hi):
            raise ValueError(f"Limits.q_margin = {self.q_margin} leaves no joint range of {geometry.q_range.tolist()}")
        return lo, hi

    def to_dict(self) -> dict:
        """JSON-ready (infinite caps become the string ``"inf"``)."""
        return {k: (list(v) if isinstance(v, tuple) else ("inf" if v == math.inf else v))
                for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> "Limits":
        return cls(**{k: (tuple(v) if isinstance(v, list) else (math.inf if v == "inf" else v))
                      for k, v in data.items()})


def as_limits(limits) -> Limits:
    if limits is None:
        return Limits()
    if not isinstance(limits, Limits):
        raise TypeError(f"limits must be a trajectories.Limits, got {type(limits).__name__}")
    return limits
