"""The batched regressor of a revolute chain (:mod:`ident.robots.chain`) against pinocchio, a long-double
evaluation, and itself (compiled and numpy: the same bits).

Oracles: ``pinocchio.computeJointTorqueRegressor`` (another algorithm: world-frame kinematics) on the TX40, the UR5
of ``examples/own_arm`` and random chains with unaligned axes, offsets and rotations; the same formulas in long
double (64-bit significand) for the rounding error; the TX40's RNEA torques of its URDF parameters.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from h4bench.ident.robots import chain, tx40
from h4bench.ident.robots.serial_steps import _pinocchio_calls, _regressor_calls, robot_chain

pin = pytest.importorskip("pinocchio")
UR5 = Path(__file__).parents[2] / "examples" / "own_arm" / "ur5.urdf"


def _random_urdf(rng, n: int, kinds) -> str:
    """A chain of n revolute links with random joint origins (xyz, rpy), axes of the given kinds ("x", "y", "z",
    "-z", "free": a random unit vector) and inertias."""
    links = ['<link name="base"/>']
    joints = []
    for i in range(n):
        m = rng.uniform(0.5, 5)
        c = rng.uniform(-0.2, 0.2, 3)
        A = rng.normal(size=(3, 3))
        Ic = A @ A.T * 0.01 + np.eye(3) * 0.01
        links.append(f'<link name="l{i}"><inertial><origin xyz="{c[0]} {c[1]} {c[2]}" rpy="0 0 0"/>'
                     f'<mass value="{m}"/><inertia ixx="{Ic[0, 0]}" ixy="{Ic[0, 1]}" ixz="{Ic[0, 2]}" '
                     f'iyy="{Ic[1, 1]}" iyz="{Ic[1, 2]}" izz="{Ic[2, 2]}"/></inertial></link>')
        kind = kinds[i % len(kinds)]
        ax = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "-z": (0, 0, -1)}.get(kind)
        if ax is None:
            v = rng.normal(size=3)
            ax = v / np.linalg.norm(v)
        xyz, rpy = rng.uniform(-0.4, 0.4, 3), rng.uniform(-np.pi, np.pi, 3)
        parent = "base" if i == 0 else f"l{i - 1}"
        joints.append(f'<joint name="j{i}" type="revolute"><parent link="{parent}"/><child link="l{i}"/>'
                      f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/>'
                      f'<axis xyz="{ax[0]} {ax[1]} {ax[2]}"/><limit effort="1" velocity="1" lower="-9" upper="9"/>'
                      '</joint>')
    return '<?xml version="1.0"?><robot name="r">' + "".join(links + joints) + "</robot>"


def _models():
    rng = np.random.default_rng(7)
    out = {"tx40": tx40.robot().model, "ur5": pin.buildModelFromUrdf(str(UR5))}
    out["mixed"] = pin.buildModelFromXML(_random_urdf(rng, 5, ["x", "y", "z", "-z", "free"]))
    out["free7"] = pin.buildModelFromXML(_random_urdf(rng, 7, ["free"]))
    return out


MODELS = _models()


def _states(rng, n, B):
    return rng.uniform(-np.pi, np.pi, (B, n)), rng.uniform(-6, 6, (B, n)), rng.uniform(-80, 80, (B, n))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_chain_regressor_is_pinocchios(name):
    model = MODELS[name]
    ch = chain.chain_of(model)
    assert ch is not None and ch.n == model.nv
    data = model.createData()
    q, v, a = _states(np.random.default_rng(1), ch.n, 300)
    q[0], v[0], a[0] = 0.0, 0.0, 0.0  # gravity alone at the zero position
    v[1] = 0.0  # no speed
    a[2] = 0.0  # no acceleration
    Y = chain.regressor(ch, q, v, a)
    ref = np.stack([pin.computeJointTorqueRegressor(model, data, q[k], v[k], a[k]) for k in range(q.shape[0])])
    scale = np.max(np.abs(ref), axis=2, keepdims=True) + 1.0  # each evaluation's joint row
    assert np.max(np.abs(Y - ref) / scale) < 1e-13
    # and the torques: Y pi = RNEA with the model's own inertias
    pi = np.concatenate([model.inertias[i].toDynamicParameters() for i in range(1, model.njoints)])
    tau = np.stack([pin.rnea(model, data, q[k], v[k], a[k]) for k in range(q.shape[0])])
    assert np.allclose(Y @ pi, tau, rtol=1e-12, atol=1e-10 * (np.max(np.abs(tau)) + 1))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_compiled_and_numpy_give_the_same_bits(name):
    if not chain.available():
        pytest.skip("the compiled regressor is not built")
    ch = chain.chain_of(MODELS[name])
    q, v, a = _states(np.random.default_rng(2), ch.n, 257)
    v[:5] = 0.0
    a[5:9] = -0.0
    q[9] = 0.0
    q[10:20] = q[20]  # runs of one position: the compiled loop keeps their kinematics
    q[30], q[31] = 0.0, -0.0  # a signed zero starts a new run (its sine differs)
    c = chain.regressor(ch, q, v, a, compiled=True)
    p = chain.regressor(ch, q, v, a, compiled=False)
    assert np.array_equal(c.view(np.int64), p.view(np.int64))  # bit for bit, signed zeros too
    live = chain.live_entries(ch.n)
    cp = chain.regressor(ch, q, v, a, compiled=True, packed=True)
    assert np.array_equal(cp.view(np.int64), c.reshape(len(q), -1)[:, live].view(np.int64))
    assert np.array_equal(chain.regressor(ch, q, v, a, compiled=False, packed=True).view(np.int64), cp.view(np.int64))
    dead = np.setdiff1d(np.arange(10 * ch.n * ch.n), live)
    assert np.all(c.reshape(len(q), -1)[:, dead] == 0)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_rounding_error_against_long_double(name):
    """The double evaluation against the same formulas in long double (inputs and constants rounded to double
    first): the error is far inside the allowance the certified equation states for the regressor
    (``PIN_REL`` = 1e-12 of the magnitudes), relative to each evaluation's joint row."""
    if np.finfo(np.longdouble).nmant < 63:
        pytest.skip("long double is not wider than double here")
    ch = chain.chain_of(MODELS[name])
    q, v, a = _states(np.random.default_rng(3), ch.n, 200)
    Y = chain.regressor(ch, q, v, a)
    ql = q.astype(np.longdouble)
    # the cosines and sines as the double path takes them (numpy's, rounded to double): the formulas' own error
    Yl = chain._regressor_numpy(ch, np.cos(q).astype(np.longdouble), np.sin(q).astype(np.longdouble),
                                v.astype(np.longdouble), a.astype(np.longdouble), dtype=np.longdouble)
    assert ql.dtype == np.longdouble
    scale = np.max(np.abs(Yl), axis=2, keepdims=True) + 1.0
    err = np.abs(Y.astype(np.longdouble) - Yl) / scale
    assert float(np.max(err)) < 1e-14


