"""The closed-loop experiment: the H4 in MuJoCo tracking a reference under joint control at 1 kHz, with
bounded torque noise between the commanded and the applied torque, and encoder quantisation.

Per sample k (period ``dt``, ``substeps`` MuJoCo steps of ``h = dt / substeps``, torque held in between):

    q_meas  = quantise(q_k)                           encoder, ``encoder_counts`` per turn
    qd_est  = VelocityFilter(q_meas)                  the controller's velocity estimate
    tau_cmd = controller(q_ref, qd_ref, q_meas, qd_est, feedforward)     (clipped at +-15 N m)
    tau_app = tau_cmd + e_k,  |e_k| <= delta          the paper's error on the input
    measured torque = tau_cmd  (= G_T V_T: the current reference is what the robot logs)

MuJoCo clips the applied torque at the actuator range; the recorded noise is ``applied - measured`` after that
clipping, which never increases |e|. The ground truth records the exact state at each sample instant and the
acceleration MuJoCo computed from it.
"""

from __future__ import annotations

import importlib.metadata
import time
from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np

from sim.controller import JointController, VelocityFilter, design_joint_controller
from sim.dataset import Dataset, GroundTruth
from sim.kinematics import _jacobians, forward_kinematics
from sim.model import H4Geometry
from sim.truth import TRUE_PARAMETER_ORDER, true_parameters

NOISE_SHAPES = ("uniform", "square", "sine", "array", "none")


class SimulationError(ValueError):
    """Bad simulation input (reference, noise, settings)."""


