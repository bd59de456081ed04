"""The closed-loop experiment: the H4 in MuJoCo tracking a reference under joint control at 1 kHz, with
bounded torque noise between the commanded and the applied torque, and encoder quantisation.

Per sample k (period ``dt``, ``substeps`` MuJoCo steps of ``h = dt / substeps``, torque held in between):

    q_meas  = quantise(q_k)                           encoder, ``encoder_counts`` per turn
    qd_est  = VelocityFilter(q_meas)                  the controller's velocity estimate
    tau_cmd = controller(q_ref, qd_ref, q_meas, qd_est, feedforward)     (clipped at +-15 N m)
    tau_app = tau_cmd + e_k,  e_k = stream.at(k, q_k, tau_cmd)      the error on the input
    logged torque = stream.measured(tau_cmd)  (TorqueNoise: tau_cmd = G_T V_T, the current reference)

The torque error follows a small protocol, so that structured error models (another module) plug in:
``stream = noise.start(t, rng)`` (t (n,) sample times from 0 [s], rng a numpy Generator) gives
``stream.at(k, q, tau_cmd) -> (4,)`` [N m] per sample (q (4,) true motor angles [rad], tau_cmd (4,) the clipped
command) and ``stream.measured(tau_cmd (n, 4)) -> (n, 4)`` the logged torques; optionally ``stream.at_list(k, q, tau_cmd)``,
the same values on lists of 4 Python floats (the loop then keeps the built-in law's floats, no arrays per
sample); ``noise.bound`` [N m] bounds
``|applied - logged|`` and ``noise.describe()`` is a JSON-able dict. :mod:`sim.noise` implements it
(:class:`~sim.noise.TorqueNoise`, one shape; :class:`~sim.noise.TorqueError`, a sum of components); both are
re-exported here.

Each sample is recorded AT the sampled state: ``mj_forward`` with the new command gives MuJoCo's
acceleration, applied (actuator-clipped) torque and loop violation there; then the integrator advances
(``mj_RungeKutta`` for RK4: ``mj_forward`` + ``mj_RungeKutta`` is exactly ``mj_step``, whose ``qacc``
would otherwise be the RK4 step average). The ground truth's noise is ``applied - logged`` after MuJoCo's
clipping, which never increases |e| for TorqueNoise.
"""

from __future__ import annotations

import functools
import importlib.metadata
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from h4bench.portable import matmul
from h4bench.sim.controller import JointController, VelocityFilter
from h4bench.sim.dataset import Dataset, GroundTruth
from h4bench.sim.kinematics import _jacobians, forward_kinematics
from h4bench.sim.model import NACELLE_JOINTS, H4Geometry
from h4bench.sim.noise.shapes import NOISE_SHAPES, PrecomputedTorqueError, TorqueNoise
from h4bench.sim.truth import TRUE_PARAMETER_ORDER, true_parameters
from h4bench.sim.validation import N_JOINTS, SimulationError

__all__ = ["NOISE_SHAPES", "PrecomputedTorqueError", "SimulationError", "SimulationSettings", "TorqueNoise",
           "axis_inertia", "default_controller", "quantise", "simulate"]

def quantise(q: np.ndarray, counts_per_turn: int | None) -> np.ndarray:
    """Encoder reading of angles q [rad]: rounded to the nearest count (resolution 2 pi / counts).

    Parameters
    ----------
    q : array of angles [rad]
    counts_per_turn : counts per turn; None or 0: exact angles

    Returns
    -------
    array of the shape of q [rad]
    """
    if not counts_per_turn:
        return np.array(q, dtype=float)
    res = 2 * np.pi / counts_per_turn
    return np.round(np.asarray(q) / res) * res