def test_the_step_evaluations_match_pinocchios_calls():
    """The certified equation's per-step evaluations (every block, its bookkeeping) against pinocchio's one by one."""
    robot = tx40.robot()
    rng = np.random.default_rng(4)
    qh, vh = rng.uniform(-3, 3, (5, 6)), rng.uniform(-4, 4, (5, 6))
    new, old = _regressor_calls(robot, qh, vh), _pinocchio_calls(robot, qh, vh)
    assert new.keys() == old.keys()
    live = chain.live_entries(6)
    assert live.size == 5 * 6 * 7
    for k in new:
        full = old[k].reshape(old[k].shape[:-2] + (-1,))
        dead = np.setdiff1d(np.arange(360), live)
        assert np.all(full[..., dead] == 0), k  # pinocchio's zeros where a chain has them
        assert new[k].shape == full[..., live].shape, k
        scale = np.max(np.abs(full)) + 1.0
        assert np.max(np.abs(new[k] - full[..., live])) < 1e-13 * scale, k
    assert np.all(new["pair"][:, np.tril_indices(6)[0], np.tril_indices(6)[1]] == 0)  # a < b only, as before


def test_other_models_keep_pinocchio(tmp_path):
    # a prismatic joint: no chain (the certified path keeps pinocchio's calls)
    xml = _random_urdf(np.random.default_rng(5), 3, ["z"]).replace('name="j1" type="revolute"',
                                                                    'name="j1" type="prismatic"')
    assert chain.chain_of(pin.buildModelFromXML(xml)) is None
    # a branch: two children of the base
    xml2 = _random_urdf(np.random.default_rng(6), 3, ["z"]).replace('<parent link="l1"/>', '<parent link="base"/>')
    assert chain.chain_of(pin.buildModelFromXML(xml2)) is None
    assert robot_chain(tx40.robot()) is not None


def test_bad_states_are_refused():
    ch = chain.chain_of(MODELS["tx40"])
    z = np.zeros((3, 6))
    with pytest.raises(ValueError, match=r"qd must have shape \(B, 6\), got \(3, 5\)"):
        chain.regressor(ch, z, np.zeros((3, 5)), z)
    with pytest.raises(ValueError, match="qdd must be finite"):
        chain.regressor(ch, z, z, np.full((3, 6), np.nan))
    with pytest.raises(ValueError, match="one shape"):
        chain.regressor(ch, z, z, np.zeros((2, 6)))
    with pytest.raises(ValueError, match="R0, p0, axis, g must have shapes"):
        chain.Chain.from_arrays(np.zeros((2, 3, 3)), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3))


@pytest.mark.skipif(shutil.which("c++") is None or not sys.platform.startswith("linux"), reason="no C++ compiler")
def test_the_regressor_is_built_where_a_compiler_is():
    """An install on a machine with a C++ compiler builds the extension (optional: a failed build would otherwise
    pass unseen, every certified serial equation then taking the slower numpy formulas)."""
    assert chain.available(), "h4bench.ident.robots._chain was not built: see the install's build output"
