"""Variants of the H4 model edited with ``mujoco.MjSpec`` (no XML written): randomised true parameters for
Monte Carlo campaigns, and robots that break the paper's hypotheses (unbalanced arms)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from sim.model import DEFAULT_MODEL_PATH, MOTOR_JOINTS, ModelError, _check_structure


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
    return model


def randomised_model(seed: int, spread: float = 0.3, path=None) -> mujoco.MjModel:
    """The H4 with its identifiable physical quantities scaled by independent factors in [1 - spread, 1 + spread]:
    each motor's armature, damping and frictionloss, each arm's inertia about its axis, the central bar's mass
    and vertical inertia, the lateral bars' mass (both by one factor, keeping the nacelle's centre of mass at
    D). Geometry is unchanged. The true parameters follow from ``sim.true_parameters`` of the result."""
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


def unbalanced_arms_model(offsets, path=None) -> tuple[mujoco.MjModel, np.ndarray]:
    """The H4 with each arm's centre of mass moved by ``offsets[i]`` [m] along the arm (from the motor axis):
    the arms are no longer balanced and gravity loads the motors. Returns (model, MXa) with MXa_i = m_i r_i
    [kg m], the first moments of the extended regressor's arm-gravity columns."""
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