def axis_inertia(geometry: H4Geometry, theta, x=None) -> np.ndarray:
    """Inertia seen by each motor at pose x (default home) [kg m^2]: Imot_i + (J^T M J)_ii.

    Parameters
    ----------
    geometry : H4Geometry
    theta : (>= 6,) parameters (Ia1..Ia4 [kg m^2], M [kg], Mz [kg] first)
    x : (4,) nacelle pose (x, y, z [m], rotation [rad]); default ``geometry.x_home``

    Returns
    -------
    (4,) axis inertia [kg m^2]
    """
    theta = np.asarray(theta, dtype=float)
    x = geometry.x_home if x is None else np.asarray(x, dtype=float)
    from h4bench.sim.kinematics import inverse_kinematics

    q = inverse_kinematics(geometry, x)
    j = _jacobians(geometry, q[None], x[None]).J[0]
    m = np.diag([theta[4], theta[4], theta[4], theta[5]])
    return theta[:4] + np.diag(matmul(matmul(j.T, m), j))  # no BLAS: the controller's J on any CPU


def default_controller(geometry: H4Geometry, theta_nominal, dt: float = 1e-3, bandwidth_hz: float = 15.0,
                       velocity_filter_hz: float = 100.0):
    """Joint controller designed with python-control from a *nominal* parameter vector (never the truth).

    Parameters
    ----------
    geometry : H4Geometry
    theta_nominal : (14,) nominal parameters (the order of :data:`sim.TRUE_PARAMETER_ORDER`; Ia1..Ia4, M, Mz
        give the axis inertias, Fv1..Fv4 the viscous friction)
    dt : sample period [s]
    bandwidth_hz : tracking bandwidth of the design [Hz]
    velocity_filter_hz : cut-off of the velocity estimate the law receives [Hz]

    Returns
    -------
    (ControllerDesign, JointController)
        The design (gains, margins) and the law with its gains.
    """
    from h4bench.sim.control_design import design_joint_controller  # noqa: PLC0415 (python-control on use only)

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


