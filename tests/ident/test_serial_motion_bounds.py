"""The within-step motion bounds of the serial certified equation against sampled motions that reach them.

Each bound (:meth:`StepGrid.mot_max_factor`, :meth:`StepGrid.mot_ms_factor`, :func:`step_displacements`,
:func:`quadratic_speed_weights`) is checked on speed profiles with ``|qdd| <= qdd_max`` built to be extreme
(bang-bang accelerations with random switch times, the V-shaped profile that attains the pointwise bound, the
linear one that attains the variance bound) on a fine time grid: the bound must hold on every profile, and the
profiles that attain it must come within a few per cent (the bound is not loose by construction).
"""

import numpy as np
import pytest

from h4bench.ident.processing.weakform import make_kernel
from h4bench.ident.robots.serial_steps import StepGrid, quadratic_speed_weights, step_displacements

DT = 1e-3
QDD = 2.0e3
SUB = 400  # fine samples per step
QUAD = 4.0 / SUB**2  # the trapezoid rule's relative error on the squared deviations (convex pieces)


def _profiles(rng, m: int, count: int = 300):
    """Speed profiles on the span of the 2 m - 1 steps centred on the middle step: (t, v) with t the fine grid
    relative to the middle step's start; ``count`` random bang-bang ones, the V at both step ends, the ramp."""
    S = (2 * m - 1) * DT
    t = np.linspace(-(m - 1) * DT, m * DT, (2 * m - 1) * SUB + 1)
    out = []
    for _ in range(count):
        sw = np.sort(rng.uniform(t[0], t[-1], rng.integers(1, 6)))
        sign = rng.choice([-1.0, 1.0]) * np.where(np.searchsorted(sw, t) % 2 == 0, 1.0, -1.0)
        a = QDD * sign * rng.uniform(0.5, 1.0)
        v = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * np.diff(t))]) + rng.normal() * 3
        out.append(v)
    for t_end in (0.0, DT):
        out.append(QDD * np.abs(t - t_end))
    out.append(QDD * t)
    assert S > 0
    return t, out


def _mean(t, v):
    return np.trapezoid(v, t) / (t[-1] - t[0])


@pytest.mark.parametrize("m", [1, 2, 3, 5])
def test_the_speed_deviation_bounds_hold_and_are_reached(m):
    rng = np.random.default_rng(m)
    t, vs = _profiles(rng, m)
    step = (t >= -1e-15) & (t <= DT + 1e-15)
    c, c2 = StepGrid.mot_max_factor(DT, m), StepGrid.mot_ms_factor(DT, m)
    worst_max = worst_ms = 0.0
    for v in vs:
        dev = v[step] - _mean(t, v)  # qd(t) - the span's secant, on the middle step
        worst_max = max(worst_max, np.max(np.abs(dev)) / (QDD * c))
        worst_ms = max(worst_ms, _mean(t[step], dev**2) / (QDD**2 * c2))
    assert worst_max <= 1.0 + 1e-6
    assert worst_max > 0.99  # the V-shaped profile attains it
    assert worst_ms <= 1.0 + QUAD  # the ramp's mean square sits on the bound; the trapezoid adds 2 / SUB^2
    if m == 1:
        assert worst_ms > 0.99  # the ramp attains the variance bound


def test_the_pointwise_bound_is_tighter_than_before():
    # the former bound, qdd_max (dt / 2 + S / 4): two thirds of it for m = 1, 0.74 of it for m = 3
    for m, ratio in ((1, 2 / 3), (3, 1.3 / 1.75)):
        S = (2 * m - 1) * DT
        assert StepGrid.mot_max_factor(DT, m) / (DT / 2 + S / 4) == pytest.approx(ratio, rel=1e-12)


@pytest.mark.parametrize("m", [1, 3])
def test_the_quadratic_weights_bound_the_kernel_weighted_products(m):
    rng = np.random.default_rng(10 + m)
    kern = make_kernel(40, DT, "triangle")
    cq = quadratic_speed_weights(kern, m)
    t, vs = _profiles(rng, m, 120)
    step = (t >= -1e-15) & (t <= DT + 1e-15)
    ts = t[step]
    worst = 0.0
    for w in (0, 1, 7, 19, 20, 39):  # steps at the kernel's ends, inside, at its apex
        k = kern.knots[w] + (kern.knots[w + 1] - kern.knots[w]) * ts / DT
        for i in range(0, len(vs) - 1, 3):
            xa = vs[i][step] - _mean(t, vs[i])
            xb = vs[i + 1][step] - _mean(t, vs[i + 1])
            worst = max(worst, np.trapezoid(k * np.abs(xa) * np.abs(xb), ts) / (cq[w] * QDD * QDD))
    assert worst <= 1.0 + 1e-6
    assert worst > 0.3
    c = StepGrid.mot_max_factor(DT, m)
    if m == 1:  # inside the kernel the mean-square bound takes over: about a third of the squared pointwise bound
        assert cq[10] < 0.36 * kern.integrals[10] * c * c
    else:  # the pointwise one, squared
        np.testing.assert_allclose(cq, kern.integrals * c * c, rtol=1e-14)


