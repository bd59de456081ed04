"""A shared oracle for the H4's interval-jet Hessian bounds: central differences of the enclosed point gradients."""

import numpy as np

from h4bench.ident.robots.h4_jets import point_jets
from h4bench.sim.kinematics import forward_kinematics

STEPS = np.array([1e-6] * 4 + [1e-4] * 4)  # central-difference steps in q [rad] and qd [rad/s]


def assert_hessians_within(geometry, zq, zv, HP, HF) -> np.ndarray:
    """Assert that the central differences of the point gradients of P and F at the states zq, zv (S, 4) lie within
    the bounds HP, HF (S, 4, 2, 8, 8) (with a margin for the differences' own error); returns |d^2 F| so found."""
    seen = np.zeros_like(HF)
    for a in range(8):
        dz = np.eye(8)[a] * STEPS[a]
        Pp, Fp = point_jets(geometry, zq + dz[:4], zv + dz[4:], forward_kinematics(geometry, zq + dz[:4]))
        Pm, Fm = point_jets(geometry, zq - dz[:4], zv - dz[4:], forward_kinematics(geometry, zq - dz[:4]))
        fd_f = np.abs((Fp.g.c - Fm.g.c) / (2 * STEPS[a]))
        assert np.all(np.abs((Pp.g.c - Pm.g.c) / (2 * STEPS[a])) <= HP[..., a, :] * (1 + 1e-6) + 1e-6)
        assert np.all(fd_f <= HF[..., a, :] * (1 + 1e-6) + 1e-4)
        seen[..., a, :] = fd_f
    return seen