@functools.cache
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
        if arr.shape != (n, N_JOINTS) or not np.all(np.isfinite(arr)):
            raise SimulationError(f"reference.{name} must be finite with shape ({n}, {N_JOINTS}), got {arr.shape}")
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

    Parameters
    ----------
    model : mujoco.MjModel of the H4 (its timestep divides the reference's sample period)
    reference : a Trajectory-like object with t (n,) [s], q (n, 4) [rad], qd (n, 4) [rad/s], qdd (n, 4) [rad/s^2]
    noise : torque-error model (the protocol above), default none
    controller, feedforward, progress, theta_true : see above
    settings : SimulationSettings (encoder, velocity filter, torque gain)
    seed : seed of the noise's generator
    metadata : entries added to the dataset's metadata

    Returns
    -------
    (Dataset, GroundTruth)
        The measured log (t, encoder angles, logged torques) and the truth (states, applied torque, noise).
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
        feedforward = np.zeros((n, N_JOINTS))
    feedforward = np.asarray(feedforward, dtype=float)
    if feedforward.shape != (n, N_JOINTS):
        raise SimulationError(f"feedforward must have shape ({n}, {N_JOINTS}), got {feedforward.shape}")

    for attr in ("start", "bound", "describe"):
        if not hasattr(noise, attr):
            raise SimulationError(f"noise must implement the torque-error protocol (start, bound, describe), "
                                  f"got {type(noise).__name__} without {attr!r}")

    geometry = H4Geometry.from_model(model)
    rng = np.random.default_rng(seed)
    stream = noise.start(t - t[0], rng)
    data = mujoco.MjData(model)
    advance = _integrator_step(model, data, substeps)
    x0 = forward_kinematics(geometry, q_ref[0])
    data.qpos[:] = geometry.qpos(q_ref[0], x0)
    data.qvel[:] = 0.0
    mujoco.mj_forward(model, data)
    vfilter = VelocityFilter(dt=dt, cutoff_hz=settings.velocity_filter_hz)
    vfilter.reset(q0=quantise(q_ref[0], settings.encoder_counts))
    controller.reset()
    ne = data.ne  # equality rows come first in efc and their number is fixed
    res = 2 * np.pi / settings.encoder_counts if settings.encoder_counts else None
    lo, hi = model.actuator_ctrlrange[:, 0].copy(), model.actuator_ctrlrange[:, 1].copy()
    if type(controller) is JointController:  # same law on Python floats (numpy costs ~1 us per call on (4,))
        law = _FloatLaw(controller, vfilter, res, lo, hi, q_ref, qd_ref, feedforward)
    else:
        law = _ArrayLaw(controller, vfilter, res, lo, hi, q_ref, qd_ref, feedforward)

    rec_qpos, rec_qvel, rec_qacc = np.empty((n, model.nq)), np.empty((n, model.nv)), np.empty((n, model.nv))
    rec_app, efc = np.empty((n, N_JOINTS)), np.zeros((n, max(ne, 1)))
    rec_cmd, rec_qm = [], []
    qm = _index(geometry.qpos_motor)
    qpos, qvel, qacc, ctrl, act, efc_pos = data.qpos, data.qvel, data.qacc, data.ctrl, data.actuator_force, data.efc_pos
    if isinstance(law, _FloatLaw) and callable(getattr(stream, "at_list", None)):
        at = stream.at_list  # floats from the state to ctrl: no array per sample
    else:
        at = _array_at(stream.at)
    append_cmd, append_qm = rec_cmd.append, rec_qm.append
    wall = time.perf_counter()
    compiled = False
    try:
        if isinstance(law, _FloatLaw):  # the same loop in compiled code when it is built and applies
            from h4bench.sim.compiled import compiled_loop  # noqa: PLC0415

            cmd_arr, qm_arr = np.empty((n, N_JOINTS)), np.empty((n, N_JOINTS))
            compiled = compiled_loop(law, stream, model, data, qm, n, substeps, efc_pos,
                                     (rec_qpos, rec_qvel, rec_qacc, rec_app, efc, cmd_arr, qm_arr), progress)
        if not compiled:
            _loop(n, qpos, qvel, qacc, qm, law.step_list, ctrl, at, mujoco.mj_forward, model, data, rec_qpos,
                  rec_qvel, rec_qacc, rec_app, act, efc, efc_pos, ne, append_cmd, append_qm, advance, progress)
    except ValueError as exc:  # e.g. rounding a NaN angle: the state diverged
        if np.all(np.isfinite(qpos)):
            raise
        raise SimulationError(f"the simulation diverged (non-finite state at t = {data.time:.4f} s); check the "
                              "reference and the controller") from exc
    wall = time.perf_counter() - wall
    law.finish()
    if compiled:
        rec_cmd, rec_qm = cmd_arr, qm_arr
    else:
        rec_cmd, rec_qm = np.array(rec_cmd, dtype=float), np.array(rec_qm, dtype=float)
    if not np.all(np.isfinite(rec_qpos)):
        raise SimulationError("the simulation diverged (non-finite state); check the reference and the controller")
    violation = np.abs(efc).max(axis=1)
    dm = geometry.dof_motor
    nac_dof = model.jnt_dofadr[[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in NACELLE_JOINTS]]
    logged = np.asarray(stream.measured(rec_cmd.copy()), dtype=float)
    if logged.shape != (n, N_JOINTS):
        raise SimulationError(f"noise stream's measured() must return shape ({n}, {N_JOINTS}), got {logged.shape}")

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
        "mujoco_warnings": {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(data.warning) if w.number},
        "versions": dict(_package_versions()),  # read once per process
    }
    meta.update(metadata or {})
    dataset = Dataset(t=t.copy(), q=rec_qm, tau=logged, metadata=meta)
    truth = GroundTruth(
        theta=true_parameters(model) if theta_true is None else np.asarray(theta_true, dtype=float),
        q=rec_qpos[:, geometry.qpos_motor], qd=rec_qvel[:, dm], qdd=rec_qacc[:, dm],
        x=geometry.nacelle_pose(rec_qpos), xdd=rec_qacc[:, nac_dof],
        tau_applied=rec_app, noise=rec_app - logged, loop_violation=violation, h=h, names=TRUE_PARAMETER_ORDER,
    )
    return dataset, truth


