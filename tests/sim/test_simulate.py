"""The closed-loop experiment: noise, quantisation, measured vs applied torques, exactness on the truth."""

from __future__ import annotations

import numpy as np
import pytest

import ident
import sim
from tests.conftest import cartesian_reference, friction_saturated, run_experiment


@pytest.fixture(scope="module")
def experiment(model, geometry):
    return run_experiment(model, geometry, seconds=3.0, noise=sim.TorqueNoise(1.0, "uniform"), seed=3)


@pytest.mark.parametrize("shape", ["uniform", "square", "sine"])
def test_noise_shapes_are_bounded(shape):
    t = np.arange(5000) * 1e-3
    e = sim.TorqueNoise(1.5, shape, frequency_hz=3.0).sample(t, np.random.default_rng(0))
    assert e.shape == (5000, 4) and np.abs(e).max() <= 1.5
    if shape == "square":  # the worst case sits on the bound
        np.testing.assert_array_equal(np.abs(e), 1.5)
    else:
        assert np.abs(e).max() > 1.4


def test_noise_array_is_checked():
    t = np.arange(10) * 1e-3
    with pytest.raises(sim.SimulationError, match=r"within \+-bound"):
        sim.TorqueNoise(1.0, "array", values=np.full((10, 4), 1.2)).sample(t, np.random.default_rng(0))
    with pytest.raises(sim.SimulationError, match=r"shape \(10, 4\)"):
        sim.TorqueNoise(1.0, "array", values=np.zeros((9, 4))).sample(t, np.random.default_rng(0))
    with pytest.raises(sim.SimulationError, match="noise shape must be one of"):
        sim.TorqueNoise(1.0, "gaussian")
    with pytest.raises(sim.SimulationError, match="bound must be a finite number >= 0"):
        sim.TorqueNoise(-1.0)


def test_measured_torque_is_the_command_and_noise_is_bounded(experiment):
    ref, data, truth = experiment
    np.testing.assert_allclose(truth.tau_applied - data.tau, truth.noise)
    assert np.abs(truth.noise).max() <= 1.0
    assert np.abs(truth.noise).max() > 0.95
    assert np.abs(data.tau).max() <= 15.0


def test_encoder_quantisation(experiment):
    _, data, truth = experiment
    res = 2 * np.pi / 20000
    assert np.abs(data.q - truth.q).max() <= res / 2 + 1e-15
    steps = data.q / res
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)


def test_tracking_and_loop_closure(experiment):
    ref, data, truth = experiment
    assert np.abs(truth.q - ref.q).max() < 0.01  # rad, with 1 N m torque noise
    assert truth.loop_violation.max() < 1e-5


def test_truth_is_exact_at_the_sample_instants(model, geometry, experiment):
    """The recorded exact state and MuJoCo's acceleration satisfy the paper's equation with the applied torque."""
    _, data, truth = experiment
    keep = friction_saturated(truth.qd, truth.qdd, truth.h)
    tau = ident.inverse_dynamics(geometry, truth.theta, truth.q, truth.qd, truth.qdd, x=truth.x, xdd=truth.xdd)
    assert np.abs(tau - truth.tau_applied)[keep].max() < 1e-6
    np.testing.assert_array_equal(truth.theta, sim.true_parameters(model))


def test_same_seed_same_data(model, geometry):
    a = run_experiment(model, geometry, seconds=0.5, noise=sim.TorqueNoise(1.0), seed=7)
    b = run_experiment(model, geometry, seconds=0.5, noise=sim.TorqueNoise(1.0), seed=7)
    np.testing.assert_array_equal(a[1].q, b[1].q)
    np.testing.assert_array_equal(a[1].tau, b[1].tau)


def test_bad_simulation_input(model, geometry):
    ref = cartesian_reference(geometry, seconds=0.1)
    _, ctrl = sim.default_controller(geometry, np.array([0.012] * 4 + [1.0, 0.003] + [0.1] * 4 + [1.0] * 4))
    ref.t = np.arange(ref.t.size) * 1.2e-3  # not a multiple of the 0.5 ms timestep
    with pytest.raises(sim.SimulationError, match="multiple of the model timestep"):
        sim.simulate(model, ref, controller=ctrl)
    with pytest.raises(sim.SimulationError, match="controller must be given"):
        sim.simulate(model, cartesian_reference(geometry, seconds=0.1))
    bad = cartesian_reference(geometry, seconds=0.1)
    bad.q = bad.q[:, :3]
    with pytest.raises(sim.SimulationError, match=r"reference.q must be finite with shape"):
        sim.simulate(model, bad, controller=ctrl)
