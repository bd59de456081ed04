"""The local q-q remainder bound of a serial arm's certified rows (:func:`ident.robots.serial_steps.q_remainder`)
against the remainder itself, sampled.

Oracle: pinocchio's regressor ``f(q, v) = Y(q, v, 0)`` at points of the step's box, and its q-gradient at the box
centre by central differences (step 1e-6: its error, about 1e-8 of an entry, is far below the remainders checked,
which are made large by boxes 10-50x a 1 kHz step). The bound must hold at every sampled (q, v) and for every
entry; it must also be tighter than the global bound it replaced, ``4 (gamma (sum|v|)^2 + g) (sum dq)^2``, and
in a box of a step's size within 1e3 of the sampled maximum (median over the entries).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from h4bench.ident.robots.serial import SerialRobot
from h4bench.ident.robots.serial_certified import geometry_bounds
from h4bench.ident.robots.serial_steps import _pinocchio_calls, q_remainder

UR5 = Path(__file__).parents[2] / "examples" / "own_arm" / "ur5.urdf"


@pytest.fixture(scope="module")
def ur5():
    robot = SerialRobot(UR5)
    return robot, geometry_bounds(robot)


def _f(robot, q, v):
    import pinocchio as pin

    n = robot.n_joints
    return pin.computeJointTorqueRegressor(robot.model, robot.data, q, v, np.zeros(n)).copy()


def _grad(robot, q, v, h=1e-6):
    n = robot.n_joints
    return np.stack([(_f(robot, q + h * np.eye(n)[k], v) - _f(robot, q - h * np.eye(n)[k], v)) / (2 * h)
                     for k in range(n)])


# (seed, box half-widths in q [rad] and v [rad/s], whether the box is small enough for the bound to be local): a
# 1 kHz step of these logs moves about 1e-3 rad, and its speed estimate is within about 0.02 rad/s
@pytest.mark.parametrize("seed, dq, dv, small", [(0, 0.01, 0.05, True), (1, 0.03, 0.2, False), (2, 0.05, 0.5, False),
                                                 (3, 0.002, 0.01, True)])
def test_the_local_remainder_bounds_the_sampled_remainder(ur5, seed, dq, dv, small):
    robot, geo = ur5
    n = robot.n_joints
    rng = np.random.default_rng(seed)
    qh = rng.uniform(-np.pi, np.pi, n)
    vh = rng.uniform(-2.0, 2.0, n)
    dq_max = np.full(n, dq) * rng.uniform(0.5, 1.0, n)
    ev_max = np.full(n, dv) * rng.uniform(0.5, 1.0, n)
    p = _pinocchio_calls(robot, qh[None], vh[None])
    bound = q_remainder(p["fab"], p["fk"], p["f0"], qh[None], vh[None], ev_max[None], dq_max[None], geo)[0]
    worst = np.zeros_like(bound)
    corners = [np.where(rng.random(n) < 0.5, -1.0, 1.0) for _ in range(8)]
    for k in range(24):
        sq = corners[k] if k < 8 else rng.uniform(-1, 1, n)
        v = vh + rng.uniform(-1, 1, n) * ev_max
        d = sq * dq_max
        g = _grad(robot, qh, v)
        actual = np.abs(_f(robot, qh + d, v) - _f(robot, qh, v) - np.einsum("kic,k->ic", g, d))
        worst = np.maximum(worst, actual)
    noise = 1e-7 * (np.abs(_f(robot, qh, vh)) + 1.0) * dq_max.sum()  # the oracle's own gradient error
    assert np.all(worst <= bound + noise), np.max(worst - bound)
    # always below the global bound the remainder had before; in a small box, within 1e3 of the sampled maximum
    sp = np.sum(np.abs(vh) + ev_max)
    former = 4 * (geo["gamma"] * sp**2 + geo["g"]) * dq_max.sum() ** 2
    assert np.max(bound) < 0.5 * former
    if small:
        live = worst > 1e-6 * np.max(worst)
        assert np.median(bound[live] / worst[live]) < 1e3
