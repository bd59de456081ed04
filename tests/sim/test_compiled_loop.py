"""The compiled sample loop (sim/_loop.cpp through sim.compiled) against its oracle, the Python loop of
sim.simulate: the same bits for every recorded array, the controller's final state and the progress calls, on
each kind of torque-error stream, with and without the encoder, with several MuJoCo steps per sample and with
another integrator; the same error where a stream refuses a sample; a MuJoCo error comes back as an exception."""

from __future__ import annotations

import ctypes
import shutil
import sys

import mujoco
import numpy as np
import pytest

from h4bench import ident
from h4bench import sim
from h4bench.sim import compiled
from h4bench.sim.noise import GainError, NoiseModelError, Ripple, TorqueError, Uniform
from tests.conftest import NOMINAL, cartesian_reference

needs_loop = pytest.mark.skipif(not compiled.available(), reason="the compiled loop is not built here")

_TRUTH = ("q", "qd", "qdd", "x", "xdd", "tau_applied", "noise", "loop_violation")


def _simulate(model, geometry, ref, noise, pure, monkeypatch, counts=20000, seed=4):
    if pure:
        monkeypatch.setenv("H4BENCH_PURE_PYTHON", "1")
    else:
        monkeypatch.delenv("H4BENCH_PURE_PYTHON", raising=False)
    _, controller = sim.default_controller(geometry, NOMINAL)
    ff = ident.inverse_dynamics(geometry, NOMINAL, ref.q, ref.qd, ref.qdd)
    calls = []
    data, truth = sim.simulate(model, ref, noise=noise, controller=controller, feedforward=ff, seed=seed,
                               settings=sim.SimulationSettings(encoder_counts=counts),
                               progress=lambda k, n: calls.append((k, n)))
    return data, truth, controller, calls


def _assert_same(a, b):
    (d1, t1, c1, p1), (d2, t2, c2, p2) = a, b
    np.testing.assert_array_equal(d1.q, d2.q)
    np.testing.assert_array_equal(d1.tau, d2.tau)
    for name in _TRUTH:
        np.testing.assert_array_equal(getattr(t1, name), getattr(t2, name), err_msg=name)
    for name in ("integrator", "_e_prev", "saturated"):
        np.testing.assert_array_equal(getattr(c1, name), getattr(c2, name), err_msg=name)
    assert p1 == p2


def _noises():
    return {
        "uniform": sim.TorqueNoise(1.0, "uniform"),
        "realistic (ripple, gain, log quantisation)": sim.realistic_drive(1.0),
        "ripple and gain": TorqueError([Uniform(0.2), Ripple([1, 11], [0.05, 0.02]), GainError(0.02)]),
        "none": None,
    }


@needs_loop
@pytest.mark.parametrize("name", list(_noises()))
def test_compiled_loop_gives_the_python_loops_bits(model, geometry, monkeypatch, name):
    ref = cartesian_reference(geometry, seconds=2.5, seed=2)
    noise = _noises()[name]
    a = _simulate(model, geometry, ref, noise, True, monkeypatch)
    b = _simulate(model, geometry, ref, noise, False, monkeypatch)
    assert np.abs(a[0].tau).max() > 1.0 and len(a[3]) == 3  # the law is exercised; progress at 0, 1000, 2000
    _assert_same(a, b)


@needs_loop
def test_compiled_loop_without_encoder_and_with_substeps_and_euler(geometry, monkeypatch):
    """Exact angles (no encoder), 2 MuJoCo steps per sample (timestep 0.5 ms), and the Euler integrator."""
    ref = cartesian_reference(geometry, seconds=1.2, seed=7)
    for timestep, integrator in ((5e-4, mujoco.mjtIntegrator.mjINT_RK4), (1e-3, mujoco.mjtIntegrator.mjINT_EULER)):
        m = sim.load_model()
        m.opt.timestep = timestep
        m.opt.integrator = integrator
        a = _simulate(m, geometry, ref, sim.realistic_drive(0.5), True, monkeypatch, counts=None)
        b = _simulate(m, geometry, ref, sim.realistic_drive(0.5), False, monkeypatch, counts=None)
        assert a[0].metadata["substeps"] == round(1e-3 / timestep)
        _assert_same(a, b)


@needs_loop
def test_a_refused_sample_raises_the_streams_own_error(model, geometry, monkeypatch):
    """A gain error that assumes |tau_cmd| <= 0.3 N m: the command goes beyond, and both loops stop with the
    stream's error at the same sample."""
    ref = cartesian_reference(geometry, seconds=1.0, seed=3)
    noise = TorqueError([GainError(0.01, torque_limit=0.3)])
    messages = []
    for pure in (True, False):
        with pytest.raises(NoiseModelError, match="within \\+-torque_limit = 0.3 N m") as err:
            _simulate(model, geometry, ref, noise, pure, monkeypatch)
        messages.append(str(err.value))
    assert messages[0] == messages[1]


def test_a_stream_with_its_own_at_list_is_not_compiled():
    class Shifted(sim.PrecomputedTorqueError):
        def at_list(self, k, q, tau_cmd):
            return [v + 0.1 for v in super().at_list(k, q, tau_cmd)]

    e = np.zeros((5, 4))
    assert sim.PrecomputedTorqueError(e).compiled_terms() is not None
    assert Shifted(e).compiled_terms() is None


@needs_loop
def test_a_mujoco_error_comes_back_instead_of_ending_the_process():
    """mju_error called through MuJoCo's library under the loop's handler returns its message to the caller;
    the process's own handler is restored afterwards."""
    from h4bench.sim import _loop

    _, fn = compiled._library()
    before = ctypes.c_void_p.from_address(fn["mju_user_error"]).value
    assert _loop.error_roundtrip(fn["mju_user_error"], fn["mju_error"], "arena full at %d") == "arena full at %d"
    assert ctypes.c_void_p.from_address(fn["mju_user_error"]).value == before


@pytest.mark.skipif(shutil.which("c++") is None or not sys.platform.startswith("linux"), reason="no C++ compiler")
def test_the_loop_is_built_where_a_compiler_is():
    """An install on a machine with a C++ compiler builds the extension (its build is optional: a failure would
    otherwise pass unseen, every run then taking the slower Python loop)."""
    assert compiled._extension() is not None, "h4bench.sim._loop was not built: see the install's build output"
    assert compiled._library() is not None, "MuJoCo's library was not found beside the mujoco package"