def _loop(n, qpos, qvel, qacc, qm, law_step, ctrl, at, forward, model, data, rec_qpos, rec_qvel, rec_qacc,
          rec_app, act, efc, efc_pos, ne, append_cmd, append_qm, advance, progress):
    """The 1 kHz sample loop of :func:`simulate` (locals only: the loop is the simulator's bottleneck). The true
    angles go to the law and the error stream as a list of floats; the applied torque is ``tau_cmd + e`` per
    joint (the same IEEE sums as numpy's)."""
    for k in range(n):
        q_true = qpos[qm].tolist()
        q_meas, tau_cmd = law_step(k, q_true)
        e0, e1, e2, e3 = at(k, q_true, tau_cmd)
        t0, t1, t2, t3 = tau_cmd
        ctrl[:] = (t0 + e0, t1 + e1, t2 + e2, t3 + e3)
        forward(model, data)  # at the sampled state: MuJoCo's qacc, applied torque, loop violation
        rec_qpos[k] = qpos
        rec_qvel[k] = qvel
        rec_qacc[k] = qacc
        rec_app[k] = act
        efc[k, :ne] = efc_pos[:ne]
        append_cmd(tau_cmd)
        append_qm(q_meas)
        advance()
        if progress is not None and k % 1000 == 0:
            progress(k, n)


def _array_at(at):
    """A stream's ``at(k, q, tau_cmd)`` for :func:`_loop`: the protocol's (4,) arrays built from its lists (a new
    array each sample: the stream may keep them)."""
    def at_arrays(k, q, tau_cmd, _array=np.array):
        return at(k, _array(q, dtype=float), _array(tau_cmd, dtype=float))
    return at_arrays


def _index(addresses: np.ndarray):
    """A basic slice for evenly spaced addresses (cheaper than fancy indexing in the loop), else the array."""
    a = np.asarray(addresses)
    step = int(a[1] - a[0]) if a.size > 1 else 1
    if step > 0 and np.array_equal(a, a[0] + step * np.arange(a.size)):
        return slice(int(a[0]), int(a[-1]) + 1, step)
    return a


def _integrator_step(model: mujoco.MjModel, data: mujoco.MjData, substeps: int):
    """``advance()``: the rest of one sample period (``substeps`` MuJoCo steps) after ``mj_forward`` at the
    current state; the first step reuses that ``mj_forward``, as ``mj_step`` would."""
    integ = mujoco.mjtIntegrator(model.opt.integrator)
    first = {mujoco.mjtIntegrator.mjINT_RK4: functools.partial(mujoco.mj_RungeKutta, model, data, 4),
             mujoco.mjtIntegrator.mjINT_EULER: functools.partial(mujoco.mj_Euler, model, data),
             mujoco.mjtIntegrator.mjINT_IMPLICIT: functools.partial(mujoco.mj_implicit, model, data),
             mujoco.mjtIntegrator.mjINT_IMPLICITFAST: functools.partial(mujoco.mj_implicit, model, data)}.get(integ)
    if first is None:
        raise SimulationError(f"model integrator {integ.name} is not supported by simulate")
    if substeps == 1:
        return first

    def advance(_first=first, _step=mujoco.mj_step):
        _first()
        _step(model, data, substeps - 1)
    return advance


