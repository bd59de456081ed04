"""h4bench.ident.robots.serial against independent oracles: pinocchio's inverse dynamics (rnea) with random standard parameters,
hand-written friction / rotor / offset / coupled-wrist formulas, numpy's SVD rank, scipy's FIR filtering."""

from __future__ import annotations

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from h4bench.ident.robots import tx40
from h4bench.ident.robots.serial import SerialRobot, base_parameters, process, rich_friction_columns

THREE_LINK_URDF = """<?xml version="1.0"?>
<robot name="three">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="50" velocity="3"/></joint>
  <link name="l1"><inertial><mass value="2.0"/><origin xyz="0.05 0.01 0.1" rpy="0.1 0 0"/>
    <inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.03" iyz="0.002" izz="0.01"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.1 0 0.2" rpy="1.5707963267948966 0 0"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="40" velocity="3"/></joint>
  <link name="l2"><inertial><mass value="1.5"/><origin xyz="0.2 0 0.01" rpy="0 0 0"/>
    <inertia ixx="0.005" ixy="0" ixz="0.0005" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
  <joint name="j3" type="prismatic"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.4 0 0" rpy="0 1.5707963267948966 0"/><axis xyz="0 0 1"/><limit lower="-0.1" upper="0.2" effort="100" velocity="1"/></joint>
  <link name="l3"><inertial><mass value="0.7"/><origin xyz="0 0.02 0.05" rpy="0 0 0"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.0005"/></inertial></link>
</robot>
"""


@pytest.fixture(scope="module")
def tx40_robot():
    return tx40.robot()


@pytest.fixture(scope="module")
def three_link(tmp_path_factory):
    path = tmp_path_factory.mktemp("urdf") / "three.urdf"
    path.write_text(THREE_LINK_URDF)
    return SerialRobot(path, coupled_wrist=(1, 2))


def _random_standard(robot, rng):
    """Random physically consistent inertial parameters (mass, COM, positive inertia about the COM, shifted to
    the joint origin) and random extras."""
    theta = np.zeros(robot.n_parameters)
    for i in range(robot.n_joints):
        m = rng.uniform(0.5, 5.0)
        c = rng.uniform(-0.2, 0.2, 3)
        A = rng.standard_normal((3, 3))
        Ic = A @ A.T * 0.01 + 0.001 * np.eye(3)
        theta[10 * i: 10 * i + 10] = pin.Inertia(m, c, Ic).toDynamicParameters()
    theta[robot.n_inertial:] = rng.uniform(-2.0, 2.0, robot.n_parameters - robot.n_inertial)
    return theta


def _rnea(robot, theta, q, qd, qdd):
    """Oracle: pinocchio's rnea on a model whose inertias are set from theta, plus the extras by hand."""
    model = robot.model.copy()
    for i in range(robot.n_joints):
        model.inertias[i + 1] = pin.Inertia.FromDynamicParameters(theta[10 * i: 10 * i + 10])
    data = model.createData()
    tau = np.array([pin.rnea(model, data, q[k], qd[k], qdd[k]) for k in range(q.shape[0])])
    return tau + _extras_by_hand(robot, theta, qd, qdd)


def _extras_by_hand(robot, theta, qd, qdd):
    """Hand formulas: tau_i += fv_i qd_i + fs_i sign(qd_i) + Ia_i qdd_i + off_i, and for the coupled pair (a, b)
    rows a and b += Iam (qdd_a + qdd_b) + fvm (qd_a + qd_b) + fsm sign(qd_a + qd_b)."""
    nj = robot.n_joints
    ex = dict(zip(robot.names, theta))
    tau = np.zeros_like(qd)
    for i in range(nj):
        tau[:, i] += ex.get(f"fv{i + 1}", 0) * qd[:, i] + ex.get(f"fs{i + 1}", 0) * np.sign(qd[:, i])
        tau[:, i] += ex.get(f"Ia{i + 1}", 0) * qdd[:, i] + ex.get(f"off{i + 1}", 0)
    if robot.coupled_wrist is not None:
        a, b = robot.coupled_wrist
        s = b + 1
        for row in (a, b):
            tau[:, row] += ex[f"Iam{s}"] * (qdd[:, a] + qdd[:, b]) + ex[f"fvm{s}"] * (qd[:, a] + qd[:, b]) \
                + ex[f"fsm{s}"] * np.sign(qd[:, a] + qd[:, b])
    return tau


@pytest.mark.parametrize("which", ["tx40", "three_link"])
def test_standard_regressor_matches_rnea(which, request):
    robot = request.getfixturevalue("tx40_robot" if which == "tx40" else "three_link")
    rng = np.random.default_rng(1)
    q, qd, qdd = robot.random_states(40, seed=11)
    W = robot.regressor(q, qd, qdd)
    assert W.shape == (40 * robot.n_joints, robot.n_parameters)
    for _ in range(3):
        theta = _random_standard(robot, rng)
        tau = _rnea(robot, theta, q, qd, qdd).reshape(-1)
        err = np.max(np.abs(W @ theta - tau)) / np.max(np.abs(tau))
        assert err < 1e-9, err


