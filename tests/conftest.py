"""Shared fixtures: the compiled H4 model, its geometry and a short exact-state MuJoCo recording."""

from __future__ import annotations

import os

# The default run has 2 worker processes (pyproject.toml: -n 2) on a 2-core machine: one BLAS thread each, unless
# the caller says otherwise (the workers and every child process a test starts inherit it; the results are the same
# at any thread count, tests/test_blas_independence.py)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
# likewise one process for a signed hull's two halves (ident.estimators.hull_split: the same box with 1 or 2)
os.environ.setdefault("H4BENCH_HULL_PROCESSES", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from h4bench import sim  # noqa: E402


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


def _record(model, geometry, q0, n, control):
    """Step ``model`` n times from motor angles q0 (4,) at rest; at every step set ``d.ctrl = control(q, qd, k)``,
    ``mj_forward`` and record AT that state: exact q, qd, MuJoCo's qdd, applied motor torques, nacelle pose
    and acceleration, loop violation (max |efc_pos| of the equality rows); then ``mj_RungeKutta`` (RK4: the
    ``qacc`` left by ``mj_step`` is a step average, not the sample's)."""
    m, d = model, mujoco.MjData(model)
    d.qpos[:] = geometry.qpos(q0, sim.forward_kinematics(geometry, q0))
    mujoco.mj_forward(m, d)
    out = {k: np.zeros((n, 4)) for k in ("q", "qd", "qdd", "tau", "x", "xdd")}
    out["violation"] = np.zeros(n)
    qm, dm, ne = geometry.qpos_motor, geometry.dof_motor, d.ne
    nac = [m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)] for j in sim.model.NACELLE_JOINTS]
    for k in range(n):
        qa, va = d.qpos[qm], d.qvel[dm]
        d.ctrl[:] = control(qa, va, k)
        mujoco.mj_forward(m, d)
        out["q"][k], out["qd"][k], out["x"][k] = qa, va, geometry.nacelle_pose(d.qpos)
        out["qdd"][k] = d.qacc[dm]
        out["tau"][k] = d.actuator_force
        out["xdd"][k] = d.qacc[nac]
        out["violation"][k] = np.abs(d.efc_pos[:ne]).max()
        if m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
            mujoco.mj_RungeKutta(m, d, 4)
        else:
            mujoco.mj_Euler(m, d)
    out["h"] = m.opt.timestep
    return out


def record_exact(model, geometry, seconds=2.0, seed=0):
    """Track a smooth reference with a PD law (gain 200) and record every MuJoCo step (see ``_record``). The
    reference: sums of sines of the nacelle pose around home, through the inverse kinematics (a joint-space
    reference would spin the nacelle into a singularity)."""
    h = model.opt.timestep
    n = int(round(seconds / h))
    t = np.arange(n) * h
    rng = np.random.default_rng(seed)
    f1, f2 = rng.uniform(0.4, 1.0, 4), rng.uniform(1.5, 3.0, 4)
    p1, p2 = rng.uniform(0, 2 * np.pi, (2, 4))
    amp = np.array([0.06, 0.06, 0.08, 0.25])  # [m, m, m, rad]
    x_ref = geometry.x_home + amp * (0.7 * np.sin(2 * np.pi * f1 * t[:, None] + p1)
                                     + 0.3 * np.sin(2 * np.pi * f2 * t[:, None] + p2))
    ref = sim.inverse_kinematics(geometry, x_ref)
    return _record(model, geometry, ref[0], n, lambda q, qd, k: np.clip(200.0 * (ref[k] - q) - 10.0 * qd, -15.0, 15.0))


def record_aggressive(model, geometry, seconds=4.0, seed=0, gain=80.0, damping=2.0, amp=0.2, hz=(0.7, 1.6)):
    """An aggressive joint motion: PD law ``gain (q_ref - q) - damping qd`` [N m/rad, N m s/rad] clipped at
    +-15 N m towards ``amp sin(2 pi f t + p)`` per joint (f uniform in ``hz``, p uniform; the start is away
    from the reference, so the torques saturate at first). Recorded at every MuJoCo step (``_record``)."""
    h = model.opt.timestep
    t = np.arange(int(round(seconds / h))) * h
    rng = np.random.default_rng(seed)
    f, p = rng.uniform(*hz, 4), rng.uniform(0, 2 * np.pi, 4)
    ref = amp * np.sin(2 * np.pi * f * t[:, None] + p)
    return _record(model, geometry, np.zeros(4), t.size,
                   lambda q, qd, k: np.clip(gain * (ref[k] - q) - damping * qd, -15.0, 15.0))


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
    from h4bench import ident

    ref = cartesian_reference(geometry, seconds=seconds, seed=seed)
    _, controller = sim.default_controller(geometry, NOMINAL)
    ff = ident.inverse_dynamics(geometry, NOMINAL, ref.q, ref.qd, ref.qdd)
    return ref, *sim.simulate(model, ref, noise=noise, controller=controller, feedforward=ff, seed=seed,
                              settings=sim.SimulationSettings(encoder_counts=encoder_counts))


@pytest.fixture(scope="session")
def paper_quick_cli(tmp_path_factory):
    """``h4bench run paper --quick`` through the command line (CliRunner, 200 columns), once per session: the run
    folder (Path) and the terminal output (str). Shared by the docs schema test and the export tests."""
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    out = tmp_path_factory.mktemp("paper-quick") / "paper"
    res = CliRunner().invoke(app, ["run", "paper", "--quick", "--out", str(out)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    return out, res.output
