"""The weak form's identities against independent oracles (scipy quadrature, the H4 regressor)."""

import numpy as np
import pytest
from scipy.integrate import quad

from h4bench import ident, sim
from h4bench.ident.processing.weakform import (coulomb_columns, imot_columns, make_kernel, row_windows,
                                               torque_rows, viscous_columns)
from h4bench.ident.robots.h4_certified import nacelle_terms

H = 1e-3
A, W0 = np.array([0.3, -0.2, 0.25, 0.1]), np.array([2.0, 3.1, 4.3, 5.2])  # q(t) = A sin(W0 t) [rad]


def motion(t):
    t = np.asarray(t, dtype=float)[..., None]
    return A * np.sin(W0 * t), A * W0 * np.cos(W0 * t), -A * W0**2 * np.sin(W0 * t)


def k_of(kernel, t0):
    return lambda t: np.interp(t, t0 + H * np.arange(kernel.knots.size), kernel.knots)


def test_kernel_has_unit_integral_and_zero_ends():
    for shape in ("hann", "triangle"):
        k = make_kernel(50, H, shape)
        assert k.knots[0] == k.knots[-1] == 0.0
        assert np.sum(k.integrals) == pytest.approx(1.0, rel=1e-14)
        assert quad(k_of(k, 0.0), 0, 50 * H, limit=200, points=H * np.arange(51))[0] == pytest.approx(1.0, rel=1e-9)
    with pytest.raises(ValueError, match="steps must be an integer >= 2"):
        make_kernel(1, H)
    with pytest.raises(ValueError, match="shape must be one of"):
        make_kernel(10, H, "gauss")


def test_acceleration_and_speed_columns_match_quadrature():
    """integral k qdd (quadrature of the analytic motion) = the Imot column from the sampled positions (exact
    identity); integral k qd within the Fv column's truncation radius."""
    n, L = 400, 60
    t = H * np.arange(n)
    q = motion(t)[0]
    k = make_kernel(L, H)
    win = row_windows(n, L, 37)
    e = np.zeros_like(q)
    acc, meas, trunc = imot_columns(q, e, win, k)
    vel, _, vtrunc = viscous_columns(q, e, win, k, np.abs(A) * W0**2)
    for r, s0 in enumerate(win.start):
        t0 = t[s0]
        kf = k_of(k, t0)
        pts = t0 + H * np.arange(L + 1)
        for j in range(4):
            ref_a = quad(lambda s: kf(s) * motion(s)[2][j], t0, t0 + L * H, points=pts, limit=400)[0]
            ref_v = quad(lambda s: kf(s) * motion(s)[1][j], t0, t0 + L * H, points=pts, limit=400)[0]
            assert acc[r, j] == pytest.approx(ref_a, abs=1e-8 * np.abs(A[j]) * W0[j] ** 2)
            assert abs(vel[r, j] - ref_v) <= vtrunc[r, j] + 1e-12
    assert np.all(trunc == 0) and np.all(meas >= 0)


def test_encoder_radius_covers_quantisation():
    n, L = 600, 80
    q = motion(H * np.arange(n))[0]
    res = 2 * np.pi / 2000
    qm = np.round(q / res) * res
    k = make_kernel(L, H)
    win = row_windows(n, L, 5)
    e = np.full_like(q, res / 2)
    exact = imot_columns(q, 0 * e, win, k)[0]
    got, meas, _ = imot_columns(qm, e, win, k)
    assert np.all(np.abs(got - exact) <= meas)
    # the bound is attained by the worst-case error pattern e_u = sign(s_u - s_u-1) res / 2 (summation by parts)
    ds = np.diff(np.concatenate([[0.0], k.slopes, [0.0]]))
    worst = q.copy()
    worst[win.start[0]:win.start[0] + L + 1, 0] += np.sign(ds) * res / 2
    dev = imot_columns(worst, 0 * e, win, k)[0][0, 0] - exact[0, 0]
    assert abs(dev) == pytest.approx(meas[0, 0], rel=1e-9)


def test_torque_side_is_exact_for_held_torques():
    n, L = 300, 40
    tau = np.random.default_rng(0).uniform(-2, 2, (n, 4))
    k = make_kernel(L, H)
    win = row_windows(n, L, 11)
    y, fp, factor = torque_rows(tau, win, k)
    assert factor == k.l1
    s0 = win.start[3]
    ref = sum(quad(k_of(k, 0.0), w * H, (w + 1) * H)[0] * tau[s0 + w] for w in range(L))
    np.testing.assert_allclose(y[3], ref, rtol=1e-10)
    assert np.all(fp >= 0) and np.all(fp < 1e-12)


