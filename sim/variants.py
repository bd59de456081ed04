"""Variants of the H4 model edited with ``mujoco.MjSpec`` (no XML written): randomised true parameters for
Monte Carlo campaigns, and robots that break the paper's hypotheses (unbalanced arms)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from h4bench.sim.model import (
    DEFAULT_MODEL_PATH,
    MOTOR_JOINTS,
    ModelError,
    _check_structure,
    apply_solver_constants,
    assemble_loops,
)


def _spec(path) -> mujoco.MjSpec:
    path = Path(DEFAULT_MODEL_PATH if path is None else path)
    if not path.is_file():
        raise ModelError(f"model path must be an existing MJCF file, got {str(path)!r} (not found)")
    try:
        return mujoco.MjSpec.from_file(str(path))
    except Exception as exc:
        raise ModelError(f"model path {str(path)!r} is not a valid MJCF model: {exc}") from exc


def _compile(spec: mujoco.MjSpec, path) -> mujoco.MjModel:
    model = spec.compile()
    _check_structure(model, path)
    assemble_loops(model, path)  # a model written back by MuJoCo (6 digits), as sim.load_model
    return apply_solver_constants(model)


def randomised_model(seed: int, spread: float = 0.3, path=None) -> mujoco.MjModel:
    """The H4 with its identifiable physical quantities scaled by independent factors in [1 - spread, 1 + spread]:
    each motor's armature, damping and frictionloss, each arm's inertia about its axis, the central bar's mass
    and vertical inertia, the lateral bars' mass (both by one factor, keeping the nacelle's centre of mass at
    D). Geometry is unchanged. The true parameters follow from ``sim.true_parameters`` of the result.

    Parameters
    ----------
    seed : seed of the factors' generator
    spread : half-width of the factors' interval, in [0, 1)
    path : the MJCF file, or None (the default model)

    Returns
    -------
    mujoco.MjModel
    """
    if not 0.0 <= spread < 1.0:
        raise ValueError(f"spread must be in [0, 1), got {spread!r}")
    rng = np.random.default_rng(seed)

    def factor():
        return float(rng.uniform(1.0 - spread, 1.0 + spread))

    spec = _spec(path)
    for i, name in enumerate(MOTOR_JOINTS):
        joint = spec.joint(name)
        joint.armature = joint.armature * factor()
        joint.damping = np.asarray(joint.damping) * factor()
        joint.frictionloss = joint.frictionloss * factor()
        arm = spec.body(f"arm{i + 1}")
        arm.inertia = np.asarray(arm.inertia) * factor()
    nacelle = spec.body("nacelle")
    nacelle.mass = nacelle.mass * factor()
    nacelle.inertia = np.asarray(nacelle.inertia) * factor()
    f_lat = factor()
    for name in ("lateral1", "lateral2"):
        bar = spec.body(name)
        bar.mass = bar.mass * f_lat
    return _compile(spec, path)


def broken_hypotheses_model(arm_com_offset=0.0, forearm_mass: float = 0.0, path=None
                            ) -> tuple[mujoco.MjModel, np.ndarray]:
    """The H4 breaking the paper's hypotheses, with the true values of the extended regressor (22 columns:
    the paper's 14, ``MXa1..4``, ``mf1..4``, see ``ident.regressor``).

    arm_com_offset : scalar or (4,) [m], each arm's centre of mass moved out along the arm (unbalanced arms);
    forearm_mass : [kg] each forearm rod body (universal joint at the arm tip B_i, ``connect`` equality at the
    nacelle point A_i, as in the default model) gains a uniform thin rod of this mass besides the point mass at
    its far end that the default model's paper parameters already count. The paper's parameters then
    hold the rod's two lumped halves (m/2 at B_i: Imot += m L^2 / 2 and a first moment MXa += m L / 2; m/2 at
    A_i: Mnac += m / 2, Ibc += m |DC_i|^2 / 2) and ``mf_i = m`` carries the rest (the rod minus its halves).

    Parameters
    ----------
    arm_com_offset : scalar or (4,) centre-of-mass offsets along the arms [m]
    forearm_mass : mass of each forearm rod [kg], >= 0
    path : the MJCF file, or None (the default model)

    Returns
    -------
    (model, theta) : the mujoco.MjModel and its (22,) true extended parameters (SI)
    """
    offsets = np.broadcast_to(np.asarray(arm_com_offset, dtype=float), (4,)).copy()
    if not np.all(np.isfinite(offsets)):
        raise ValueError(f"arm_com_offset must be finite [m], got {arm_com_offset!r}")
    if not (np.isfinite(forearm_mass) and forearm_mass >= 0):
        raise ValueError(f"forearm_mass must be a finite number >= 0 [kg], got {forearm_mass!r}")
    base, mxa = unbalanced_arms_model(offsets, path)
    from h4bench.sim.model import H4Geometry
    from h4bench.sim.truth import true_parameters

    theta = np.concatenate([true_parameters(base), mxa, np.zeros(4)])
    if forearm_mass == 0.0:
        return base, theta
    geometry = H4Geometry.from_model(base)
    spec = _spec(path)
    for i, r in enumerate(offsets):
        spec.body(f"arm{i + 1}").ipos = [r, 0.0, 0.0]
    for i in range(4):
        # the model's rod keeps its point mass at the far end (counted in the 14 parameters) and gains a
        # uniform thin rod of forearm_mass from B_i to A_i: one rigid body, closed like the default model
        rod = spec.body(f"forearm_rod{i + 1}")
        end = np.asarray(base.site_pos[mujoco.mj_name2id(base, mujoco.mjtObj.mjOBJ_SITE, f"rod_end{i + 1}")])
        point_mass, point_inertia = float(rod.mass), np.asarray(rod.inertia, dtype=float)
        total = point_mass + forearm_mass
        com = (point_mass * end + forearm_mass * end / 2) / total
        axis = end / np.linalg.norm(end)
        inertia = np.diag(point_inertia).astype(float)
        for mass, at in ((point_mass, end), (forearm_mass, end / 2)):
            r = at - com
            inertia += mass * (r @ r * np.eye(3) - np.outer(r, r))
        inertia += forearm_mass * float(end @ end) / 12 * (np.eye(3) - np.outer(axis, axis))  # thin uniform rod
        rod.explicitinertial = True
        rod.mass, rod.ipos = total, com
        evals, evecs = np.linalg.eigh(inertia)  # principal axes: MjSpec takes diagonal inertia + iquat
        if np.linalg.det(evecs) < 0:
            evecs[:, 0] = -evecs[:, 0]
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, evecs.ravel())
        rod.inertia, rod.iquat = evals, quat
    model = _compile(spec, path)
    half = forearm_mass / 2.0
    theta[:4] += half * geometry.arm_length**2
    theta[4] += 4 * half
    theta[5] += half * float(np.sum(geometry.bar_offset[:, :2] ** 2))
    theta[14:18] += half * geometry.arm_length
    theta[18:22] = forearm_mass
    return model, theta


def unbalanced_arms_model(offsets, path=None) -> tuple[mujoco.MjModel, np.ndarray]:
    """The H4 with each arm's centre of mass moved by ``offsets[i]`` [m] along the arm (from the motor axis):
    the arms are no longer balanced and gravity loads the motors. Returns (model, MXa) with MXa_i = m_i r_i
    [kg m], the first moments of the extended regressor's arm-gravity columns.

    Parameters
    ----------
    offsets : scalar or (4,) centre-of-mass offsets along the arms [m]
    path : the MJCF file, or None (the default model)

    Returns
    -------
    (model, MXa) : the mujoco.MjModel and the (4,) first moments [kg m]
    """
    offsets = np.asarray(offsets, dtype=float).reshape(-1)
    if offsets.shape != (4,) or not np.all(np.isfinite(offsets)):
        raise ValueError(f"offsets must be 4 finite values [m], got {offsets!r}")
    spec = _spec(path)
    mxa = []
    for i, r in enumerate(offsets):
        arm = spec.body(f"arm{i + 1}")
        arm.ipos = [r, 0.0, 0.0]
        mxa.append(arm.mass * r)
    return _compile(spec, path), np.array(mxa)
