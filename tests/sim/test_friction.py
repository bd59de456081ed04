"""The simulated friction law (sim.friction) against MuJoCo's own constraint forces."""

import mujoco
import numpy as np
import pytest

from h4bench.sim.friction import friction_band, soft_friction
from h4bench.sim.model import MOTOR_JOINTS, load_model


@pytest.fixture(scope="module")
def motion():
    """2 s of the H4 tracking fast sines under a saturated PD (reversals at up to ~500 rad/s^2): per step the
    motors' speed, acceleration and MuJoCo's friction-loss force (efc_force of the friction rows)."""
    model = load_model()
    data = mujoco.MjData(model)
    dofs = [int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in MOTOR_JOINTS]
    qadr = [int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in MOTOR_JOINTS]
    q0 = data.qpos[qadr].copy()
    freq = np.array([3.0, 4.0, 5.0, 6.0])
    friction_row = int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF)
    v, a, f = [], [], []
    for k in range(2000):
        ref = q0 + 0.3 * np.sin(2 * np.pi * freq * k * model.opt.timestep)
        data.ctrl[:] = np.clip(200 * (ref - data.qpos[qadr]) - 5 * data.qvel[dofs], -15, 15)
        mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        force = np.zeros(4)
        for r in np.flatnonzero(data.efc_type == friction_row):
            force[dofs.index(int(data.efc_id[r]))] = data.efc_force[r]
        v.append(data.qvel[dofs].copy())
        a.append(data.qacc[dofs].copy())
        f.append(force)
    return model, np.array(v), np.array(a), np.array(f), model.dof_frictionloss[dofs]


def test_soft_friction_reads_the_friction_rows():
    model = load_model()
    b, R = soft_friction(model)
    # b = 2 / (d_max timeconst) of solreffriction 0.002, solimpfriction d_max 0.999 (models/h4.xml)
    assert b == pytest.approx(np.full(4, 2 / (0.999 * 0.002)), rel=1e-12)
    assert np.all(R > 0) and np.all(np.isfinite(R))


def test_friction_is_coulomb_above_the_band_and_not_below(motion):
    model, v, a, f, fs = motion
    deviation = np.abs(f + fs * np.sign(v))  # MuJoCo's force minus Coulomb's -Fs sign(qd)
    b, R = soft_friction(model)
    # the pointwise condition of the module docstring, then the band with the run's own peak |qdd|
    pointwise = b * np.abs(v) >= np.abs(a) + R * fs
    assert np.max(deviation[pointwise]) <= 1e-9 * np.max(fs)
    band = friction_band(model, np.abs(a).max(axis=0), fs)
    above = np.abs(v) >= band
    assert np.max(deviation[above]) <= 1e-9 * np.max(fs)
    # the band is needed: below it, with the speed not yet zero, MuJoCo's force is far from Coulomb's
    assert np.all(band > 0.3) and np.max(deviation[~above & (np.abs(v) > 0.1 * band)]) > np.max(fs)


def test_friction_band_rejects_bad_bounds():
    model = load_model()
    with pytest.raises(ValueError, match="qdd_max and fs_max"):
        friction_band(model, -1.0, 1.0)
    with pytest.raises(TypeError, match="mujoco.MjModel"):
        soft_friction("h4.xml")