def test_nacelle_lagrangian_form_matches_the_regressor():
    """dP/dt + F (time derivative by central differences along a smooth motion) = the regressor's Mnac and Ibc
    columns (ident.regressor, eq. 19 form)."""
    geometry = sim.H4Geometry.from_model(sim.load_model(sim.DEFAULT_MODEL_PATH))
    from h4bench.sim.kinematics import inverse_kinematics

    q0 = inverse_kinematics(geometry, np.array([0.0, 0.0, -0.55, 0.0]))  # home pose (trajectories.limits)

    def path(t):  # a small motion about home
        q, qd, qdd = motion(t)
        return q / 3 + q0, qd / 3, qdd / 3

    t = np.linspace(0.1, 0.5, 5)
    dt = 1e-5
    q, qd, qdd = path(t)
    w = ident.regressor(geometry, q, qd, qdd).reshape(-1, 4, 14)[..., 4:6]
    Pp = nacelle_terms(geometry, *path(t + dt)[:2])[0]
    Pm = nacelle_terms(geometry, *path(t - dt)[:2])[0]
    F = nacelle_terms(geometry, q, qd)[1]
    strong = (Pp - Pm) / (2 * dt) + F
    np.testing.assert_allclose(strong, w, rtol=1e-6, atol=1e-7 * np.abs(w).max())


def test_torque_side_for_sample_instant_torques_is_within_the_rate_term():
    """A continuous applied torque logged at the sample instants: y of the linear interpolation is exact for a
    torque linear in time, and within rho h / 2 * factor of the quadrature of k tau for a smooth one (rho its
    largest |d tau / dt|), the bound nearly attained by a torque that zig-zags at rate rho between samples."""
    n, L = 300, 40
    k = make_kernel(L, H)
    win = row_windows(n, L, 7)
    t = H * np.arange(n)
    lin = np.stack([2.0 + 30.0 * t, -1.0 + 5.0 * t], axis=1)
    y, fp, factor = torque_rows(lin, win, k, "sample")
    y_hold = torque_rows(lin, win, k)[0]
    for r, t0 in enumerate(H * win.start[:5]):
        exact = [quad(lambda s: k_of(k, t0)(s) * (2.0 + 30.0 * s), t0, t0 + L * H, limit=200,
                      points=t0 + H * np.arange(L + 1))[0]]
        assert abs(y[r, 0] - exact[0]) <= fp[r, 0] + 1e-12
    assert not np.allclose(y, y_hold)  # the held torques' sum is a different quantity
    assert factor == pytest.approx(1.0, rel=1e-12)  # k >= 0 and unit integral: sum |c| = 1
    rho, w = 40.0, 2 * np.pi * 3.0
    amp = rho / w
    smooth = np.stack([amp * np.sin(w * t), amp * np.cos(w * t)], axis=1)
    y = torque_rows(smooth, win, k, "sample")[0]
    for r in range(0, win.start.size, 5):
        t0 = H * win.start[r]
        exact = quad(lambda s: k_of(k, t0)(s) * amp * np.sin(w * s), t0, t0 + L * H, limit=400,
                     points=t0 + H * np.arange(L + 1))[0]
        assert abs(y[r, 0] - exact) <= rho * H / 2 * factor
    # a torque that leaves the interpolation by rho h / 2 at every mid-step (a zig-zag at rate rho): the bound
    # is attained within the kernel's variation over a step
    tau_mid = lambda s: rho * np.minimum(s % H, H - s % H)  # noqa: E731  zero at the samples, peak rho h / 2
    t0 = H * win.start[3]
    exact = quad(lambda s: k_of(k, t0)(s) * tau_mid(s), t0, t0 + L * H, limit=2000,
                 points=t0 + H * np.arange(2 * L + 1) / 2)[0]
    assert exact == pytest.approx(rho * H / 4, rel=0.01)  # mean of the zig-zag rho h / 4; the bound is rho h / 2
    with pytest.raises(ValueError, match="timing must be 'hold' or 'sample'"):
        torque_rows(lin, win, k, "mid")