def test_step_displacements_bound_the_true_excursions():
    rng = np.random.default_rng(7)
    ts = np.linspace(0.0, DT, SUB + 1)
    worst_mean = worst_max = 0.0
    for _ in range(400):
        sw = np.sort(rng.uniform(0, DT, rng.integers(1, 4)))
        a = QDD * np.where(np.searchsorted(sw, ts) % 2 == 0, 1.0, -1.0) * rng.choice([-1.0, 1.0])
        v = rng.normal() * 2 + np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * np.diff(ts))])
        q = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(ts))]) + rng.normal()
        e0, e1 = rng.uniform(0, 1e-5, 2)
        m0, m1 = q[0] + rng.uniform(-e0, e0), q[-1] + rng.uniform(-e1, e1)  # the measured end positions
        ebar = 0.5 * (e0 + e1)
        dq_mean, dq_max = step_displacements(np.array([[m1 - m0]]), np.array([[e0]]), np.array([[e1]]),
                                             np.array([[ebar]]), np.array([QDD]), DT)
        qh = 0.5 * (m0 + m1)
        k = rng.uniform(0, 1) + rng.uniform(-1, 1) * (ts - DT / 2) / DT  # linear, >= 0 on the step
        k = k - min(0.0, k.min())
        dev = np.abs(q - qh)
        worst_mean = max(worst_mean, np.trapezoid(k * dev, ts) / np.trapezoid(k, ts) / (dq_mean[0, 0] + ebar))
        worst_max = max(worst_max, dev.max() / dq_max[0, 0])
    assert worst_mean <= 1.0 + 1e-9 and worst_max <= 1.0 + 1e-9
    assert worst_mean > 0.5 and worst_max > 0.5


def test_the_mass_matrix_derivatives_enclose_long_double_ones():
    """:func:`mass_derivatives` and :func:`mass_hessian_bound` on the TX40's chain at random steps, against central
    differences of the same regressor formulas in long double (errors ~1e-10 for dM, ~1e-6 for the Hessian, far
    inside the allowances): ``|dM - dM_true| <= eps`` at the mid position, and ``|d2 M / dq_a dq_k| <= HB`` at random
    points of the step's box; every derivative in the first joint's angle 0 (mass_pairs)."""
    from h4bench.ident.robots import chain, tx40
    from h4bench.ident.robots.serial_certified import geometry_bounds
    from h4bench.ident.robots.serial_steps import _regressor_calls, mass_derivatives, mass_hessian_bound, mass_pairs

    if np.finfo(np.longdouble).nmant < 63:
        pytest.skip("long double is not wider than double here")
    robot = tx40.robot()
    ch = chain.chain_of(robot.model)
    geo = geometry_bounds(robot)
    n = 6
    rng = np.random.default_rng(5)
    qh, vh = rng.uniform(-3, 3, (4, n)), rng.uniform(-2, 2, (4, n))
    p = _regressor_calls(robot, qh, vh)
    Mc = p["Mc"] - p["g0"][:, None]
    dM, eps, HB0 = mass_derivatives(Mc, p["Mk"], p["gk"], p["Mab"], p["gab"], qh, geo)
    dq_max = np.full((4, n), 2e-3)
    HB = mass_hessian_bound(HB0.copy(), dq_max, geo["M"])
    live = chain.live_entries(n)
    I = np.eye(n)

    def M_ld(q):  # (n columns b, F live entries) in long double
        ql = np.asarray(q, dtype=np.longdouble)[None].repeat(n + 1, axis=0)
        acc = np.zeros((n + 1, n), dtype=np.longdouble)
        acc[1:] = I
        Y = chain._regressor_numpy(ch, np.cos(ql), np.sin(ql), np.zeros((n + 1, n), dtype=np.longdouble), acc,
                                   dtype=np.longdouble).reshape(n + 1, -1)[:, live]
        return Y[1:] - Y[0]

    fa, fb = mass_pairs(n)
    pair = np.full((n, n), -1)  # -1: a pair with the first joint, where every derivative of M is 0
    pair[fa, fb] = pair[fb, fa] = np.arange(fa.size)
    worst_d = worst_h = 0.0
    for s in range(4):
        h = np.longdouble(1e-5)
        for k in range(n):
            d_true = (M_ld(qh[s] + h * I[k]) - M_ld(qh[s] - h * I[k])) / (2 * h)
            if k == 0:  # M does not depend on the first joint: dM is 0 there, exactly
                assert np.all(dM[s, 0] == 0) and float(np.max(np.abs(d_true))) < 1e-12
                continue
            worst_d = max(worst_d, float(np.max(np.abs(dM[s, k] - d_true) / np.broadcast_to(eps, dM.shape)[s, k])))
        for _ in range(2):
            z = qh[s] + rng.uniform(-1, 1, n) * dq_max[s]
            g = np.longdouble(1e-3)
            for a in range(n):
                for k in range(a, n):
                    h2 = (M_ld(z + g * (I[a] + I[k])) - M_ld(z + g * (I[a] - I[k])) - M_ld(z - g * (I[a] - I[k]))
                          + M_ld(z - g * (I[a] + I[k]))) / (4 * g * g)
                    if pair[a, k] < 0:
                        assert float(np.max(np.abs(h2))) < 1e-9
                        continue
                    worst_h = max(worst_h, float(np.max(np.abs(h2) / HB[s, pair[a, k]])))
    assert worst_d <= 1.0
    assert worst_h <= 1.0
    assert worst_d > 1e-4 and worst_h > 0.05  # the allowances are not vacuous
