"""The vectorised certified equation of a serial arm against the per-window reference (the previous implementation).

Oracle: :func:`ident.robots.serial_reference.inertial_rows_reference` (``certified_equation(..., reference=True)``):
one pinocchio regressor call per (window, step) pair and the per-step bounds one step at a time, on the same logs.
Robots: the TX40 (coupled wrist) synthetic log of ``test_serial_certified`` and a UR5 (``examples/own_arm/ur5.urdf``, the
example-robot-data URDF, its meshes not read) on the same analytic sum-of-sines motion; for the UR5 also the soundness
certificate against the true rows (Gauss-Legendre quadrature of the analytic motion).

Tolerances, from the a-priori error bounds of the two computations (u = 2^-53):

* the radii (``parts``, ``terms`` position and motion): sums of L to 3 L non-negative terms in another order,
  each within ``gamma`` of the exact sum, so within ``rtol = 8 (L + 4) u`` of each other (the equation's own
  ``gamma_l``); the torque side and the extra columns: the same code, equal bit for bit;
* ``Wc``: within the floating-point radii of the two (``terms['float']`` of each), plus ``2^-44`` of the column's
  largest entry: entries that are zero in exact arithmetic (not structurally: an axis or an offset of the URDF)
  come out of pinocchio as rounding noise (about 1e-16 N m here) on both sides, which the stated relative
  allowance of pinocchio's error does not cover in either computation;
* ``terms['float']``: never below the reference's (the vectorised one adds the reconstruction's rounding bound)
  but for the float radius of the noise entries above, and ``D`` accordingly: never below the reference's, above
  it by at most that addition.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.processing.weakform import make_kernel
from h4bench.ident.robots import tx40
from h4bench.ident.robots.chain import live_entries
from h4bench.ident.robots.serial import SerialRobot
from h4bench.ident.robots.serial_certified import certificate, certified_equation, geometry_bounds, secant_span
from h4bench.ident.robots.serial_reference import inertial_rows_reference
from h4bench.ident.robots.serial_steps import PARTS, inertial_rows
from tests.ident.test_serial_certified import COUNTS, DT, H, _log, _trajectory, _true_rows

U = 2.0**-53
UR5 = Path(__file__).parents[2] / "examples" / "own_arm" / "ur5.urdf"


@pytest.fixture(scope="module")
def tx():
    robot = tx40.robot()
    return robot, robot.base(200, 0), _log(robot)


@pytest.fixture(scope="module")
def ur5():
    robot = SerialRobot(UR5)
    return robot, robot.base(200, 0), _ur5_log(robot)


def _ur5_log(robot, seed=2, T=0.6):
    """The analytic motion of ``test_serial_certified`` on the UR5: exact torques at the sample instants from the
    URDF's parameters plus friction and offsets, positions rounded to 2^17 counts, torque errors +-0.5 N m."""
    rng = np.random.default_rng(seed)
    traj, qd_max, qdd_max = _trajectory(seed)
    theta = robot.urdf_parameters({"fv": rng.uniform(0.5, 3, 6), "Ia": rng.uniform(0.01, 0.3, 6),
                                   "off": rng.uniform(-0.5, 0.5, 6)})
    N = int(round(T / DT)) + 1
    q, qd, qdd = traj(np.arange(N) * DT)
    tau = (robot.regressor(q, qd, qdd) @ theta).reshape(N, 6) + rng.uniform(-0.5, 0.5, (N, 6))
    res = 2 * np.pi / COUNTS
    tf = np.linspace(0, T, 20 * N)
    tauf = (robot.regressor(*traj(tf)) @ theta).reshape(-1, 6)
    rate = 1.5 * np.max(np.abs(np.diff(tauf, axis=0)), axis=0) / (tf[1] - tf[0])
    spec = ErrorSpec(n_joints=6, sample_period=DT, position_resolution=res, torque_error=0.5,
                     torque_timing="sample", torque_rate=rate, qd_max=qd_max, qdd_max=qdd_max)
    return traj, theta, np.round(q / res) * res, tau, spec


