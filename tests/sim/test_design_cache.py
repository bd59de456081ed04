"""Controller designs cached by their inputs (per process and on disk) are the designs computed afresh, bit for
bit; the simulation's float path through the noise stream gives the array path's results bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from h4bench import sim
from h4bench.sim import control_design as cd
from h4bench.sim import design_cache
from h4bench.sim.noise import TorqueError, realistic_drive
from h4bench.sim.noise.components import GainError, Ripple, Uniform
from tests.conftest import NOMINAL, cartesian_reference

J = np.array([0.031, 0.029, 0.034, 0.027])
FV = np.array([0.11, 0.09, 0.12, 0.10])
_FLOATS = ("bandwidth_hz", "crossover_hz", "phase_margin_deg", "gain_margin", "lower_gain_margin", "rise_time",
           "settling_time", "overshoot_pct")


def _same_design(a, b) -> None:
    for name in ("J", "Fv", "kp", "kv", "ki"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert (a.dt, a.velocity_filter_hz, a.bandwidth_hz, a.phase_margin_deg) == \
        (b.dt, b.velocity_filter_hz, b.bandwidth_hz, b.phase_margin_deg)
    for ra, rb in zip(a.continuous + a.discrete, b.continuous + b.discrete):
        for f in _FLOATS:
            x, y = getattr(ra, f), getattr(rb, f)
            assert x == y or (np.isnan(x) and np.isnan(y)), f
        assert ra.stable == rb.stable and ra.poles.dtype == rb.poles.dtype
        assert np.array_equal(ra.poles, rb.poles)
        assert np.array_equal(np.signbit(ra.poles.imag), np.signbit(rb.poles.imag))
    assert a.report() == b.report()


@pytest.fixture(scope="module")
def fresh():
    """The oracle: one design computed without any cache."""
    return cd._design(J, FV, 12.0, 1e-3, 60.0, 100.0)


def test_cached_designs_are_the_computed_ones(tmp_path, monkeypatch, fresh):
    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path))
    monkeypatch.setattr(cd, "_DESIGNS", {})
    calls = []
    monkeypatch.setattr(cd, "_design", lambda *a: calls.append(a) or fresh)  # computing is the oracle's job
    first = cd.design_joint_controller(J, FV, bandwidth_hz=12.0)
    assert len(calls) == 1 and first is fresh
    assert cd.design_joint_controller(J, FV, bandwidth_hz=12.0) is first  # per process: the same object
    files = list((tmp_path / "controllers").glob("*.json"))
    assert len(files) == 1
    monkeypatch.setattr(cd, "_DESIGNS", {})
    loaded = cd.design_joint_controller(J, FV, bandwidth_hz=12.0)  # a new process: from disk, exactly
    assert len(calls) == 1 and loaded is not fresh
    _same_design(loaded, fresh)
    with pytest.raises(ValueError):
        loaded.kp[0] = 1.0  # read-only like a computed design's
    cd.design_joint_controller(np.nextafter(J, 1.0), FV, bandwidth_hz=12.0)  # one bit of J: another design
    assert len(calls) == 2 and len(list((tmp_path / "controllers").glob("*.json"))) == 2
    files[0].write_text("{not json")  # a corrupt entry is recomputed, never trusted
    monkeypatch.setattr(cd, "_DESIGNS", {})
    cd.design_joint_controller(J, FV, bandwidth_hz=12.0)
    assert len(calls) == 3
    key = design_cache.design_key(J, FV, 12.0, 1e-3, 60.0, 100.0)  # an entry of other inputs under the key
    design_cache.store_design(key, dataclasses.replace(fresh, J=J * 1.5))
    monkeypatch.setattr(cd, "_DESIGNS", {})
    cd.design_joint_controller(J, FV, bandwidth_hz=12.0)
    assert len(calls) == 4
    with pytest.raises(ValueError, match="bandwidth_hz must be below the Nyquist"):  # checked before any cache
        cd.design_joint_controller(J, FV, bandwidth_hz=600.0)


def test_an_unwritable_design_cache_costs_nothing(tmp_path, monkeypatch, fresh):
    (tmp_path / "a-file").write_text("not a folder")
    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path / "a-file"))
    monkeypatch.setattr(cd, "_DESIGNS", {})
    monkeypatch.setattr(cd, "_design", lambda *a: fresh)
    assert cd.design_joint_controller(J, FV, bandwidth_hz=12.0) is fresh


def test_at_list_is_at_bit_for_bit():
    rng = np.random.default_rng(5)
    t = np.arange(200) * 1e-3
    model = TorqueError([Uniform(0.3), Ripple((1, 3), (0.1, 0.05)), GainError(0.02)])
    stream = model.start(t, np.random.default_rng(1))
    for k in range(0, 200, 7):
        q = rng.uniform(-3, 3, 4)
        tau = rng.uniform(-14, 14, 4)
        assert np.array_equal(np.array(stream.at_list(k, q.tolist(), tau.tolist())), stream.at(k, q, tau))
    fixed = sim.TorqueNoise(0.5, "uniform").start(t, np.random.default_rng(2))
    assert np.array_equal(np.array(fixed.at_list(3, None, None)), fixed.at(3, None, None))
    with pytest.raises(Exception, match="q must be finite"):
        stream.at_list(0, [np.nan, 0.0, 0.0, 0.0], [0.0] * 4)
    with pytest.raises(Exception, match="torque_limit"):
        stream.at_list(0, [0.0] * 4, [99.0, 0.0, 0.0, 0.0])


class _ArraysOnly:
    """A noise model whose stream hides ``at_list``: the simulator takes its array path."""

    def __init__(self, noise):
        self.noise, self.bound = noise, noise.bound

    def describe(self):
        return self.noise.describe()

    def start(self, t, rng):
        stream = self.noise.start(t, rng)
        return type("Stream", (), {"at": staticmethod(stream.at), "measured": staticmethod(stream.measured)})()


@pytest.mark.parametrize("noise", [realistic_drive(1.3), sim.TorqueNoise(1.0, "square", 2.0)],
                         ids=["realistic", "square"])
def test_float_path_equals_array_path(model, geometry, noise):
    ref = cartesian_reference(geometry, seconds=1.5, seed=3)
    from h4bench import ident

    ff = ident.inverse_dynamics(geometry, NOMINAL, ref.q, ref.qd, ref.qdd)
    out = []
    for n in (noise, _ArraysOnly(noise)):
        _, controller = sim.default_controller(geometry, NOMINAL)
        out.append(sim.simulate(model, ref, noise=n, controller=controller, feedforward=ff, seed=7))
    (d1, t1), (d2, t2) = out
    for name in ("q", "tau"):
        assert np.array_equal(getattr(d1, name), getattr(d2, name)), name
    for name in ("q", "qd", "qdd", "x", "xdd", "tau_applied", "noise", "loop_violation"):
        assert np.array_equal(getattr(t1, name), getattr(t2, name)), name


def test_cached_feedforward_is_the_computed_one_and_never_another_inputs(tmp_path, monkeypatch, geometry):
    """The feed-forward kept on disk is ``ident.inverse_dynamics`` of the same inputs bit for bit; another
    reference, other parameters or another cache entry's content are never taken for it."""
    from h4bench import ident
    from h4bench.scenarios import experiment

    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path))
    monkeypatch.setattr(experiment, "_FEEDFORWARD", {})
    ref = cartesian_reference(geometry, seconds=0.4, seed=1)
    oracle = ident.inverse_dynamics(geometry, NOMINAL, ref.q, ref.qd, ref.qdd)
    first = experiment.feedforward(geometry, NOMINAL, ref)
    np.testing.assert_array_equal(first, oracle)
    files = list((tmp_path / "feedforward").glob("*.npy"))
    assert len(files) == 1
    monkeypatch.setattr(experiment, "_FEEDFORWARD", {})  # a new process: from disk
    monkeypatch.setattr(ident, "inverse_dynamics", lambda *a, **k: pytest.fail("recomputed"))
    loaded = experiment.feedforward(geometry, NOMINAL, ref)
    np.testing.assert_array_equal(loaded, oracle)
    assert not loaded.flags.writeable
    monkeypatch.undo()
    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path))
    monkeypatch.setattr(experiment, "_FEEDFORWARD", {})
    other = cartesian_reference(geometry, seconds=0.4, seed=2)
    np.testing.assert_array_equal(experiment.feedforward(geometry, NOMINAL, other),
                                  ident.inverse_dynamics(geometry, NOMINAL, other.q, other.qd, other.qdd))
    theta = NOMINAL * 1.1
    np.testing.assert_array_equal(experiment.feedforward(geometry, theta, ref),
                                  ident.inverse_dynamics(geometry, theta, ref.q, ref.qd, ref.qdd))
    assert len(list((tmp_path / "feedforward").glob("*.npy"))) == 3
    np.save(files[0], np.zeros((3, 4)))  # a damaged entry (wrong shape) is recomputed, not used
    monkeypatch.setattr(experiment, "_FEEDFORWARD", {})
    np.testing.assert_array_equal(experiment.feedforward(geometry, NOMINAL, ref), oracle)
