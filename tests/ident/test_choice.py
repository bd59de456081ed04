"""The certified equation's kernels from the specification (:mod:`ident.processing.choice`).

Oracles: the family's stated grid; the H4's certified equation of each kernel alone (the family's rows must be
exactly theirs, stacked); the Oettli-Prager hull of each kernel alone (the family's box lies inside each)."""

import numpy as np
import pytest

from h4bench import ident, sim
from h4bench.ident.processing.choice import MIN_KERNEL_STEPS, STRIDE_DIVISOR, check_kernel_steps, kernel_family
from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.robots import h4_certified as hc


def test_kernel_family_grid():
    f = kernel_family(12001, 1e-3, 2, even=True)
    assert f.steps[0] == 40 and f.steps[-1] <= 800 and all(b > a for a, b in zip(f.steps, f.steps[1:]))
    assert all(L % 2 == 0 for L in f.steps)
    assert all(1.4 < b / a < 1.8 for a, b in zip(f.steps, f.steps[1:]))  # geometric, factor ~1.6
    assert f.strides == tuple(max(2, L // STRIDE_DIVISOR) for L in f.steps)
    short = kernel_family(1001, 1e-3)  # at most a tenth of the log
    assert max(short.steps) <= 100 and min(short.steps) >= MIN_KERNEL_STEPS
    assert kernel_family(201, 1e-3).steps == (MIN_KERNEL_STEPS,)  # a short log keeps the shortest accepted kernel
    assert kernel_family(12001, 2e-4).steps[0] == 200  # the same durations at another sample rate
    with pytest.raises(ValueError, match="stride must be an integer >= 1, got 0"):
        kernel_family(1000, 1e-3, 0)


def test_check_kernel_steps_names_the_argument():
    assert check_kernel_steps(40) == 40
    for bad in (7, 20, 39):
        with pytest.raises(ValueError, match=rf"kernel_steps must be >= 40 sample steps, got {bad}: .* at its prior"):
            check_kernel_steps(bad)
    for bad in (2.5, True, "40"):
        with pytest.raises(ValueError, match="kernel_steps must be an integer number of sample steps"):
            check_kernel_steps(bad)


@pytest.fixture(scope="module")
def h4_log():
    """A short H4 motion about home (sines), quantised to 2^16 counts; torques of a uniform-noise-free toy
    (zeros: the rows' left side is not what is checked here)."""
    geometry = sim.H4Geometry.from_model(sim.load_model())
    h = 1e-3
    t = np.arange(701) * h
    q0 = sim.inverse_kinematics(geometry, np.array([0.0, 0.0, -0.55, 0.0]))  # home pose (trajectories.limits)
    q = q0 + 0.05 * np.sin(2 * np.pi * np.array([1.1, 1.7, 2.3, 1.3]) * t[:, None] + np.arange(4))
    res = 2 * np.pi / 2**16
    spec = ErrorSpec(n_joints=4, sample_period=h, position_resolution=res, torque_error=1.0, qd_max=3.0,
                     qdd_max=40.0)
    return geometry, np.round(q / res) * res, spec


def test_h4_family_stacks_each_kernels_rows(h4_log):
    geometry, q, spec = h4_log
    tau = np.cos(np.arange(q.size)).reshape(q.shape)
    eq = hc.certified_equation(geometry, q, tau, spec, hc.Processing(stride=3))
    fam = kernel_family(q.shape[0], spec.sample_period, 3)
    assert eq.info["kernels"]["steps"] == list(fam.steps) and len(fam.steps) >= 2
    rows = 0
    for L, st in zip(fam.steps, fam.strides):  # oracle: each kernel alone, as an explicit setting gives it
        one = hc.certified_equation(geometry, q, tau, spec, hc.Processing(kernel_steps=L, stride=st))
        assert one.info["kernel_steps"] == L and "kernels" not in one.info
        sl = slice(rows, rows + len(one))
        for name in ("Wc", "D", "y", "bound", "sample", "joint"):
            np.testing.assert_array_equal(getattr(eq, name)[sl], getattr(one, name))
        for k, v in one.terms.items():
            np.testing.assert_array_equal(eq.terms[k][sl], v)
        rows += len(one)
    assert rows == len(eq) == eq.info["rows"]
    with pytest.raises(ValueError, match=r"kernel_steps must be >= 40 sample steps, got 7"):
        hc.certified_equation(geometry, q, tau, spec, hc.Processing(kernel_steps=7))


def test_h4_family_box_lies_in_every_single_kernels_box(h4_log):
    """The family's set is the intersection of the single kernels' sets: its hull lies in each one's hull (to the
    hulls' outward rounding). Torques within 0.5 N m of 0 (theta = 0 lies in every set: none is empty)."""
    geometry, q, spec = h4_log
    tau = np.random.default_rng(0).uniform(-0.5, 0.5, q.shape)
    prior = ident.Box(np.zeros(14), np.full(14, 2.0))
    eq = hc.certified_equation(geometry, q, tau, spec, hc.Processing(stride=3))

    def box(e):
        return ident.estimate(e.Wc, e.y, e.bound, prior, method="certified", regressor_radius=e.D,
                              groups=e.joint.astype(np.int64), check_consistency=False)

    fam_box = box(eq)
    for L, st in zip(eq.info["kernels"]["steps"], eq.info["kernels"]["strides"]):
        one = box(hc.certified_equation(geometry, q, tau, spec, hc.Processing(kernel_steps=L, stride=st)))
        slack = 1e-7 * (prior.upper - prior.lower)
        assert np.all(fam_box.lower >= one.lower - slack) and np.all(fam_box.upper <= one.upper + slack)