class _ArrayLaw:
    """Any controller: ``controller.step(q_ref, qd_ref, q, qd, ff)`` (or its call) on (4,) arrays."""

    def __init__(self, controller, vfilter, res, lo, hi, q_ref, qd_ref, ff):
        self.law = getattr(controller, "step", None) or (
            lambda qr, vr, qq, vv, f: controller(qr, vr, qq, vv, feedforward=f))
        self.vfilter, self.res, self.lo, self.hi = vfilter, res, lo, hi
        self.q_ref, self.qd_ref, self.ff = q_ref, qd_ref, ff

    def step_list(self, k, q_true):
        """One sample: q_true a list of 4 floats [rad]; returns (q_meas, tau) (4,) arrays."""
        q_true = np.array(q_true, dtype=float)
        res = self.res
        q_meas = np.round(q_true / res) * res if res else q_true
        tau = np.clip(self.law(self.q_ref[k], self.qd_ref[k], q_meas, self.vfilter.step(q_meas), self.ff[k]),
                      self.lo, self.hi)
        return q_meas, tau

    def finish(self):
        pass


class _FloatLaw:
    """:meth:`JointController.step` after :meth:`VelocityFilter.step` and the encoder rounding, operation for
    operation on Python floats (the same IEEE results; a test checks the two paths agree bit for bit). The
    controller's and filter's states are read at the start and written back by :meth:`finish`."""

    def __init__(self, c: JointController, vf: VelocityFilter, res, lo, hi, q_ref, qd_ref, ff):
        self.c, self.vf, self.res = c, vf, res
        self.gains = list(zip(c.kp.tolist(), c.kv.tolist(), (0.5 * c.ki * c.dt).tolist(),
                              [(-t, t, lo_i, hi_i) for t, lo_i, hi_i in zip(c.tau_max.tolist(), lo.tolist(),
                                                                           hi.tolist())]))
        self.integ, self.e_prev, self.sat = c.integrator.tolist(), c._e_prev.tolist(), c.saturated.tolist()
        self.pole, self.gain = vf.pole, vf.gain
        self.qd_est = vf._qd.tolist()
        self.q_prev = None if vf._q_prev is None else vf._q_prev.tolist()
        self.q_ref, self.qd_ref, self.ff = q_ref, qd_ref, ff  # arrays (n, 4); as lists once the Python loop runs
        self._rows = None

    def step_list(self, k, q_true):
        """:meth:`step` with q_true a list of 4 floats [rad]; returns (q_meas, tau) lists."""
        if self._rows is None:
            self._rows = (self.q_ref.tolist(), self.qd_ref.tolist(), self.ff.tolist())
        q_ref, qd_ref, ff = self._rows
        res = self.res
        qm = [round(v / res) * res for v in q_true] if res else q_true
        q_prev = qm if self.q_prev is None else self.q_prev
        p, g = self.pole, self.gain
        integ, e_prev, qd_est, tau, sat = [], [], [], [], []
        for (kp, kv, kidt, (nt, t, lo, hi)), qmi, qpi, vi, ii, epi, qri, vri, fi in zip(
                self.gains, qm, q_prev, self.qd_est, self.integ, self.e_prev, q_ref[k], qd_ref[k], ff[k]):
            v = p * vi + g * (qmi - qpi)  # VelocityFilter.step
            e = kp * (qri - qmi) + vri - v  # JointController.step from here
            cand = ii + kidt * (e + epi)
            cand = nt if cand < nt else (t if cand > t else cand)
            u = kv * e + cand + fi
            if not (abs(u) > t and (e > 0) - (e < 0) == (u > 0) - (u < 0)):
                ii = cand
            u = kv * e + ii + fi
            qd_est.append(v)
            e_prev.append(e)
            integ.append(ii)
            sat.append(abs(u) > t)
            u = nt if u < nt else (t if u > t else u)
            tau.append(hi if u > hi else (lo if u < lo else u))  # simulate's clip at the actuator range
        self.q_prev, self.qd_est, self.integ, self.e_prev, self.sat = qm, qd_est, integ, e_prev, sat
        return qm, tau

    def finish(self):
        c, vf = self.c, self.vf
        c.integrator, c._e_prev, c.saturated = np.array(self.integ), np.array(self.e_prev), np.array(self.sat)
        vf._qd, vf._q_prev = np.array(self.qd_est), np.array(self.q_prev)