def _assert_same_equation(new, old, L):
    rtol = 8 * (L + 4) * U
    for name in ("y", "bound", "joint", "window"):
        assert np.array_equal(getattr(new, name), getattr(old, name)), name
    for name in ("coulomb", "torque", "model", "rounding"):
        assert np.array_equal(new.terms[name], old.terms[name]), name
    for name, arr in [*((f"parts.{k}", new.parts[k]) for k in PARTS),
                      *((f"terms.{k}", new.terms[k]) for k in ("position", "motion"))]:
        ref = old.parts[name[6:]] if name.startswith("parts") else old.terms[name[6:]]
        assert np.all(np.abs(arr - ref) <= rtol * ref), (name, np.max(np.abs(arr - ref) / np.maximum(ref, 1e-300)))
    fn, fo = new.terms["float"], old.terms["float"]
    col = np.max(np.abs(old.Wc), axis=0)
    assert np.all(np.abs(new.Wc - old.Wc) <= fn + fo + 2.0**-44 * col)
    noise = (1e-12 + rtol) * L * 2.0**-44 * col  # the float radius of an entry made of pinocchio's noise
    assert np.all(fn >= fo * (1 - rtol) - noise)
    assert np.all(new.D >= old.D * (1 - rtol) - noise)
    assert np.all(new.D - old.D <= (fn - fo) * (1 + rtol) + rtol * old.D + noise)


@pytest.mark.parametrize("half_width, stride, shape", [
    pytest.param(H, H, "triangle", marks=pytest.mark.slow),  # the soundness fixture's rows (test_serial_certified)
    (12, 7, "hann"),  # many windows, a stride that does not divide the kernel
    (30, 300, "triangle"),  # windows further apart than a block of steps: the held steps restart
])
def test_tx40_equation_matches_the_reference(tx, half_width, stride, shape):
    robot, base, (_, _, q, tau, spec) = tx
    kw = {"half_width": half_width, "stride": stride, "kernel_shape": shape}
    new = certified_equation(robot, base, q, tau, spec, **kw)
    old = certified_equation(robot, base, q, tau, spec, reference=True, **kw)
    assert len(new) == len(old) >= 24  # 4 windows or more
    _assert_same_equation(new, old, 2 * half_width)


@pytest.mark.parametrize("memory", [1, pytest.param(2**27, marks=pytest.mark.slow)])  # one window per batch / many
def test_ur5_window_sums_match_the_reference(ur5, memory):
    """The inertial sums themselves (standard columns, before the base columns): Wi, the magnitudes, every part;
    windows in blocks, a stride that does not divide the kernel, a secant half-span over 1."""
    robot, _, (_, _, q, _, spec) = ur5
    e = spec.position_error(q)
    m = secant_span(spec, float(np.median(e)))
    kern = make_kernel(30, DT, "triangle")
    starts = np.arange(m, q.shape[0] - m - 30, 13)
    progress = []
    Wi, mag, recon, parts = inertial_rows(robot, geometry_bounds(robot), q, e, spec, m, kern, starts,
                                          lambda d, t: progress.append((d, t)), memory=memory)
    Wr, magr, _, partsr = inertial_rows_reference(robot, geometry_bounds(robot), q, e, spec, m, kern, starts)
    rtol = 8 * (30 + 4) * U
    gamma = (1e-12 + rtol) * magr  # the floating-point allowance of the reference's sums
    scale = np.max(np.abs(Wr), axis=(0, 1))  # per standard column, over windows and rows
    assert np.all(np.abs(Wi - Wr) <= gamma + recon + 2.0**-44 * scale)
    assert np.all(np.abs(mag - magr) <= rtol * magr + 2.0**-44 * scale)
    # the entries a chain cannot fill (joint j, a body before j): zero in both regressors; the vectorised stage
    # leaves them out (0), the reference adds its global terms there too (the equation masks them either way)
    live = np.zeros(6 * 60, dtype=bool)
    live[live_entries(6)] = True
    live = live.reshape(6, 60)
    assert np.all(Wr[:, ~live] == 0) and np.all(Wi[:, ~live] == 0)
    for name in PARTS:
        assert np.all(parts[name][:, ~live] == 0), name
        assert np.all(np.abs(parts[name] - partsr[name])[:, live] <= rtol * partsr[name][:, live]), name
    assert progress[-1] == (starts.size, starts.size)


def test_ur5_equation_is_sound_and_matches_the_reference(ur5):
    robot, base, (traj, theta, q, tau, spec) = ur5
    new = certified_equation(robot, base, q, tau, spec, half_width=H, stride=10)
    old = certified_equation(robot, base, q, tau, spec, half_width=H, stride=10, reference=True)
    _assert_same_equation(new, old, 2 * H)
    W_true, y_true = _true_rows(robot, theta, traj, new)
    cert = certificate(new, W_true[:, base.independent], y_true, base.from_standard(theta))
    assert cert["entry_violations"] == 0 and cert["torque_violations"] == 0 and cert["violations"] == 0
    assert cert["min_margin"] > 0
