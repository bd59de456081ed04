"""Shared fixtures: the compiled H4 model, its geometry and a short exact-state MuJoCo recording."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import sim


@pytest.fixture(scope="session")
def model():
    return sim.load_model()


@pytest.fixture(scope="session")
def geometry(model):
    return sim.H4Geometry.from_model(model)


def bounded_noise_problem(rng, m, p, theta_range=(0.5, 1.5)):
    """Synthetic bounded-error data: W (m, p) standard normal, theta uniform in ``theta_range``, and
    y = W theta + e with e uniform in [-1, 1] (so the bound 1 holds). Returns (W, theta, y), drawn in that
    order from ``rng``."""
    W = rng.standard_normal((m, p))
    theta = rng.uniform(*theta_range, p)
    return W, theta, W @ theta + rng.uniform(-1, 1, m)


def random_workspace_poses(rng, n):
    """Poses well inside the workspace: |x|, |y| <= 0.1 m, z in [-0.7, -0.42] m, |theta| <= 0.35 rad."""
    return np.column_stack([
        rng.uniform(-0.1, 0.1, n), rng.uniform(-0.1, 0.1, n), rng.uniform(-0.7, -0.42, n), rng.uniform(-0.35, 0.35, n)
    ])


def record_exact(model, geometry, seconds=2.0, seed=0, timestep=None):
    """Track a smooth reference with a PD law; record, at every MuJoCo step, the exact state (q, qd),
    MuJoCo's joint acceleration qdd, the applied motor torques, the nacelle pose and acceleration, and the
    loop violation. The reference: sums of sines of the nacelle pose around home, through the inverse
    kinematics (a joint-space reference would spin the nacelle into a singularity)."""
    m = model
    if timestep is not None:
        m = mujoco.MjModel.from_xml_path(str(sim.DEFAULT_MODEL_PATH))
        m.opt.timestep = timestep
        m.eq_solref[:, 0] = 2 * timestep
        m.dof_solref[:, 0] = 2 * timestep
    d = mujoco.MjData(m)
    h = m.opt.timestep
    n = int(round(seconds / h))
    t = np.arange(n) * h
    rng = np.random.default_rng(seed)
    f1, f2 = rng.uniform(0.4, 1.0, 4), rng.uniform(1.5, 3.0, 4)
    p1, p2 = rng.uniform(0, 2 * np.pi, (2, 4))
    amp = np.array([0.06, 0.06, 0.08, 0.25])  # [m, m, m, rad]
    x_ref = geometry.x_home + amp * (0.7 * np.sin(2 * np.pi * f1 * t[:, None] + p1)
                                     + 0.3 * np.sin(2 * np.pi * f2 * t[:, None] + p2))
    ref = sim.inverse_kinematics(geometry, x_ref)
    out = {k: np.zeros((n, 4)) for k in ("q", "qd", "qdd", "tau", "x", "xdd")}
    out["violation"] = np.zeros(n)
    eq_rows = None
    for k in range(n):
        qa, va = d.qpos[geometry.qpos_motor], d.qvel[geometry.dof_motor]
        d.ctrl[:] = np.clip(200.0 * (ref[k] - qa) - 10.0 * va, -15.0, 15.0)
        out["q"][k], out["qd"][k], out["x"][k] = qa, va, geometry.nacelle_pose(d.qpos)
        mujoco.mj_step(m, d)
        out["qdd"][k] = d.qacc[geometry.dof_motor]
        out["tau"][k] = d.actuator_force
        out["xdd"][k] = d.qacc[geometry.qpos_nacelle]
        if eq_rows is None:
            eq_rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        out["violation"][k] = np.abs(d.efc_pos[d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY]).max()
    out["h"] = h
    return out


def friction_saturated(qd, qdd, h, band=0.005):
    """Samples where MuJoCo's frictionloss is exactly -Fs sign(qd): the constraint acts on the end-of-step
    speed v+ = qd + h qdd, so keep a sample only when v+ has the sign of qd and |v+| >= band (the speed band
    of solimpfriction, models/README.md)."""
    v_next = qd + h * qdd
    return (np.sign(v_next) == np.sign(qd)) & (np.abs(v_next) >= band)


@pytest.fixture(scope="session")
def exact_recording(model, geometry):
    return record_exact(model, geometry, seconds=2.0, seed=0)


NOMINAL = np.array(__import__('ident').NOMINAL_PARAMETERS)


def cartesian_reference(geometry, seconds=3.0, dt=1e-3, seed=0, amp=(0.06, 0.06, 0.08, 0.25)):
    """A smooth nacelle reference (sines with a smoothstep ramp-in) mapped to the joints; qd, qdd by
    differentiating q (np.gradient): enough to drive the controller in tests."""
    import types

    t = np.arange(int(round(seconds / dt))) * dt
    rng = np.random.default_rng(seed)
    f, p = rng.uniform(0.3, 0.9, 4), rng.uniform(0, 2 * np.pi, 4)
    s = np.clip(t / 0.5, 0, 1)
    x = geometry.x_home + np.asarray(amp) * (s * s * (3 - 2 * s))[:, None] * np.sin(2 * np.pi * f * t[:, None] + p)
    q = sim.inverse_kinematics(geometry, x)
    qd = np.gradient(q, dt, axis=0)
    return types.SimpleNamespace(t=t, x=x, q=q, qd=qd, qdd=np.gradient(qd, dt, axis=0))


def run_experiment(model, geometry, seconds=3.0, noise=None, seed=0, encoder_counts=20000):
    import ident

    ref = cartesian_reference(geometry, seconds=seconds, seed=seed)
    _, controller = sim.default_controller(geometry, NOMINAL)
    ff = ident.inverse_dynamics(geometry, NOMINAL, ref.q, ref.qd, ref.qdd)
    return ref, *sim.simulate(model, ref, noise=noise, controller=controller, feedforward=ff, seed=seed,
                              settings=sim.SimulationSettings(encoder_counts=encoder_counts))
