"""The 1 kHz joint-control law of the H4 (position P + velocity PI cascade) and its velocity estimate.

Structure and the design rule of the gains: :mod:`sim.control_design` (python-control, loaded only there and
only when a controller is designed). This module imports neither python-control nor matplotlib (nor the design
module): it is what the simulation loop runs.
"""

from __future__ import annotations

import math

import numpy as np

from h4bench.sim.validation import N_JOINTS, axis_array, joint_vector, positive

__all__ = ["TAU_MAX_DEFAULT", "JointController", "VelocityFilter"]

TAU_MAX_DEFAULT = 15.0  # N m: the default torque limit of the law (the H4 actuator range)
# ------------------------------------------------------------------------------------------ the 1 kHz law


class VelocityFilter:
    """Filtered difference of measured (possibly quantised) joint angles, ``c2d(s/(tau s + 1), dt, 'tustin')``.

    ``qd_k = p qd_{k-1} + g (q_k - q_{k-1})`` with ``g = 2/(2 tau + dt)``, ``p = (2 tau - dt)/(2 tau + dt)``,
    ``tau = 1/(2 pi cutoff_hz)``: the velocity estimate :func:`design_joint_controller` assumes.
    dt : sample period [s]; cutoff_hz : -3 dB frequency [Hz], below the Nyquist frequency.
    Call with q (4,) [rad] once per sample; returns qd (4,) [rad/s]. The first call after :meth:`reset`
    (without q0) returns zeros.
    """

    def __init__(self, dt: float = 1e-3, cutoff_hz: float = 100.0) -> None:
        self.dt = positive(dt, "dt")
        self.cutoff_hz = positive(cutoff_hz, "cutoff_hz")
        if self.cutoff_hz >= 0.5 / self.dt:
            raise ValueError(f"cutoff_hz must be below the Nyquist frequency {0.5 / self.dt:g} Hz, "
                             f"got {self.cutoff_hz:g}")
        tau = 1.0 / (2 * math.pi * self.cutoff_hz)
        self.gain = 2.0 / (2.0 * tau + self.dt)
        self.pole = (2.0 * tau - self.dt) / (2.0 * tau + self.dt)
        self.reset()

    def reset(self, q0=None, qd0=None) -> None:
        """Forget the history; optionally start from angle q0 (4,) [rad] and velocity qd0 (4,) [rad/s]."""
        self._q_prev = None if q0 is None else joint_vector(q0, "q0").copy()
        self._qd = np.zeros(N_JOINTS) if qd0 is None else joint_vector(qd0, "qd0").copy()

    def __call__(self, q) -> np.ndarray:
        return self.step(joint_vector(q, "q")).copy()

    def step(self, q: np.ndarray) -> np.ndarray:
        """:meth:`__call__` without input checks, for hot loops: q must be a float (4,) array. Returns the
        filter's state array (do not modify it)."""
        if self._q_prev is None:
            self._q_prev = q.copy()
        self._qd = self.pole * self._qd + self.gain * (q - self._q_prev)
        self._q_prev = q.copy()
        return self._qd


