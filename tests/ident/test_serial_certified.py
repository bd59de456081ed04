"""The derived interval equation of a serial robot (:mod:`ident.robots.serial_certified`).

Oracles: a synthetic log of the TX40 URDF (with friction, rotor inertia, offsets, the coupled wrist) whose true
motion is analytic (sums of sines: exact q, qd, qdd and exact bounds on |qd|, |qdd|), torques from pinocchio's
standard regressor at a known theta (the independent path: no weak form in it), positions quantised to 2^17
counts, torque errors uniform in +-e; the true weak-form rows by Gauss-Legendre quadrature (4 points per
sample step) of the analytic motion; pinocchio at random configurations for the geometric bounds; random
points of an Oettli-Prager set for the signed hull.
"""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident.estimators.uncertain_signed import signed_uncertain_hull
from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.processing.weakform import make_kernel
from h4bench.ident.robots import tx40
from h4bench.ident.robots.serial_certified import (
    certificate,
    certified_equation,
    check_motion_bounds,
    geometry_bounds,
)

DT = 1e-3
H = 40  # kernel half-width [steps]: 80 ms windows
COUNTS = 2**17
TORQUE_ERROR = 0.5


@pytest.fixture(scope="module")
def robot():
    return tx40.robot()


@pytest.fixture(scope="module")
def base(robot):
    return robot.base(200, 0)


def _trajectory(seed, vibration=0.0):
    """Sums of sines per joint; ``vibration`` [rad/s^2] adds a 250 Hz component of that acceleration amplitude
    (a period of 4 sample steps: the speed swings within each step, as on an arm whose one-step accelerations
    dominate its stated qdd_max)."""
    rng = np.random.default_rng(seed)
    om = np.array([1.3, 2.9, 5.1]) * 2 * np.pi / 3
    a = rng.uniform(0.1, 0.4, (6, 3))
    if vibration:
        om = np.r_[om, 2 * np.pi * 250.0]
        a = np.c_[a, np.full(6, vibration / om[-1] ** 2)]
    ph = rng.uniform(0, 2 * np.pi, (6, a.shape[1]))
    c = rng.uniform(-1, 1, 6)

    def traj(t):
        arg = om[None, None, :] * np.asarray(t)[:, None, None] + ph[None]
        return (c + (a * np.sin(arg)).sum(-1), (a * om * np.cos(arg)).sum(-1), -(a * om**2 * np.sin(arg)).sum(-1))

    return traj, (a * om).sum(1), (a * om**2).sum(1)


def _log(robot, seed=0, T=1.2, qdd_scale=1.0, torque_scale=1.0, counts=COUNTS, vibration=0.0):
    rng = np.random.default_rng(seed + 1)
    traj, qd_max, qdd_max = _trajectory(seed, vibration)
    theta = robot.urdf_parameters({"fv": rng.uniform(0.5, 3, 6), "Ia": rng.uniform(0.01, 0.3, 6),
                                   "off": rng.uniform(-0.5, 0.5, 6), "Iam": 0.01, "fvm": 0.3})
    # Coulomb friction 0: its sign flips make the torque jump, and a sample-instant torque needs a rate bound
    N = int(round(T / DT)) + 1
    q, qd, qdd = traj(np.arange(N) * DT)
    tau = (robot.regressor(q, qd, qdd) @ theta).reshape(N, 6)
    res = 2 * np.pi / counts
    q_meas = np.round(q / res) * res
    # the worst case for a kernel average: a slow square wave of the full amplitude (white noise averages out)
    square = np.sign(np.sin(2 * np.pi * np.arange(N)[:, None] * DT / 0.4 + rng.uniform(0, 2 * np.pi, 6)))
    tau_meas = tau + TORQUE_ERROR * np.where(square == 0, 1.0, square)
    tf = np.linspace(0, T, 20 * N)
    tauf = (robot.regressor(*traj(tf)) @ theta).reshape(-1, 6)
    rate = 1.5 * np.max(np.abs(np.diff(tauf, axis=0)), axis=0) / (tf[1] - tf[0])  # stated with a margin
    spec = ErrorSpec(n_joints=6, sample_period=DT, position_resolution=res, torque_error=torque_scale * TORQUE_ERROR,
                     torque_timing="sample", torque_rate=rate, qd_max=qd_max, qdd_max=qdd_scale * qdd_max)
    return traj, theta, q_meas, tau_meas, spec


