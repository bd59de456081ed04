"""A model edited the official MuJoCo way (MjSpec, written back by ``to_xml`` or ``mj_saveLastXML`` with 6
significant digits) loads with its loops assembled at qpos0 and keeps the exact-loop properties."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from h4bench import ident
from h4bench import sim
from tests.conftest import friction_saturated, record_aggressive


def _to_xml(tmp_path):
    path = tmp_path / "spec.xml"
    path.write_text(mujoco.MjSpec.from_file(str(sim.model.DEFAULT_MODEL_PATH)).to_xml())
    return path


def _save_last(tmp_path):
    path = tmp_path / "last.xml"
    mujoco.MjModel.from_xml_path(str(sim.model.DEFAULT_MODEL_PATH))
    mujoco.mj_saveLastXML(str(path), mujoco.MjModel.from_xml_path(str(sim.model.DEFAULT_MODEL_PATH)))
    return path


def _raw_gap(path):
    """The loop gap at qpos0 of the file as MuJoCo compiles it (no assembly)."""
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    ids = [[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"{s}{i}") for s in ("rod_end", "A")] for i in (1, 2, 3, 4)]
    return max(np.abs(d.site_xpos[e] - d.site_xpos[a]).max() for e, a in ids)


@pytest.mark.parametrize("write", [_to_xml, _save_last], ids=["to_xml", "mj_saveLastXML"])
def test_a_model_written_back_by_mujoco_runs_exactly(tmp_path, write):
    """Oracle: MuJoCo's own loop residual (efc_pos) and actuator forces on an aggressive motion."""
    path = write(tmp_path)
    assert _raw_gap(path) > 1e-8  # the rounded file is open as written (measured ~2e-7 m)
    model = sim.load_model(path)
    geometry = sim.H4Geometry.from_model(model)
    d = mujoco.MjData(model)
    mujoco.mj_kinematics(model, d)
    for i in range(1, 5):
        end, a = (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{s}{i}") for s in ("rod_end", "A"))
        assert np.abs(d.site_xpos[end] - d.site_xpos[a]).max() < 1e-14
    theta = sim.true_parameters(model)  # the point-mass check accepts the written-back rods
    np.testing.assert_allclose(theta, sim.true_parameters(sim.load_model()), rtol=1e-5)
    r = record_aggressive(model, geometry, seconds=2.0, seed=0)
    assert r["violation"].max() < 1e-8  # [m]
    ok = sim.singularity_measure(geometry, r["x"]) < 100.0
    r = {k: v[ok] for k, v in r.items() if k != "h"} | {"h": r["h"]}
    keep = friction_saturated(r["qd"], r["qdd"], r["h"])
    x = sim.forward_kinematics(geometry, r["q"], x0=r["x"])
    err = np.abs(ident.inverse_dynamics(geometry, theta, r["q"], r["qd"], r["qdd"], x=x) - r["tau"])[keep]
    assert keep.sum() > 100 and err.max() < 1e-3, err.max()


def test_a_model_whose_loop_is_off_by_more_than_the_tolerance_is_refused(tmp_path):
    spec = mujoco.MjSpec.from_file(str(sim.model.DEFAULT_MODEL_PATH))
    site = spec.site("rod_end2")
    site.pos = [site.pos[0] + 1e-3, 0.0, 0.0]  # 1 mm longer than the assembled rod
    path = tmp_path / "open.xml"
    path.write_text(spec.to_xml())
    with pytest.raises(sim.ModelError, match=r"forearm_rod2.*ends 0\.000[5-9]\d* m from A2; up to 0\.0001 m"):
        sim.load_model(path)


def test_the_shipped_model_is_left_as_written():
    raw = mujoco.MjModel.from_xml_path(str(sim.model.DEFAULT_MODEL_PATH))
    model = sim.load_model()
    for name in ("body_pos", "body_quat", "body_ipos", "site_pos"):
        np.testing.assert_array_equal(getattr(model, name), getattr(raw, name))


def test_the_variants_of_a_written_back_model_are_assembled_too(tmp_path):
    """h4bench.sim.randomised_model compiles its own MjSpec: its loops are closed like load_model's."""
    model = sim.randomised_model(3, 0.3, _to_xml(tmp_path))
    d = mujoco.MjData(model)
    mujoco.mj_kinematics(model, d)
    for i in range(1, 5):
        end, a = (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{s}{i}") for s in ("rod_end", "A"))
        assert np.abs(d.site_xpos[end] - d.site_xpos[a]).max() < 1e-14
    sim.H4Geometry.from_model(model)