def test_coulomb_steps_of_sample_instant_torques_lie_in_the_coulomb_column():
    """Coulomb friction ``fs sign(qd)`` logged at the sample instants steps at each reversal, so no bound on
    ``|d tau / dt|`` covers the interpolation of the samples on the reversing step (the quadrature oracle below
    differs from ``y`` by more than a rate term of a torque constant between the steps allows). It
    needs no term of its own: on a step whose sign is certain the interpolation is exact, and on an uncertain step
    the interpolation of the samples is a k-weighted value in ``[-fs, fs]``, i.e. ``fs`` times a value that the
    Coulomb column's interval ``[-1, 1] K_w`` allows. Checked: ``y`` lies in ``fs [value - radius, value +
    radius]`` on every row, and so does the exact integral (oracle: scipy quadrature on the true motion)."""
    n, L, fs = 600, 40, 1.7
    k = make_kernel(L, H, "triangle")
    win = row_windows(n, L, 3)
    t = H * np.arange(n)
    w = 2 * np.pi * 2.3
    q_true = np.stack([0.2 * np.sin(w * t + 0.3), 0.1 * np.cos(w * t)], axis=1)  # reversals between the samples
    qd = lambda s: np.stack([0.2 * w * np.cos(w * s + 0.3), -0.1 * w * np.sin(w * s)], axis=-1)  # noqa: E731
    e = np.full_like(q_true, 1e-7)
    q = q_true + e * np.cos(t)[:, None]  # within the error bounds
    qdd_max = np.array([0.2 * w**2, 0.1 * w**2])
    y = torque_rows(fs * np.sign(qd(t)), win, k, "sample")[0]
    value, radius, uncertain = coulomb_columns(q, e, win, k, qdd_max)
    assert uncertain.any(axis=0).all()  # every joint reverses
    worst = 0.0
    for r in range(win.start.size):
        t0 = H * win.start[r]
        for j in range(2):
            exact = quad(lambda s: k_of(k, t0)(s) * fs * np.sign(qd(s)[j]), t0, t0 + L * H, limit=400,
                         points=t0 + H * np.arange(L + 1))[0]
            assert abs(exact - fs * value[r, j]) <= fs * radius[r, j] + 1e-9  # the sign interval holds the truth
            assert abs(y[r, j] - fs * value[r, j]) <= fs * radius[r, j] + 1e-12  # and the logged samples' row
            worst = max(worst, abs(y[r, j] - exact))
    # the interpolation misses the step: as a rate term it would need |d tau/dt| >= 2 worst / h (> 68 N m/s here,
    # for a torque that is constant apart from the steps)
    assert worst > 0.04 * fs


def test_friction_band_covers_a_friction_law_that_is_coulomb_only_above_it():
    """A friction law that is Coulomb's ``fs sign(qd)`` only at ``|qd| >= band`` (here ``fs clip(qd / band, -1,
    1)``, a linear pre-sliding zone): with ``band`` stated, every row's Coulomb column holds its exact integral
    (oracle: scipy quadrature on the true motion); with the band left at 0 some rows do not."""
    n, L, fs, band = 600, 40, 1.7, np.array([0.25, 0.15])
    k = make_kernel(L, H, "hann")
    win = row_windows(n, L, 7)
    t = H * np.arange(n)
    w = 2 * np.pi * 2.3
    q = np.stack([0.2 * np.sin(w * t + 0.3), 0.1 * np.cos(w * t)], axis=1)
    qd = lambda s: np.stack([0.2 * w * np.cos(w * s + 0.3), -0.1 * w * np.sin(w * s)], axis=-1)  # noqa: E731
    e = np.full_like(q, 1e-7)
    qdd_max = np.array([0.2 * w**2, 0.1 * w**2])
    missed = {}
    for stated in (band, np.zeros(2)):
        value, radius, uncertain = coulomb_columns(q, e, win, k, qdd_max, stated)
        worst = 0.0
        for r in range(win.start.size):
            t0 = H * win.start[r]
            for j in range(2):
                exact = quad(lambda s: k_of(k, t0)(s) * fs * np.clip(qd(s)[j] / band[j], -1, 1), t0, t0 + L * H,
                             limit=400, points=t0 + H * np.arange(L + 1))[0]
                worst = max(worst, abs(exact - fs * value[r, j]) - fs * radius[r, j])
        missed[bool(stated.any())] = worst
    assert missed[True] <= 1e-9 and missed[False] > 1e-3


@pytest.mark.parametrize("timing, latency, rate", [("hold", 0.0, None), ("sample", 0.0, [40.0, 3.0]),
                                                   ("sample", 2e-3, [40.0, 3.0]), ("hold", 1e-3, [0.1, 7.0]),
                                                   ("hold", 0.0, [5.0, 5.0])])
def test_torque_side_terms_bound_the_exact_products(timing, latency, rate):
    """Each term at or above its exact value (rational arithmetic on the floats given), within 4 ulp of it."""
    from fractions import Fraction

    from h4bench.ident.processing.errorspec import ErrorSpec
    from h4bench.ident.processing.weakform import torque_side_terms

    h, l1 = 1e-3, 1.0000000000000033
    spec = ErrorSpec(n_joints=2, sample_period=h, position_resolution=1e-4, torque_error=[0.3, 0.7],
                     model_error=[0.1, 0.0], qd_max=[1.0, 1.0], qdd_max=[10.0, 10.0], torque_timing=timing,
                     latency=latency, torque_rate=rate)
    got = torque_side_terms(spec, l1)
    span = Fraction(latency) + (Fraction(h) / 2 if timing == "sample" else 0)
    exact = {"torque": [Fraction(x) * Fraction(l1) for x in (0.3, 0.7)],
             "model": [Fraction(x) * Fraction(l1) for x in (0.1, 0.0)],
             "timing": [Fraction(r) * span * Fraction(l1) for r in (rate or [0.0, 0.0])]}
    for key, values in exact.items():
        for g, x in zip(got[key], values):
            assert Fraction(float(g)) >= x
            assert float(g) <= float(x) * (1 + 8 * 2.0**-53) + 1e-300, key
    assert (got["timing"] > 0).all() == (rate is not None and (timing == "sample" or latency > 0))