def spec_toml(spec, *, kernel_steps: int, stride: int, refine: int) -> str:
    """The ``--spec`` TOML of a synthetic log of :func:`_log` (its ErrorSpec ``spec``, the square wave's amplitude
    as the torque error) with a ``[certified]`` table."""
    return f"""[error_model]
sample_period = {DT}
counts_per_turn = {COUNTS}
torque_timing = "sample"
torque_error = {TORQUE_ERROR}
torque_rate = {[float(v) for v in spec.torque_rate]}
qd_max = {[float(v) for v in spec.qd_max]}
qdd_max = {[float(v) for v in spec.qdd_max]}

[error_model.sources]
torque_error = "the synthetic log's square-wave amplitude"

[certified]
kernel_steps = {kernel_steps}
stride = {stride}
refine = {refine}
"""


def _true_rows(robot, theta, traj, eq, points=4):
    """int k Y(q, qd, qdd) dt and int k tau dt of the true motion, Gauss-Legendre (``points`` per sample step)."""
    k = make_kernel(2 * H, DT, "triangle").knots
    gx, gw = np.polynomial.legendre.leggauss(points)
    W, y = [], []
    for s in eq.window[::6, 0]:
        tt = (s + np.arange(2 * H)[:, None] + (gx[None, :] + 1) / 2) * DT
        kk = k[:-1, None] + (k[1:] - k[:-1])[:, None] * (gx[None, :] + 1) / 2
        Y = robot.regressor(*traj(tt.ravel())).reshape(-1, 6, robot.n_parameters)
        w = (kk * gw[None, :] / 2 * DT).ravel()
        Wr = np.einsum("n,njp->jp", w, Y)
        W.append(Wr)
        y.append(Wr @ theta)
    return np.concatenate(W), np.concatenate(y)


@pytest.fixture(scope="module")
def synthetic(robot, base):
    traj, theta, q, tau, spec = _log(robot)
    eq = certified_equation(robot, base, q, tau, spec, half_width=H, stride=H)
    W_true, y_true = _true_rows(robot, theta, traj, eq)
    return eq, W_true[:, base.independent], y_true, base.from_standard(theta), spec, q


def test_geometry_bounds_hold_at_random_configurations(robot):
    import pinocchio as pin

    geo = geometry_bounds(robot)
    rng = np.random.default_rng(3)
    m, d = robot.model, robot.data
    Z, I = np.zeros(6), np.eye(6)
    worst = {"M": 0.0, "dM": 0.0, "g": 0.0, "h": 0.0}
    for _ in range(40):
        q = rng.uniform(-np.pi, np.pi, 6)
        v = rng.normal(0, 2, 6)
        kq = rng.integers(6)
        g0 = pin.computeJointTorqueRegressor(m, d, q, Z, Z).copy()
        h = pin.computeJointTorqueRegressor(m, d, q, v, Z) - g0
        worst["g"] = max(worst["g"], np.abs(g0).max() / geo["g"])
        worst["h"] = max(worst["h"], np.abs(h).max() / (geo["gamma"] * np.abs(v).sum() ** 2))
        for b in range(6):
            M = pin.computeJointTorqueRegressor(m, d, q, Z, I[b]) - g0
            qk = q + 1e-6 * I[kq]
            Mk = pin.computeJointTorqueRegressor(m, d, qk, Z, I[b]) - pin.computeJointTorqueRegressor(m, d, qk, Z, Z)
            worst["M"] = max(worst["M"], np.abs(M).max() / geo["M"])
            worst["dM"] = max(worst["dM"], np.abs(Mk - M).max() / 1e-6 / geo["dM"])
    assert all(v <= 1.0 for v in worst.values()), worst
    assert worst["M"] > 0.3 and worst["dM"] > 0.3  # the bounds are not vacuous either