def test_urdf_parameters_reproduce_rnea_of_the_urdf_model(tx40_robot):
    q, qd, qdd = tx40_robot.random_states(20, seed=3)
    theta = tx40_robot.urdf_parameters()
    data = tx40_robot.model.createData()
    tau = np.array([pin.rnea(tx40_robot.model, data, q[k], qd[k], qdd[k]) for k in range(20)]).reshape(-1)
    W = tx40_robot.regressor(q, qd, qdd)
    assert np.max(np.abs(W @ theta - tau)) <= 1e-9 * np.max(np.abs(tau))


def test_extra_columns_match_hand_formulas(three_link):
    rng = np.random.default_rng(5)
    _, qd, qdd = three_link.random_states(30, seed=6)
    qd[3] = 0.0  # sign(0) = 0 rows too
    theta = np.zeros(three_link.n_parameters)
    theta[three_link.n_inertial:] = rng.uniform(-3, 3, three_link.n_parameters - three_link.n_inertial)
    got = three_link.extra_columns(qd, qdd) @ theta[three_link.n_inertial:]
    assert np.allclose(got, _extras_by_hand(three_link, theta, qd, qdd).reshape(-1), rtol=0, atol=1e-12)
    names = set(three_link.names)
    assert {"fv1", "fs3", "Ia2", "off3", "Iam3", "fvm3", "fsm3"} <= names


@pytest.mark.parametrize("which", ["tx40", "three_link"])
def test_base_parameters_reproduce_torques_on_new_states(which, request):
    robot = request.getfixturevalue("tx40_robot" if which == "tx40" else "three_link")
    base = robot.base(n_samples=150, seed=0)
    q, qd, qdd = robot.random_states(60, seed=99)  # states the QR never saw
    rng = np.random.default_rng(2)
    W = robot.regressor(q, qd, qdd)
    for _ in range(3):
        theta = _random_standard(robot, rng)
        tau = _rnea(robot, theta, q, qd, qdd).reshape(-1)
        err = np.max(np.abs(base.regressor(W) @ base.from_standard(theta) - tau)) / np.max(np.abs(tau))
        assert err < 1e-9, err
    # rank by an independent method: SVD of the standard regressor on the new states. The URDF's rotations
    # (pi/2 to 11 digits) leave structural dependences at ~1e-12 relative, not 1e-16 (and columns of ~1e-12,
    # which column equilibration would blow up to spurious directions): the rank is read in the gap between
    # 1e-10 and 1e-6 of the unscaled matrix, the criterion of the QR.
    s = np.linalg.svd(W, compute_uv=False)
    s = s / s[0]
    r = len(base)
    assert s[r - 1] > 1e-6 and (r == s.size or s[r] < 1e-10), (s[r - 1], s[r:r + 1])
    assert np.linalg.matrix_rank(base.regressor(W)) == len(base)
    assert np.array_equal(base.matrix[:, base.independent], np.eye(len(base)))


def test_tx40_base_parameters_known_groupings(tx40_robot):
    """Classical regroupings of a 6R arm with a vertical first axis (Khalil & Dombre, ch. 12): the first link's
    only base inertial parameter is Izz1 (absorbing Ia1), m6 never appears alone, and every mass is regrouped."""
    base = tx40_robot.base()
    names = set(base.names)
    assert "Izz1'" in names
    assert not any(n.startswith("m") and n[1:].isdigit() for n in base.names)
    for j in range(9):
        assert f"{tx40_robot.names[j]}" not in names and f"{tx40_robot.names[j]}'" not in names  # link 1 but Izz1
    assert base.singular_gap > 1e6


def test_box_from_standard_encloses_random_images(tx40_robot):
    base = tx40_robot.base()
    rng = np.random.default_rng(4)
    lo = rng.uniform(-1, 0, tx40_robot.n_parameters)
    hi = lo + rng.uniform(0, 2, tx40_robot.n_parameters)
    blo, bhi = base.box_from_standard(lo, hi)
    pts = rng.uniform(lo, hi, (2000, lo.size))
    pts[:10] = np.where(rng.random((10, lo.size)) < 0.5, lo, hi)  # vertices
    img = base.from_standard(pts)
    assert np.all(img >= blo) and np.all(img <= bhi)
    # exact for a linear map: the vertex maximising each row attains the upper end
    v = np.where(base.matrix > 0, hi, lo)
    assert np.allclose(np.einsum("ij,ij->i", base.matrix, v), bhi, rtol=1e-12, atol=1e-12)


