"""A simulated log of a serial arm with a known truth: what a user's drive log looks like, made with pinocchio.

The true motion is analytic (a sum of sines per joint: exact positions, speeds and accelerations, and exact
bounds on ``|qd|`` and ``|qdd|``), the torques are pinocchio's RNEA of the URDF's inertias plus viscous and
Coulomb friction, rotor inertia and a constant offset per joint (an independent path: no regressor in it), the
positions are rounded to an encoder's counts, and the logged torque carries a bounded, structured error (a slow
sine of 5/8 of the bound plus uniform noise of 3/8: low-frequency errors survive any kernel, so the bound is
really used). Torques are logged at the sample instants (``torque_timing = "sample"``).

The specification the log is honest about (:func:`arm_spec`) states the encoder, the sample period, the torque
error, the motion bounds (the analytic ones) and the torque rate of the applied torque apart from the Coulomb
steps (sampled finely from the truth, with a margin); the Coulomb steps at the reversals are left to the
certified equation, which derives their effect from the Coulomb column (``ident.processing.weakform``).

Used by ``benchmarks/bench_serial_certified.py``, the tests and the arm example (``examples/``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ArmLog", "arm_log", "arm_spec", "fixed_fingers_urdf", "write_arm_csv"]


@dataclass(frozen=True)
class ArmLog:
    """q (N, n) measured positions [rad]; tau (N, n) logged torques [N m]; dt [s]; theta (p,) true standard
    parameters (``SerialRobot.names`` order); qd_max, qdd_max (n,) analytic bounds of the true motion;
    qd_peak, qdd_peak (n,) the true motion's sampled peaks; torque_rate (n,) the stated bound of |d tau/dt| apart
    from the Coulomb steps [N m/s]; counts (encoder counts per turn); torque_error [N m]; q_true (N, n)."""

    q: np.ndarray
    tau: np.ndarray
    dt: float
    theta: np.ndarray
    qd_max: np.ndarray
    qdd_max: np.ndarray
    qd_peak: np.ndarray
    qdd_peak: np.ndarray
    torque_rate: np.ndarray
    counts: int
    torque_error: float
    q_true: np.ndarray


def _motion(n: int, rng, lo, hi, speed: float):
    """Sum of three sines per joint centred in the joint range; amplitudes scaled to the peak speed ``speed``."""
    om = np.array([0.9, 1.7, 2.9]) * 2 * np.pi / 4  # rad/s: periods about 4.4, 2.4, 1.4 s
    a = rng.uniform(0.3, 1.0, (n, 3))
    a *= speed / (a * om).sum(axis=1, keepdims=True)
    ph = rng.uniform(0, 2 * np.pi, (n, 3))
    amp = a.sum(axis=1)
    c = np.clip(0.5 * (lo + hi), lo + amp, hi - amp)  # within the limits where they allow it

    def states(t):
        arg = om[None, None, :] * np.asarray(t)[:, None, None] + ph[None]
        return (c + (a * np.sin(arg)).sum(-1), (a * om * np.cos(arg)).sum(-1), -(a * om**2 * np.sin(arg)).sum(-1))

    return states, (a * om).sum(axis=1), (a * om**2).sum(axis=1)


def arm_log(robot, *, seconds: float = 12.0, dt: float = 1e-3, counts: int = 2**17, torque_error: float = 0.8,
            speed: float = 1.5, seed: int = 0) -> ArmLog:
    """Simulate the log of ``robot`` (:class:`ident.robots.serial.SerialRobot` with friction, rotor inertia and
    offsets) under the module docstring's model. speed : peak joint speed bound [rad/s]; seed : motion, friction
    and noise."""
    import pinocchio as pin

    rng = np.random.default_rng(seed)
    n = robot.n_joints
    model, data = robot.model, robot.data
    lo = np.maximum(np.asarray(model.lowerPositionLimit, float), -np.pi)
    hi = np.minimum(np.asarray(model.upperPositionLimit, float), np.pi)
    states, qd_max, qdd_max = _motion(n, rng, lo, hi, speed)
    fv, fs = rng.uniform(0.5, 3.0, n), rng.uniform(0.5, 2.0, n)
    Ia, off = rng.uniform(0.01, 0.3, n), rng.uniform(-0.5, 0.5, n)
    theta = robot.urdf_parameters({"fv": fv, "fs": fs, "Ia": Ia, "off": off})

    def torques(q, qd, qdd, coulomb=True):
        tau = np.array([pin.rnea(model, data, q[k], qd[k], qdd[k]) for k in range(q.shape[0])])
        return tau + fv * qd + (fs * np.sign(qd) if coulomb else 0.0) + Ia * qdd + off

    N = int(round(seconds / dt)) + 1
    t = np.arange(N) * dt
    q, qd, qdd = states(t)
    tau = torques(q, qd, qdd)
    # the applied torque's rate apart from the Coulomb steps: 8 points per sample step, 1.5x the largest slope
    tf = np.arange(8 * (N - 1) + 1) * (dt / 8)
    smooth = torques(*states(tf), coulomb=False)
    rate = 1.5 * np.max(np.abs(np.diff(smooth, axis=0)), axis=0) / (dt / 8)
    res = 2 * np.pi / counts
    q_meas = np.round(q / res) * res
    ph = rng.uniform(0, 2 * np.pi, n)
    err = 0.625 * np.sin(2 * np.pi * 0.37 * t[:, None] + ph) + 0.375 * rng.uniform(-1, 1, (N, n))
    return ArmLog(q=q_meas, tau=tau + torque_error * err, dt=dt, theta=theta, qd_max=qd_max, qdd_max=qdd_max,
                  qd_peak=np.max(np.abs(qd), axis=0), qdd_peak=np.max(np.abs(qdd), axis=0), torque_rate=rate,
                  counts=int(counts), torque_error=float(torque_error), q_true=q)


def arm_spec(log: ArmLog, *, qd_scale: float = 1.0, qdd_scale: float = 1.0) -> dict:
    """The ``[error_model]`` table that states the log's truth (``qd_scale``/``qdd_scale`` understate or overstate
    the motion bounds, to test the checks), with its sources."""
    return {
        "sample_period": log.dt, "counts_per_turn": log.counts, "position_rounding": "nearest",
        "torque_timing": "sample", "torque_error": log.torque_error,
        "torque_rate": [float(v) for v in log.torque_rate],
        "qd_max": [float(v) * qd_scale for v in log.qd_max], "qdd_max": [float(v) * qdd_scale for v in log.qdd_max],
        "sources": {
            "counts_per_turn": "encoder data sheet (simulated: positions rounded to the counts)",
            "torque_error": "drive data sheet (simulated: bounded slow sine + uniform noise)",
            "torque_rate": "bound of |d tau/dt| apart from the Coulomb steps (simulated: 1.5x the sampled peak)",
            "qd_max": "stated bound of the motion (simulated: the analytic bound)",
            "qdd_max": "stated bound of the motion (simulated: the analytic bound)",
        },
    }


def write_arm_csv(log: ArmLog, path, spec_path=None, spec: dict | None = None) -> None:
    """Write the log as the CSV ``identify`` reads (``t, q1..qn, tau1..taun``, full precision) and, with
    ``spec_path``, the specification as a TOML ``[error_model]`` table (``spec`` or :func:`arm_spec`)."""
    from h4bench.scenarios.export import log_csv_text, spec_toml_text
    from h4bench.sim.dataset import atomic_write_bytes

    t = np.arange(log.q.shape[0]) * log.dt
    atomic_write_bytes(Path(path), log_csv_text(t, log.q, log.tau).encode())
    if spec_path is not None:
        atomic_write_bytes(Path(spec_path), spec_toml_text(spec if spec is not None else arm_spec(log)).encode())


def fixed_fingers_urdf(urdf, out) -> Path:
    """A copy of a URDF with every prismatic joint fixed (e.g. a gripper's fingers), so that the arm is a chain of
    revolute joints, written to ``out``; the URDF itself when it has no prismatic joint."""
    import re

    text = Path(urdf).read_text()
    fixed = re.sub(r'(<joint\b[^>]*\btype=")prismatic(")', r"\1fixed\2", text)
    if fixed == text:
        return Path(urdf)
    Path(out).write_text(fixed)
    return Path(out)
