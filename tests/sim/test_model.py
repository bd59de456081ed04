"""The MJCF itself: compiles, steps without warnings, closed at qpos0, documented number by number."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from h4bench import sim

ROOT = Path(__file__).resolve().parents[2]


def test_model_steps_two_seconds_under_random_torques_without_warnings(model, geometry):
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, 0)
    rng = np.random.default_rng(3)
    hold = np.zeros(4)
    for k in range(int(2.0 / model.opt.timestep)):
        if k % 50 == 0:
            hold = rng.uniform(-4.0, 4.0, 4)
        # hold the home pose with a PD law plus random torques, all within the +-15 N m limits
        q, qd = d.qpos[geometry.qpos_motor], d.qvel[geometry.dof_motor]
        d.ctrl[:] = np.clip(60.0 * (0.0 - q) - 3.0 * qd + hold, -15.0, 15.0)
        mujoco.mj_step(model, d)
    counts = {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(d.warning) if w.number}
    assert counts == {}, f"MuJoCo warnings: {counts}"
    assert np.all(np.isfinite(d.qpos))


def test_model_is_closed_at_qpos0_and_home(model):
    d = mujoco.MjData(model)
    for key in (None, 0):
        if key is None:
            mujoco.mj_resetData(model, d)
        else:
            mujoco.mj_resetDataKeyframe(model, d, key)
        mujoco.mj_forward(model, d)
        eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        assert eq.sum() == 14  # 4 rod-end connects (3 rows each) + 2 lateral-bar parallelism rows
        assert np.abs(d.efc_pos[eq]).max() < 1e-12


def test_contacts_disabled_and_motor_limits(model):
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    np.testing.assert_array_equal(model.actuator_ctrlrange, np.tile([-15.0, 15.0], (4, 1)))
    np.testing.assert_array_equal(model.actuator_gear[:, 0], np.ones(4))


def test_home_pose_is_far_from_singular(geometry):
    # a 4-fold symmetric nacelle makes z and theta columns collinear (cond ~1e4-1e7); the H breaks that
    assert sim.singularity_measure(geometry, geometry.x_home) < 50.0


def _readme_names():
    text = (ROOT / "models" / "README.md").read_text()
    return set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", text))


def test_readme_table_covers_every_named_element(model):
    documented = _readme_names()
    kinds = {
        "body": (model.nbody, mujoco.mjtObj.mjOBJ_BODY),
        "joint": (model.njnt, mujoco.mjtObj.mjOBJ_JOINT),
        "actuator": (model.nu, mujoco.mjtObj.mjOBJ_ACTUATOR),
        "tendon": (model.ntendon, mujoco.mjtObj.mjOBJ_TENDON),
        "equality": (model.neq, mujoco.mjtObj.mjOBJ_EQUALITY),
        "site": (model.nsite, mujoco.mjtObj.mjOBJ_SITE),
    }
    missing = []
    for kind, (count, obj) in kinds.items():
        for i in range(count):
            name = mujoco.mj_id2name(model, obj, i)
            if kind == "body" and i == 0:
                continue  # the world
            if not name or name not in documented:
                missing.append(f"{kind} {name!r}")
    assert not missing, f"models/README.md lacks rows for: {missing}"


def test_readme_documents_every_number_of_the_xml():
    xml = (ROOT / "models" / "h4.xml").read_text()
    xml = re.sub(r"<!--.*?-->", "", xml, flags=re.S)
    numbers = set()
    for value in re.findall(r'="([-0-9. e]+)"', xml):
        numbers.update(float(v) for v in value.split())
    text = (ROOT / "models" / "README.md").read_text()
    documented = {float(v) for v in re.findall(r"(?<![\w.])-?\d+(?:\.\d+)?(?:e-?\d+)?", text)}
    missing = sorted(v for v in numbers if v not in documented and v not in (0.0, 1.0, -1.0))
    assert not missing, f"numbers in h4.xml without a row in models/README.md: {missing}"


@pytest.mark.parametrize("bad", ["/nonexistent/h4.xml", __file__])
def test_load_model_bad_path_names_the_argument(bad):
    with pytest.raises(sim.ModelError, match="model path"):
        sim.load_model(bad)


def test_load_model_rejects_a_non_h4(tmp_path):
    p = tmp_path / "arm.xml"
    p.write_text('<mujoco><worldbody><body><joint name="q1"/><geom size="0.1"/></body></worldbody></mujoco>')
    with pytest.raises(sim.ModelError, match="must define joint"):
        sim.load_model(p)


def _raw_model():
    return mujoco.MjModel.from_xml_path(str(sim.DEFAULT_MODEL_PATH))  # compiled, solver constants not applied


def test_inverse_weights_are_scaled_once_and_survive_set_const(model):
    """h4bench.sim.load_model scales the non-motor inverse weights by the model's numeric; re-applying (which re-runs
    mj_setConst) gives the same values, and the sim.variants builders apply it too."""
    raw = _raw_model()
    i = mujoco.mj_name2id(raw, mujoco.mjtObj.mjOBJ_NUMERIC, "h4_invweight_scale")
    scale = raw.numeric_data[raw.numeric_adr[i]]
    motors = [raw.jnt_dofadr[mujoco.mj_name2id(raw, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in sim.model.MOTOR_JOINTS]
    others = np.setdiff1d(np.arange(raw.nv), motors)
    np.testing.assert_array_equal(model.dof_invweight0[motors], raw.dof_invweight0[motors])
    np.testing.assert_allclose(model.dof_invweight0[others], scale * raw.dof_invweight0[others], rtol=1e-12)
    np.testing.assert_allclose(model.body_invweight0, scale * raw.body_invweight0, rtol=1e-12)
    again = sim.apply_solver_constants(sim.load_model())
    np.testing.assert_allclose(again.dof_invweight0, model.dof_invweight0, rtol=1e-12)
    mujoco.mj_setConst(again, mujoco.MjData(again))  # MuJoCo's own recomputation drops the scaling ...
    np.testing.assert_allclose(again.dof_invweight0, raw.dof_invweight0, rtol=1e-12)
    sim.apply_solver_constants(again)  # ... which apply_solver_constants restores
    np.testing.assert_allclose(again.dof_invweight0, model.dof_invweight0, rtol=1e-12)
    for variant in (sim.randomised_model(3), sim.unbalanced_arms_model([0.01] * 4)[0],
                    sim.broken_hypotheses_model(forearm_mass=0.2)[0]):
        assert variant.body_invweight0[variant.nbody - 1].max() < 1e-3 * raw.body_invweight0[raw.nbody - 1].max()


def test_rod_ends_meet_their_attachment_points_exactly_at_qpos0(model, geometry):
    d = mujoco.MjData(model)
    mujoco.mj_kinematics(model, d)
    for i in range(4):
        end = d.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"rod_end{i + 1}")]
        a = d.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"A{i + 1}")]
        assert np.abs(end - a).max() < 1e-15
    np.testing.assert_allclose(geometry.forearm_length, geometry.forearm_length[0], rtol=1e-15)


def test_forearm_universal_joints_stay_far_from_gimbal_lock(model, geometry):
    """A rod's universal joint locks when its second hinge reaches 90 deg; over the workspace it stays far
    from that (measured 12.6 deg), and the rod angles close MuJoCo's loops (oracle: efc_pos)."""
    from tests.conftest import random_workspace_poses

    x = random_workspace_poses(np.random.default_rng(0), 20000)
    angles = geometry.rod_angles(sim.inverse_kinematics(geometry, x), x)
    assert np.degrees(np.abs(angles[..., 1]).max()) < 30.0