def test_process_matches_scipy_filtering(tx40_robot):
    """The 6-joint processing (groups of 4 joints through ident.processing.filtering) against filtering each joint's
    column directly with numpy.convolve, and the bound against ||h||_1 times the raw bound."""
    from h4bench.ident.processing.filtering import decimation_fir

    log = tx40.load_log()
    base = tx40_robot.base()
    n = 4000
    eq = process(tx40_robot, base, log.q[:n], log.tau[:n], log.dt, cutoff_hz=100.0, decimation=20, numtaps=81,
                 speed_threshold=0.0, keep_raw=True)
    raw = eq.info["raw"]
    taps = decimation_fir(20, 81)
    L = taps.size
    for j in (0, 4, 5):
        rows = np.flatnonzero(eq.joint == j)
        full = np.convolve(raw["y"][:, j], taps, mode="valid")[::20]
        assert np.allclose(eq.y[rows], full[: rows.size], rtol=0, atol=1e-9 * np.max(np.abs(full)))
        col = np.convolve(raw["W"][:, j, 3], taps, mode="valid")[::20]
        assert np.allclose(eq.W[rows, 3], col[: rows.size], rtol=0, atol=1e-9 * (np.max(np.abs(col)) + 1))
    assert abs(eq.gain - np.abs(taps).sum()) < 1e-12
    assert np.all(eq.window[:, 1] - eq.window[:, 0] == L - 1)
    # the derivatives are those of ident.processing.filtering on the same joints
    b = eq.bound(np.arange(1.0, 7.0))
    assert np.all(b >= np.arange(1.0, 7.0)[eq.joint] * np.abs(taps).sum())


def test_rich_friction_columns():
    qd = np.array([[0.5, -2.0], [-0.1, 0.0]])
    cols, names = rich_friction_columns(qd, 0.2)
    assert names == ("fva1", "fva2", "fst1", "fst2", "fvq1", "fvq2")
    assert cols.shape == (2, 2, 6)
    assert cols[0, 0, 0] == 0.5 and cols[0, 1, 1] == 2.0 and cols[0, 0, 1] == 0.0
    assert np.isclose(cols[1, 0, 2], -np.exp(-0.5)) and cols[1, 1, 3] == 0.0
    assert cols[0, 1, 5] == -4.0


def test_bad_inputs_are_named(tx40_robot, tmp_path):
    with pytest.raises(ValueError, match="urdf"):
        SerialRobot(tmp_path / "missing.urdf")
    with pytest.raises(TypeError, match="urdf"):
        SerialRobot(3)
    with pytest.raises(ValueError, match="coupled_wrist"):
        tx40.robot(coupled_wrist=(4, 4))
    with pytest.raises(ValueError, match="q must have shape"):
        tx40_robot.regressor(np.zeros((3, 5)), np.zeros((3, 6)), np.zeros((3, 6)))
    with pytest.raises(ValueError, match="finite"):
        tx40_robot.regressor(np.full((2, 6), np.nan), np.zeros((2, 6)), np.zeros((2, 6)))
    with pytest.raises(ValueError, match="names"):
        base_parameters(np.eye(3), ["a", "b"])
    with pytest.raises(ValueError, match="extras"):
        tx40_robot.urdf_parameters({"nope": 1.0})


def test_prediction_envelope_against_linprog():
    """Endpoints enclose scipy's LP optimum (outer) and are tight to 1e-7 relative; inside the box evaluation."""
    from scipy.optimize import linprog

    from h4bench.ident.numerics.interval import point_matvec
    from h4bench.ident.robots.serial import prediction_envelope

    rng = np.random.default_rng(8)
    m, p = 300, 7
    W = rng.standard_normal((m, p)) * np.logspace(-2, 2, p)
    theta = rng.uniform(-1, 1, p)
    y = W @ theta + rng.uniform(-0.5, 0.5, m)
    b = np.full(m, 0.5)
    lo, hi = -3 * np.ones(p), 3 * np.ones(p)
    W_new = rng.standard_normal((12, p)) * np.logspace(-2, 2, p)
    elo, ehi, info = prediction_envelope(W, y, b, lo, hi, W_new)
    A, ub = np.vstack([W, -W]), np.r_[y + b, b - y]
    blo, bhi = point_matvec(W_new, lo, hi)
    for k in range(W_new.shape[0]):
        mn = linprog(W_new[k], A_ub=A, b_ub=ub, bounds=list(zip(lo, hi)), method="highs").fun
        mx = -linprog(-W_new[k], A_ub=A, b_ub=ub, bounds=list(zip(lo, hi)), method="highs").fun
        scale = 1 + abs(mn) + abs(mx)
        assert elo[k] <= mn + 1e-9 * scale and ehi[k] >= mx - 1e-9 * scale
        assert mn - elo[k] <= 1e-7 * scale and ehi[k] - mx <= 1e-7 * scale
        assert blo[k] <= elo[k] and ehi[k] <= bhi[k]
        assert elo[k] <= W_new[k] @ theta <= ehi[k]  # the truth is feasible
    assert info["lp_failures"] == 0
