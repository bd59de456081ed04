"""Fourier excitation: conditioning, feasibility re-checked with sim/ident, exact derivatives against finite
differences, rest at both ends, the slow/fast schedule, the optimiser's fast path and gradients."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from h4bench import ident
from h4bench import sim
from h4bench import trajectories as tj
from tests.conftest import random_workspace_poses
from h4bench.trajectories.design import CONSTRAINT_NAMES, CoefficientProblem, fast_motion
from h4bench.trajectories.fourier import START_SCALE, PhaseSchedule, fourier_basis


def scaled_cond(geometry, traj):
    """cond(W diag(theta_nominal)) of ident.regressor on the reference, forward kinematics recomputed."""
    W = ident.regressor(geometry, traj.q, traj.qd, traj.qdd)
    return np.linalg.cond(W * tj.nominal_parameters()[None])


def test_optimised_conditioning_beats_the_seeded_start(geometry, excitation, excitation_start):
    before, after = scaled_cond(geometry, excitation_start), scaled_cond(geometry, excitation)
    assert after < 0.5 * before, (before, after)
    opt = excitation.parameters["optimisation"]
    # the coarse-grid figures the optimiser saw agree with the full-resolution ones to 10 %
    assert opt["cond_start"] == pytest.approx(before, rel=0.1)
    assert opt["cond_optimised"] == pytest.approx(after, rel=0.1)
    assert excitation.checks["cond_W_scaled"] == pytest.approx(after, rel=1e-9)


@pytest.mark.parametrize("name", ["excitation", "excitation_start", "short_excitation"])
def test_every_sample_passes_an_independent_recheck(geometry, request, name):
    traj = request.getfixturevalue(name)
    lim = tj.Limits()
    q_ik = sim.inverse_kinematics(geometry, traj.x)  # raises if any sample is unreachable
    assert np.abs(q_ik - traj.q).max() < 1e-9
    assert np.all(traj.x >= np.array(lim.x_lower)) and np.all(traj.x <= np.array(lim.x_upper))
    assert np.all(traj.q >= geometry.q_range[:, 0] + lim.q_margin)
    assert np.all(traj.q <= geometry.q_range[:, 1] - lim.q_margin)
    assert sim.singularity_measure(geometry, traj.x).max() <= lim.max_cond_jx
    assert np.abs(traj.qd).max() <= 8.0 and np.abs(traj.qdd).max() <= 150.0
    tau = ident.inverse_dynamics(geometry, tj.nominal_parameters(), traj.q, traj.qd, traj.qdd)  # FK inside
    assert np.abs(tau).max() <= 0.8 * 15.0
    assert traj.checks["feasible"] and traj.checks["violations"] == {}


def test_the_optimiser_uses_the_limits(excitation):
    """The optimum presses against a limit (a design far inside every limit would not be optimal)."""
    assert max(excitation.checks["usage"].values()) > 0.8


def test_derivatives_agree_with_central_differences(excitation):
    """Central differences have error (h^2 / 6) max|next derivative|: O(dt^2), quartered when h halves."""
    q, qd, qdd, dt = excitation.q, excitation.qd, excitation.qdd, excitation.dt
    jerk = np.abs(np.diff(qdd, axis=0)).max() / dt
    snap = np.abs(np.diff(qdd, 2, axis=0)).max() / dt**2
    errs = []
    for h in (1, 2):
        e_qd = np.abs((q[2 * h:] - q[:-2 * h]) / (2 * h * dt) - qd[h:-h]).max()
        e_qdd = np.abs((qd[2 * h:] - qd[:-2 * h]) / (2 * h * dt) - qdd[h:-h]).max()
        assert e_qd <= 1.1 * (h * dt) ** 2 / 6 * jerk + 1e-9
        assert e_qdd <= 1.1 * (h * dt) ** 2 / 6 * snap + 1e-7
        errs.append((e_qd, e_qdd))
    assert 3.5 < errs[1][0] / errs[0][0] < 4.5 and 3.5 < errs[1][1] / errs[0][1] < 4.5


def test_nacelle_motion_is_consistent_with_the_joint_motion(geometry, excitation):
    """x = FK(q) and the nacelle velocity J qd equals the central difference of x."""
    k = slice(0, None, 97)
    np.testing.assert_allclose(sim.forward_kinematics(geometry, excitation.q[k]), excitation.x[k], atol=1e-10)
    _, xd, _ = sim.cartesian_motion(geometry, excitation.q, excitation.qd, excitation.qdd, x=excitation.x)
    fd = (excitation.x[2:] - excitation.x[:-2]) / (2 * excitation.dt)
    assert np.abs(fd - xd[1:-1]).max() < 1e-3 * np.abs(xd).max()


@pytest.mark.parametrize("name", ["excitation", "short_excitation"])
def test_starts_and_ends_at_rest_at_home(geometry, request, name):
    traj = request.getfixturevalue(name)
    for k in (0, -1):
        assert np.all(traj.qd[k] == 0.0) and np.all(traj.qdd[k] == 0.0)
        np.testing.assert_allclose(traj.x[k], geometry.x_home, atol=1e-12)
    np.testing.assert_allclose(traj.q[0], sim.inverse_kinematics(geometry, geometry.x_home), atol=1e-12)
    assert traj.t[0] == 0.0 and traj.dt == pytest.approx(1e-3) and traj.duration == pytest.approx(10.0 if
                                                                                                  name == "excitation"
                                                                                                  else 4.0)


def test_slow_phase_is_slow_and_fast_phase_fast(excitation):
    p = excitation.parameters
    knots = np.array(p["schedule_knots"])
    slow = (excitation.t > knots[1]) & (excitation.t < knots[2])
    fast = (excitation.t > knots[3]) & (excitation.t < knots[4])
    v_slow, v_fast = np.abs(excitation.qd[slow]).max(), np.abs(excitation.qd[fast]).max()
    assert v_slow < 2 * p["slow_ratio"] * v_fast  # phase speed ratio 0.2; the path differs between the phases
    assert np.abs(excitation.qd[slow]).max(axis=0).min() > 0.05  # still moving: friction is excited
    assert p["base_hz"] == pytest.approx(p["base_hz_requested"], rel=0.2)
    assert p["cycles"] == round(p["cycles"]) >= 1


def test_seeded_and_reproducible(geometry):
    a = tj.fourier_excitation(geometry, duration=3.0, seed=7, optimise=False)
    b = tj.fourier_excitation(geometry, duration=3.0, seed=7, optimise=False)
    c = tj.fourier_excitation(geometry, duration=3.0, seed=8, optimise=False)
    assert np.array_equal(a.q, b.q) and a.parameters["seed"] == 7
    assert not np.allclose(a.q, c.q)


def test_joint_space_series_is_supported_but_feasible_only_small(geometry):
    """space='joint': the start must shrink far more (theta's small Jacobian column) than in Cartesian space."""
    joint = tj.fourier_excitation(geometry, duration=3.0, seed=0, optimise=False, space="joint")
    cart = tj.fourier_excitation(geometry, duration=3.0, seed=0, optimise=False)
    assert joint.checks["feasible"]
    np.testing.assert_allclose(sim.forward_kinematics(geometry, joint.q[::50]), joint.x[::50], atol=1e-10)
    assert joint.parameters["space"] == "joint"
    assert joint.checks["cond_W_scaled"] > cart.checks["cond_W_scaled"]


@pytest.mark.slow
def test_joint_space_optimisation(geometry):
    traj = tj.fourier_excitation(geometry, duration=4.0, seed=0, space="joint")
    assert traj.checks["feasible"]
    assert traj.parameters["optimisation"]["cond_optimised"] < traj.parameters["optimisation"]["cond_start"]


def test_fourier_trajectory_rebuilds_a_saved_design_exactly(geometry, short_excitation):
    again = tj.fourier_trajectory(geometry, short_excitation.parameters)
    for name in ("x", "q", "qd", "qdd"):
        np.testing.assert_array_equal(getattr(again, name), getattr(short_excitation, name))


def test_fast_path_matches_sim_and_ident(geometry):
    rng = np.random.default_rng(5)
    x = random_workspace_poses(rng, 300)
    xd, xdd = rng.normal(0, 0.5, (300, 4)), rng.normal(0, 10, (300, 4))
    m = fast_motion(geometry, x, xd, xdd)
    q = sim.inverse_kinematics(geometry, x)
    jac = sim.jacobians(geometry, q, x=x)
    qd = np.linalg.solve(jac.J, xd[..., None])[..., 0]
    jd = sim.jacobian_dot(geometry, q, qd, x=x)
    qdd = np.linalg.solve(jac.J, (xdd - np.einsum("nab,nb->na", jd, qd))[..., None])[..., 0]
    np.testing.assert_allclose(m["q"], q, atol=1e-12)
    np.testing.assert_allclose(m["qd"], qd, atol=1e-9)
    np.testing.assert_allclose(m["qdd"], qdd, atol=1e-7)
    np.testing.assert_allclose(m["Jx"], jac.Jx, atol=1e-14)
    W = ident.regressor(geometry, q, qd, qdd, x=x).reshape(300, 4, 14)
    np.testing.assert_allclose(m["mnac"], W[..., 4], atol=1e-9)
    np.testing.assert_allclose(m["ibc"], W[..., 5], atol=1e-9)


@pytest.mark.parametrize("space, near", [("cartesian", False), ("cartesian", True), ("joint", False)])
def test_optimiser_gradients_match_central_differences(geometry, space, near):
    """Chain-rule gradients against central differences of the whole objective and constraints. cond(Jx)'s
    gradient is exact near its limit and deliberately zero far from it (below 0.8 x the limit)."""
    T, H = 4.0, 3
    shape = PhaseSchedule.slow_fast(T, 0.3, 0.2, 0.5, 0.5)
    sched = PhaseSchedule.slow_fast(T, 0.3, 0.2, 0.5, 0.5, 2 / shape.total)
    phi, phid, phidd = sched(np.linspace(0, T, 120))
    centre = geometry.x_home if space == "cartesian" else sim.inverse_kinematics(geometry, geometry.x_home)
    z = np.random.default_rng(2).normal(0, 0.3 if space == "cartesian" else 0.1, 2 * H * 4)

    def problem(max_cond_jx):
        return CoefficientProblem(geometry, space, centre, fourier_basis(H, phi), phid, phidd, START_SCALE[space],
                                  tj.Limits(max_cond_jx=max_cond_jx), tj.nominal_parameters(), 0.95)

    worst = problem(100.0).outputs(problem(100.0).inputs(z))[:, -1].max()
    prob = problem(worst / 0.95 * 1.1 if near else 100.0)
    log_cond, cons, grad, dcons = prob.evaluate(z, gradient=True)
    assert np.isfinite(log_cond) and np.all(np.isfinite(cons))
    h = 1e-6
    fd = np.array([(prob.evaluate(z + h * e)[0] - prob.evaluate(z - h * e)[0]) / (2 * h) for e in np.eye(z.size)])
    fdc = np.array([(prob.evaluate(z + h * e)[1] - prob.evaluate(z - h * e)[1]) / (2 * h) for e in np.eye(z.size)]).T
    assert np.abs(grad - fd).max() <= 1e-4 * np.abs(fd).max()
    jx = CONSTRAINT_NAMES.index("cond_jx:0")
    assert (cons[jx] >= -0.2) == near
    if not near:
        assert worst < 0.8 * 95.0 and np.all(dcons[jx] == 0.0)
        dcons, fdc = np.delete(dcons, jx, axis=0), np.delete(fdc, jx, axis=0)
    else:
        assert np.abs(dcons[jx]).max() > 0
    assert np.abs(dcons - fdc).max() <= 1e-4 * np.abs(fdc).max()


@settings(max_examples=40, deadline=None)
@given(duration=st.floats(2.0, 30.0), slow_fraction=st.floats(0.0, 0.5), slow_ratio=st.floats(0.05, 1.0),
       speed=st.floats(0.1, 3.0))
def test_phase_schedule_derivatives_and_total(duration, slow_fraction, slow_ratio, speed):
    sched = PhaseSchedule.slow_fast(duration, slow_fraction * (duration - 1.5) / duration, slow_ratio, 0.5, 0.5,
                                    speed)
    t = np.linspace(0, duration, 20001)
    phi, phid, phidd = sched(t)
    dt = t[1] - t[0]
    assert phi[0] == 0 and phid[0] == 0 and phid[-1] == 0 and phidd[0] == 0 and phidd[-1] == 0
    assert phi[-1] == pytest.approx(sched.total, rel=1e-12)
    assert np.all(phid >= 0) and np.all(np.diff(phi) >= 0)
    assert np.abs(np.gradient(phi, dt)[1:-1] - phid[1:-1]).max() < 1e-4 * speed + 1e-9
    assert np.abs(np.gradient(phid, dt)[1:-1] - phidd[1:-1]).max() < 1e-3 * speed / 0.5 + 1e-9


@pytest.mark.parametrize("kwargs, match", [
    ({"duration": -1.0}, "duration"),
    ({"duration": float("nan")}, "duration"),
    ({"harmonics": 0}, "harmonics"),
    ({"harmonics": 2.5}, "harmonics"),
    ({"base_hz": 0.0}, "base_hz"),
    ({"slow_fraction": 0.95}, "slow_fraction"),
    ({"slow_ratio": 1.5}, "slow_ratio"),
    ({"dt": 2.0}, "dt"),
    ({"space": "polar"}, "space"),
    ({"theta_nominal": np.ones(13)}, "theta_nominal"),
    ({"theta_nominal": np.full(14, np.nan)}, "theta_nominal"),
    ({"seed": "zero"}, "seed"),
    ({"limits": {"qd_max": 8}}, "limits"),
])
def test_bad_inputs_name_the_argument(geometry, kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        tj.fourier_excitation(geometry, **{"duration": 3.0, **kwargs})


def test_geometry_is_checked():
    with pytest.raises(TypeError, match="geometry"):
        tj.fourier_excitation("h4", duration=3.0)


def test_fourier_trajectory_validates(geometry, short_excitation):
    with pytest.raises(ValueError, match="duration"):
        tj.fourier_trajectory(geometry, short_excitation.parameters, duration=-2.0)
    with pytest.raises(ValueError, match="dt"):
        tj.fourier_trajectory(geometry, short_excitation.parameters, dt=float("nan"))
    with pytest.raises(ValueError, match="parameters must be a Fourier trajectory's parameters"):
        tj.fourier_trajectory(geometry, {"waypoints_x": []})
