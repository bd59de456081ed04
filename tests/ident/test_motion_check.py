"""The motion-bound check (:mod:`ident.processing.motion_check`) against analytic trajectories.

Oracle: sums of sines whose exact max |qd|, |qdd| are computed on a grid 200 times finer than the log's samples
(plus the analytic derivative's value at the grid's best point); the positions are quantised like an encoder, or
perturbed by the worst-case error pattern (+e, -e alternating: it maximises every odd-span second difference).
A proven lower bound must never exceed the truth (soundness) and must come close to it on a smooth motion
(strength); a stated bound at 0.7 x the truth must be flagged, one at the truth must not.
"""

from __future__ import annotations

import numpy as np
import pytest

from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.processing.motion_check import SpecCheck, check_motion_bounds, floor_digits

H = 1e-3


def _motion(seed: int, n_joints: int = 3, T: float = 2.0):
    rng = np.random.default_rng(seed)
    om = rng.uniform(2.0, 25.0, (n_joints, 3))
    a = rng.uniform(0.05, 0.5, (n_joints, 3))
    ph = rng.uniform(0, 2 * np.pi, (n_joints, 3))

    def q(t):
        arg = om[None] * np.asarray(t)[:, None, None] + ph[None]
        return (a * np.sin(arg)).sum(-1), (a * om * np.cos(arg)).sum(-1), -(a * om**2 * np.sin(arg)).sum(-1)

    fine = np.linspace(0, T, int(round(T / H)) * 200 + 1)
    _, qd, qdd = q(fine)
    return q, int(round(T / H)) + 1, np.abs(qd).max(0), np.abs(qdd).max(0)


def _spec(n, res, qd_max, qdd_max, **kw):
    return ErrorSpec(n_joints=n, sample_period=H, position_resolution=res, torque_error=1.0, qd_max=qd_max,
                     qdd_max=qdd_max, **kw)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("counts", [4096, 2**17])
def test_lower_bounds_are_below_the_truth_and_close_to_it(seed, counts):
    traj, N, qd_true, qdd_true = _motion(seed)
    res = 2 * np.pi / counts
    q = np.round(traj(np.arange(N) * H)[0] / res) * res
    check = check_motion_bounds(q, _spec(3, res, qd_true, qdd_true))
    assert np.all(check.qd_lower <= qd_true) and np.all(check.qdd_lower <= qdd_true)
    assert check.contradicted == []  # the truth itself is never contradicted
    # strength: a 2 s log of a smooth motion proves nearly all of it (spans of a few steps to a few tens)
    assert np.all(check.qd_lower >= 0.97 * qd_true), check.qd_lower / qd_true
    assert np.all(check.qdd_lower >= (0.95 if counts > 4096 else 0.85) * qdd_true), check.qdd_lower / qdd_true
    assert np.all((check.qdd_span >= 1) & (check.qdd_span <= 400))


@pytest.mark.parametrize("entry", ["qd_max", "qdd_max"])
def test_a_bound_at_seven_tenths_of_the_truth_is_flagged_on_every_joint(entry):
    traj, N, qd_true, qdd_true = _motion(5)
    res = 2 * np.pi / 2**17
    q = np.round(traj(np.arange(N) * H)[0] / res) * res
    stated = {"qd_max": qd_true, "qdd_max": qdd_true, entry: 0.7 * (qd_true if entry == "qd_max" else qdd_true)}
    check = check_motion_bounds(q, _spec(3, res, **stated))
    found = check.contradictions
    assert [(c["entry"], c["joint"]) for c in found] == [(entry, j) for j in (1, 2, 3)]
    for c, line in zip(found, check.contradicted):
        assert c["stated"] < c["proven_lower"] <= (qd_true if entry == "qd_max" else qdd_true)[c["joint"] - 1]
        assert line.startswith(f"{entry} of joint {c['joint']} = {c['stated']:.6g} ")
        assert "is contradicted by the data: the positions prove max |" in line
        printed = float(line.split(">= ")[1].split()[0])
        assert printed <= c["proven_lower"]  # rounded down: the message never overstates the proof


def test_worst_case_position_errors_never_make_the_bound_exceed_the_truth():
    """Every sample at +e or -e from the truth, alternating (the pattern that inflates every odd-span second
    difference by the full 4 e), and a second pattern with per-sample bounds: still below the truth."""
    traj, N, qd_true, qdd_true = _motion(7)
    q_true = traj(np.arange(N) * H)[0]
    e = 2 * np.pi / 4096 / 2
    sign = np.where(np.arange(N) % 2 == 0, 1.0, -1.0)[:, None]
    check = check_motion_bounds(q_true + e * sign, _spec(3, 2 * e, qd_true, qdd_true))
    assert np.all(check.qd_lower <= qd_true) and np.all(check.qdd_lower <= qdd_true)
    assert np.all(check.qdd_lower > 0.5 * qdd_true)
    # per-sample bounds: large on a few samples (a glitch the spec declares), tiny elsewhere
    rng = np.random.default_rng(0)
    pe = np.full(q_true.shape, 1e-7)
    glitch = rng.choice(N, 40, replace=False)
    pe[glitch] = 0.05
    q = q_true + pe * rng.choice([-1.0, 1.0], q_true.shape)
    check = check_motion_bounds(q, _spec(3, 1e-6, qd_true, qdd_true), position_error=pe)
    assert np.all(check.qd_lower <= qd_true) and np.all(check.qdd_lower <= qdd_true)


def test_a_ramp_at_constant_speed_proves_the_speed_and_no_acceleration():
    """q = v t exactly (no quantisation): max |qd| = v is proven to within rounding, max |qdd| >= 0 only."""
    v = np.array([0.5, -3.0])
    q = np.arange(2001)[:, None] * H * v[None]
    check = check_motion_bounds(q, _spec(2, 1e-12, np.abs(v), [1.0, 1.0]))
    assert np.all(check.qd_lower <= np.abs(v)) and np.allclose(check.qd_lower, np.abs(v), rtol=1e-6)
    assert np.all(check.qdd_lower < 1e-3)


def test_floor_digits_never_rounds_up():
    for x in [431.25, 1.0, 0.000123456, 9.99999, 12345678.9, 1e-300]:
        y = floor_digits(x)
        assert y <= x and y >= x * (1 - 1e-3)
    assert floor_digits(0.0) == 0.0


def test_bad_inputs_are_named_and_the_serial_module_reexports_the_check():
    from h4bench.ident.robots import serial_certified

    assert serial_certified.check_motion_bounds is check_motion_bounds and serial_certified.SpecCheck is SpecCheck
    spec = _spec(2, 1e-4, 1.0, 1.0)
    with pytest.raises(ValueError, match="q must have shape"):
        check_motion_bounds(np.zeros((10, 3)), spec)
    with pytest.raises(ValueError, match="position_error"):
        check_motion_bounds(np.zeros((10, 2)), spec, position_error=np.zeros((9, 2)))
    with pytest.raises(ValueError, match="max_span"):
        check_motion_bounds(np.zeros((10, 2)), spec, max_span=0)
    short = check_motion_bounds(np.zeros((2, 2)), spec)  # one step: a secant, no second difference
    assert np.all(short.qd_lower == 0) and np.all(short.qdd_lower == 0)