def test_derived_radii_cover_the_actual_errors_row_by_row(synthetic):
    eq, W_true, y_true, theta, spec, q = synthetic
    cert = certificate(eq, W_true, y_true, theta)
    assert cert["rows"] == len(eq) > 150
    assert cert["entry_violations"] == 0 and cert["torque_violations"] == 0 and cert["violations"] == 0
    assert cert["min_margin"] > 0
    # the torque term is what the spec says (torque_error + rate dt / 2 times int k = 1)
    assert np.allclose(eq.terms["torque"][eq.joint == 0], TORQUE_ERROR + spec.torque_rate[0] * DT / 2, rtol=1e-9)
    # the square wave's plateaus use most of the torque bound
    assert 0.5 < np.max(np.abs(eq.y - y_true) / eq.bound) <= 1.0
    assert check_motion_bounds(q, spec).contradicted == []


def test_radii_cover_the_actual_errors_when_the_speed_swings_within_each_step(robot, base):
    """A fine encoder (2^24 counts: the secants span one step, m = 1, where the speed deviation's quadratic term
    takes its mean-square bound) and a 250 Hz vibration of 300 rad/s^2 (the speed deviates from each step's
    secant by up to about qdd_max dt / 2 within the step): every entry and row within its radius against the
    true rows (12 Gauss-Legendre points per step: the vibration is resolved)."""
    traj, theta, q, tau, spec = _log(robot, counts=2**24, vibration=300.0)
    eq = certified_equation(robot, base, q, tau, spec, half_width=H, stride=2 * H)
    assert eq.info["secant_half_span"] == 1
    W_true, y_true = _true_rows(robot, theta, traj, eq, points=12)
    cert = certificate(eq, W_true[:, base.independent], y_true, base.from_standard(theta))
    assert cert["entry_violations"] == 0 and cert["torque_violations"] == 0 and cert["violations"] == 0
    assert cert["parts"]["coriolis_motion"]["median"] > 0
    assert check_motion_bounds(q, spec).contradicted == []


def test_hull_encloses_the_true_base_parameters_and_narrows_some(robot, base, synthetic):
    eq, W_true, y_true, theta, spec, q = synthetic
    lo_s, hi_s = tx40.standard_prior(robot)
    blo, bhi = base.box_from_standard(lo_s, hi_s)
    box = signed_uncertain_hull(eq.Wc, eq.D, eq.y, eq.bound, ident.Box(blo, bhi, names=base.names))
    assert np.all(box.contains(theta))
    assert np.min((box.upper - box.lower) / (bhi - blo)) < 0.75  # informative on a few parameters only (a 1.2 s log)


def test_a_lying_spec_is_caught(robot, base):
    """A torque error stated at 0.4 of the real one: the torque side and whole rows are violated against the
    truth. A qdd_max stated 20 times too small: the data themselves prove it false (the rows' radii keep a
    margin: the largest actual error is about 0.15 of its radius on this log, so they do not catch it)."""
    traj, theta, q, tau, spec = _log(robot, torque_scale=0.4)
    eq = certified_equation(robot, base, q, tau, spec, half_width=H, stride=2 * H)
    W_true, y_true = _true_rows(robot, theta, traj, eq)
    cert = certificate(eq, W_true[:, base.independent], y_true, base.from_standard(theta))
    assert cert["torque_violations"] > 0 and cert["violations"] > 0 and cert["min_margin"] < 0
    _, _, q, _, spec = _log(robot, qdd_scale=0.05)
    assert any("qdd_max" in c for c in check_motion_bounds(q, spec).contradicted)


def test_signed_hull_encloses_random_points_of_the_oettli_prager_set():
    rng = np.random.default_rng(5)
    m, p = 60, 4
    Wc = rng.normal(size=(m, p))
    D = 0.05 * np.abs(rng.normal(size=(m, p)))
    theta0 = np.array([1.0, -0.5, 0.2, -2.0])
    y = Wc @ theta0 + rng.uniform(-0.3, 0.3, m)
    b = np.full(m, 0.3)
    prior = ident.Box(np.full(p, -5.0), np.full(p, 5.0))
    box = signed_uncertain_hull(Wc, D, y, b, prior)
    pts = theta0 + rng.uniform(-0.3, 0.3, (20000, p))
    feasible = np.all(np.abs(y[None] - pts @ Wc.T) <= b + np.abs(pts) @ D.T, axis=1)
    assert feasible.sum() > 20
    assert all(np.all(box.contains(t)) for t in pts[feasible])
    assert np.all(box.upper - box.lower < 10.0)