@dataclass(frozen=True)
class TorqueNoise:
    """Bounded torque noise ``|e| <= bound`` [N m] added to the commanded torque.

    shape: ``uniform`` (i.i.d. in [-bound, bound]), ``square`` (the worst case: +-bound square wave of
    ``frequency_hz`` with a random phase per joint), ``sine`` (bound sin(2 pi f t + phase)), ``array``
    (user-provided ``values`` (n, 4), checked against the bound) or ``none``.
    """

    bound: float = 0.0
    shape: str = "uniform"
    frequency_hz: float = 5.0
    values: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.shape not in NOISE_SHAPES:
            raise SimulationError(f"noise shape must be one of {NOISE_SHAPES}, got {self.shape!r}")
        if not (np.isfinite(self.bound) and self.bound >= 0):
            raise SimulationError(f"noise bound must be a finite number >= 0 [N m], got {self.bound!r}")
        if self.shape in ("square", "sine") and not (self.frequency_hz > 0):
            raise SimulationError(f"noise frequency_hz must be > 0, got {self.frequency_hz!r}")
        if self.shape == "array" and self.values is None:
            raise SimulationError("noise shape 'array' needs values of shape (n, 4)")

    def sample(self, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noise (n, 4) [N m] at sample times t (n,)."""
        n = t.size
        if self.shape == "none" or self.bound == 0.0 and self.shape != "array":
            return np.zeros((n, 4))
        if self.shape == "uniform":
            return rng.uniform(-self.bound, self.bound, (n, 4))
        phase = rng.uniform(0.0, 2 * np.pi, 4)
        arg = 2 * np.pi * self.frequency_hz * t[:, None] + phase
        if self.shape == "square":
            return self.bound * np.where(np.sin(arg) >= 0.0, 1.0, -1.0)
        if self.shape == "sine":
            return self.bound * np.sin(arg)
        values = np.asarray(self.values, dtype=float)
        if values.shape != (n, 4):
            raise SimulationError(f"noise values must have shape ({n}, 4) (one per sample and joint), got {values.shape}")
        if not np.all(np.isfinite(values)) or np.abs(values).max() > self.bound:
            raise SimulationError(f"noise values must be finite and within +-bound = {self.bound} N m, "
                                  f"got max |e| = {np.nanmax(np.abs(values)):.6g}")
        return values.copy()

    def describe(self) -> dict:
        d = asdict(self)
        d.pop("values")
        return d


def quantise(q: np.ndarray, counts_per_turn: int | None) -> np.ndarray:
    """Encoder reading of angles q [rad]: rounded to the nearest count (resolution 2 pi / counts)."""
    if not counts_per_turn:
        return np.array(q, dtype=float)
    res = 2 * np.pi / counts_per_turn
    return np.round(np.asarray(q) / res) * res


def axis_inertia(geometry: H4Geometry, theta, x=None) -> np.ndarray:
    """Inertia seen by each motor at pose x (default home) [kg m^2]: Imot_i + (J^T M J)_ii."""
    theta = np.asarray(theta, dtype=float)
    x = geometry.x_home if x is None else np.asarray(x, dtype=float)
    from sim.kinematics import inverse_kinematics

    q = inverse_kinematics(geometry, x)
    j = _jacobians(geometry, q[None], x[None]).J[0]
    m = np.diag([theta[4], theta[4], theta[4], theta[5]])
    return theta[:4] + np.diag(j.T @ m @ j)


def default_controller(geometry: H4Geometry, theta_nominal, dt: float = 1e-3, bandwidth_hz: float = 15.0,
                       velocity_filter_hz: float = 100.0):
    """Joint controller designed with python-control from a *nominal* parameter vector (never the truth)."""
    design = design_joint_controller(axis_inertia(geometry, theta_nominal), np.asarray(theta_nominal)[6:10],
                                     bandwidth_hz=bandwidth_hz, dt=dt, velocity_filter_hz=velocity_filter_hz)
    return design, JointController.from_design(design)


@dataclass
class SimulationSettings:
    """encoder_counts : counts per motor turn (None: exact angles); velocity_filter_hz : the controller's
    velocity estimate cut-off [Hz]; torque_gain : G_T [N m/V] of the amplifier (the log's V_T = tau / G_T)."""

    encoder_counts: int | None = 20000
    velocity_filter_hz: float = 100.0
    torque_gain: float = 1.5


def _package_versions() -> dict:
    out = {}
    for dist in ("h4bench", "mujoco", "numpy", "scipy", "control", "toppra"):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = None
    return out


def _reference_arrays(reference):
    try:
        t, q, qd, qdd = (np.asarray(getattr(reference, k), dtype=float) for k in ("t", "q", "qd", "qdd"))
    except AttributeError as exc:
        raise SimulationError(f"reference must have arrays t, q, qd, qdd (a Trajectory), got {type(reference).__name__}") from exc
    n = t.size
    for name, arr in (("q", q), ("qd", qd), ("qdd", qdd)):
        if arr.shape != (n, 4) or not np.all(np.isfinite(arr)):
            raise SimulationError(f"reference.{name} must be finite with shape ({n}, 4), got {arr.shape}")
    if n < 3 or np.any(np.diff(t) <= 0):
        raise SimulationError("reference.t must be strictly increasing with at least 3 samples")
    return t, q, qd, qdd


def simulate(model: mujoco.MjModel, reference, *, noise: TorqueNoise | None = None, controller=None,
             feedforward: np.ndarray | None = None, settings: SimulationSettings | None = None, seed: int = 0,
             metadata: dict | None = None, progress=None, theta_true=None) -> tuple[Dataset, GroundTruth]:
    """Run the closed-loop experiment along ``reference`` (t (n,), q, qd, qdd (n, 4)) and return the
    measured :class:`Dataset` and the :class:`GroundTruth`.

    controller : a callable ``(q_ref, qd_ref, q, qd, feedforward=...) -> tau (4,)`` with ``reset()``, e.g. the
    second value of :func:`default_controller` (designed from nominal parameters, never from the truth).
    feedforward : (n, 4) torques added to the controller's output (e.g. inverse dynamics of the reference
    with nominal parameters). progress : optional callable(k, n) called every 1000 samples. theta_true : the
    truth to record when the model is a variant whose parameters ``true_parameters`` cannot read (e.g. the
    extended structure's 22 values of :func:`sim.broken_hypotheses_model`).
    """
    settings = settings or SimulationSettings()
    noise = noise or TorqueNoise(0.0, "none")
    if controller is None:
        raise SimulationError("controller must be given (see sim.default_controller)")
    t, q_ref, qd_ref, qdd_ref = _reference_arrays(reference)
    n = t.size
    dt = float(np.median(np.diff(t)))
    h = model.opt.timestep
    substeps = int(round(dt / h))
    if substeps < 1 or abs(substeps * h - dt) > 1e-9 * dt:
        raise SimulationError(f"the reference's sample period {dt:g} s must be a multiple of the model timestep {h:g} s")
    if feedforward is None:
        feedforward = np.zeros((n, 4))
    feedforward = np.asarray(feedforward, dtype=float)
    if feedforward.shape != (n, 4):
        raise SimulationError(f"feedforward must have shape ({n}, 4), got {feedforward.shape}")

    geometry = H4Geometry.from_model(model)
    rng = np.random.default_rng(seed)
    e = noise.sample(t - t[0], rng)
    data = mujoco.MjData(model)
    x0 = forward_kinematics(geometry, q_ref[0])
    data.qpos[:] = geometry.qpos(q_ref[0], x0)
    data.qvel[:] = 0.0
    mujoco.mj_forward(model, data)
    vfilter = VelocityFilter(dt=dt, cutoff_hz=settings.velocity_filter_hz)
    vfilter.reset(q0=quantise(q_ref[0], settings.encoder_counts))
    controller.reset()

    out = {k: np.empty((n, 4)) for k in ("q", "qd", "qdd", "x", "xdd", "tau_app", "q_meas", "tau_cmd")}
    o_q, o_qd, o_qdd, o_x, o_xdd, o_app, o_qm, o_cmd = (out[k] for k in
                                                       ("q", "qd", "qdd", "x", "xdd", "tau_app", "q_meas", "tau_cmd"))
    ne = data.ne  # equality rows come first in efc and their number is fixed
    efc = np.zeros((n, max(ne, 1)))
    qm, dm, nac = geometry.qpos_motor, geometry.dof_motor, geometry.qpos_nacelle
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    res = 2 * np.pi / settings.encoder_counts if settings.encoder_counts else None
    qpos, qvel, qacc, ctrl, act = data.qpos, data.qvel, data.qacc, data.ctrl, data.actuator_force
    # the controller's unchecked core when it has one (inputs are checked once above)
    law = getattr(controller, "step", None) or (lambda qr, vr, qq, vv, f: controller(qr, vr, qq, vv, feedforward=f))
    step = mujoco.mj_step
    wall = time.perf_counter()
    for k in range(n):
        q_true = qpos[qm]
        q_meas = np.round(q_true / res) * res if res else q_true
        tau_cmd = np.clip(law(q_ref[k], qd_ref[k], q_meas, vfilter.step(q_meas), feedforward[k]), lo, hi)
        ctrl[:] = tau_cmd + e[k]
        o_q[k] = q_true
        o_qd[k] = qvel[dm]
        o_x[k] = qpos[nac]
        o_qm[k] = q_meas
        o_cmd[k] = tau_cmd
        step(model, data)
        o_qdd[k] = qacc[dm]
        o_xdd[k] = qacc[nac]
        o_app[k] = act
        efc[k, :ne] = data.efc_pos[:ne]
        if substeps > 1:
            step(model, data, substeps - 1)
        if progress is not None and k % 1000 == 0:
            progress(k, n)
    violation = np.abs(efc).max(axis=1)
    out["x"] = geometry.nacelle_origin0 + (out["x"] - geometry.nacelle_qpos0)  # raw nacelle qpos -> pose
    wall = time.perf_counter() - wall
    if not np.all(np.isfinite(out["q"])):
        raise SimulationError("the simulation diverged (non-finite state); check the reference and the controller")

    meta = {
        "kind": "simulation",
        "dt": dt,
        "timestep": h,
        "substeps": substeps,
        "seed": seed,
        "noise": noise.describe(),
        "encoder_counts": settings.encoder_counts,
        "velocity_filter_hz": settings.velocity_filter_hz,
        "torque_gain": settings.torque_gain,
        "controller": getattr(controller, "describe", lambda: type(controller).__name__)(),
        "wall_seconds": wall,
        "versions": _package_versions(),
    }
    meta.update(metadata or {})
    dataset = Dataset(t=t.copy(), q=out["q_meas"], tau=out["tau_cmd"], metadata=meta)
    truth = GroundTruth(
        theta=true_parameters(model) if theta_true is None else np.asarray(theta_true, dtype=float), q=out["q"], qd=out["qd"], qdd=out["qdd"], x=out["x"], xdd=out["xdd"],
        tau_applied=out["tau_app"], noise=out["tau_app"] - out["tau_cmd"], loop_violation=violation, h=h,
        names=TRUE_PARAMETER_ORDER,
    )
    return dataset, truth