class JointController:
    """Discrete position-P / velocity-PI cascade for the 4 joints, one call per sample period dt.

    kp : (4,) or scalar [1/s]; kv : [N m s/rad]; ki : [N m/rad]; dt : [s]; tau_max : torque limit [N m],
    scalar or (4,) (default 15); inertia_ff : optional (4,) nominal inertia [kg m^2] used as feed-forward
    ``inertia_ff * qdd_ref``.

    Law at sample k (velocity error ``e_k = kp (q_ref - q) + qd_ref - qd``):

        I_k   = I_{k-1} + ki dt/2 (e_k + e_{k-1})          (Tustin, = ct.c2d(ki/s, dt, 'tustin'))
        u_k   = kv e_k + I_k + inertia_ff qdd_ref + feedforward
        tau_k = clip(u_k, -tau_max, tau_max)

    Anti-windup by conditional integration: where ``u_k`` is saturated and ``e_k`` pushes further into the
    limit, ``I_k = I_{k-1}``; I is also clamped to +-tau_max. The torque is meant to be held over the next
    period (zero-order hold), as the design assumes. ``qd`` comes from the caller: the simulator's velocity or,
    with an encoder, a filtered difference such as :class:`VelocityFilter` (the design's ``velocity_filter_hz``
    should then match its cut-off).
    """

    def __init__(self, kp, kv, ki, dt: float = 1e-3, tau_max=TAU_MAX_DEFAULT, inertia_ff=None) -> None:
        self.kp = axis_array(kp, "kp", allow_zero=True)
        self.kv = axis_array(kv, "kv", allow_zero=True)
        self.ki = axis_array(ki, "ki", allow_zero=True)
        self.dt = positive(dt, "dt")
        self.tau_max = axis_array(tau_max, "tau_max", allow_zero=False)
        self.inertia_ff = None if inertia_ff is None else axis_array(inertia_ff, "inertia_ff", allow_zero=True)
        self.reset()

    @classmethod
    def from_design(cls, design, tau_max=TAU_MAX_DEFAULT, inertia_ff="design") -> JointController:
        """Controller with a design's gains.

        Parameters
        ----------
        design : ControllerDesign
            From :func:`design_joint_controller`.
        tau_max : float or (4,) torque limit [N m]
        inertia_ff : "design" (the design's J), None, or (4,) nominal inertia [kg m^2] for ``qdd_ref``

        Returns
        -------
        JointController
        """
        if not callable(getattr(design, "controller", None)):  # duck-typed: the design module imports this one
            raise TypeError(f"design must be a ControllerDesign, got {type(design).__name__}")
        return design.controller(tau_max=tau_max, inertia_ff=inertia_ff)

    def reset(self) -> None:
        """Zero the integrators and the stored previous velocity error."""
        self.integrator = np.zeros(N_JOINTS)
        self._e_prev = np.zeros(N_JOINTS)
        self.saturated = np.zeros(N_JOINTS, dtype=bool)

    def __call__(self, q_ref, qd_ref, q, qd, qdd_ref=None, feedforward=None) -> np.ndarray:
        """Torque (4,) [N m] for references q_ref [rad], qd_ref [rad/s], measures q [rad], qd [rad/s],
        optional qdd_ref [rad/s^2] (needs ``inertia_ff``) and feedforward torque [N m], all (4,)."""
        q_ref = joint_vector(q_ref, "q_ref")
        qd_ref = joint_vector(qd_ref, "qd_ref")
        q = joint_vector(q, "q")
        qd = joint_vector(qd, "qd")
        ff = np.zeros(N_JOINTS)
        if qdd_ref is not None:
            if self.inertia_ff is None:
                raise ValueError("qdd_ref was given but inertia_ff is None: pass inertia_ff to the controller "
                                 "or the feed-forward torque as feedforward")
            ff = ff + self.inertia_ff * joint_vector(qdd_ref, "qdd_ref")
        if feedforward is not None:
            ff = ff + joint_vector(feedforward, "feedforward")
        return self.step(q_ref, qd_ref, q, qd, ff)

    def step(self, q_ref: np.ndarray, qd_ref: np.ndarray, q: np.ndarray, qd: np.ndarray, ff: np.ndarray) -> np.ndarray:
        """The law of :meth:`__call__` without input checks, for hot loops: float (4,) arrays, ``ff`` the
        total feed-forward torque [N m]."""
        e = self.kp * (q_ref - q) + qd_ref - qd
        candidate = np.clip(self.integrator + 0.5 * self.ki * self.dt * (e + self._e_prev),
                            -self.tau_max, self.tau_max)
        u = self.kv * e + candidate + ff
        winding = (np.abs(u) > self.tau_max) & (np.sign(e) == np.sign(u))
        self.integrator = np.where(winding, self.integrator, candidate)
        u = self.kv * e + self.integrator + ff
        self._e_prev = e
        self.saturated = np.abs(u) > self.tau_max
        return np.clip(u, -self.tau_max, self.tau_max)