def test_bad_inputs_are_named(robot, base):
    spec = ErrorSpec(n_joints=6, sample_period=DT, position_resolution=1e-5, torque_error=1.0, qd_max=1.0,
                     qdd_max=1.0)
    q = np.zeros((500, 6))
    with pytest.raises(ValueError, match="half_width"):
        certified_equation(robot, base, q, q, spec, half_width=1, stride=10)
    with pytest.raises(ValueError, match="q, tau"):
        certified_equation(robot, base, q, q[:, :5], spec, half_width=10, stride=10)
    with pytest.raises(ValueError, match="samples"):
        certified_equation(robot, base, q[:30], q[:30], spec, half_width=20, stride=10)
    with pytest.raises(ValueError, match="spec"):
        certified_equation(robot, base, q, q, ErrorSpec(n_joints=5, sample_period=DT, position_resolution=1e-5,
                                                        torque_error=1.0, qd_max=1.0, qdd_max=1.0),
                           half_width=10, stride=10)


def test_family_stacks_each_kernels_rows(robot, base, monkeypatch):
    """certified_family: the rows of each kernel of the family, as certified_equation gives them alone (the
    oracle: the kernels share one pass of the per-step stage, each window the same bits), stacked in the family's
    order; the family named in info. One or two processes: the same bits. A short family (40 and 64 steps) keeps it
    fast."""
    from h4bench.ident.processing.choice import kernel_family
    from h4bench.ident.robots import serial_certified as sc

    monkeypatch.setattr(sc, "SERIAL_FAMILY", {"shortest_s": 0.04, "longest_s": 0.064, "factor": 1.6})
    _, _, q, tau, spec = _log(robot, T=0.8)
    fam = kernel_family(q.shape[0], DT, 10, even=True, **sc.SERIAL_FAMILY)
    assert fam.steps == (40, 64)
    eq = sc.certified_family(robot, base, q, tau, spec, stride=10)
    assert eq.info["kernels"]["steps"] == [40, 64]
    # the windows of the log's second half in a worker process: the same bits
    two = sc.certified_family(robot, base, q, tau, spec, stride=10, processes=2)
    for name in ("Wc", "D", "y", "bound", "joint", "window"):
        np.testing.assert_array_equal(getattr(two, name), getattr(eq, name))
    one_kernel = dict(half_width=20, stride=7)  # a stride that no block boundary divides
    a = sc.certified_equation(robot, base, q, tau, spec, **one_kernel)
    b = sc.certified_equation(robot, base, q, tau, spec, **one_kernel, processes=2)
    for k in a.terms:
        np.testing.assert_array_equal(b.terms[k], a.terms[k])
    np.testing.assert_array_equal(b.Wc, a.Wc)
    # no stated stride: every kernel's L // SERIAL_OVERLAP, or denser on a short log (here 800 samples: (N - L) // 128)
    wide = sc.certified_family(robot, base, q, tau, spec)
    assert wide.info["kernels"]["strides"] == [min(L // sc.SERIAL_OVERLAP, (q.shape[0] - L) // sc.SERIAL_WINDOWS)
                                               for L in (40, 64)] == list(sc.serial_strides(q.shape[0], (40, 64)))
    at = 0
    for L, st in zip(fam.steps, fam.strides):
        one = sc.certified_equation(robot, base, q, tau, spec, half_width=L // 2, stride=st)
        sl = slice(at, at + len(one))
        for name in ("Wc", "D", "y", "bound", "joint", "window"):
            np.testing.assert_array_equal(getattr(eq, name)[sl], getattr(one, name))
        for k in one.terms:
            np.testing.assert_array_equal(eq.terms[k][sl], one.terms[k])
        at += len(one)
    assert at == len(eq) == eq.info["rows"]
