"""Tests of ident.processing.filtering against independent oracles.

Oracles: analytic derivatives of sinusoids (Taylor remainders dt^2/6 and dt^2/12), the bilinear-transform
Butterworth magnitude |H|^2 = 1 / (1 + (tan(pi f dt) / tan(pi fc dt))^(2N)), numpy.convolve per column, and
exact rational arithmetic (fractions.Fraction) for the filtered residuals.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from h4bench.ident.processing.filtering import (
    DEFAULT_TORQUE_TIMING,
    Derivatives,
    FilteredEquation,
    ProcessingSettings,
    central_difference,
    decimation_fir,
    default_edge_samples,
    derivatives,
    exclude_low_speed,
    lowpass_position,
    parallel_filter,
    second_difference,
)

DT = 1e-3


def _sines(n, dt, freqs=(0.7, 1.3, 2.9, 4.1), amps=(0.5, 0.3, 0.2, 0.4)):
    """q[:, i] = a_i sin(w_i t + i) and its exact derivatives."""
    t = np.arange(n)[:, None] * dt
    w = 2 * np.pi * np.asarray(freqs)[None, :]
    a = np.asarray(amps)[None, :]
    ph = np.arange(4)[None, :]
    return (a * np.sin(w * t + ph), a * w * np.cos(w * t + ph), -a * w**2 * np.sin(w * t + ph), a, w)


def _exact_residual(y_f, W_f, theta):
    """max_r |y_f[r] - W_f[r] @ theta| - bound in exact rational arithmetic, as Fractions per row."""
    th = [Fraction(float(t)) for t in theta]
    out = []
    for r in range(y_f.size):
        s = Fraction(float(y_f[r])) - sum(Fraction(float(w)) * t for w, t in zip(W_f[r], th))
        out.append(abs(s))
    return out


# ----------------------------------------------------------------------------------------- differences


def test_central_difference_matches_analytic_derivative_with_dt2_error():
    errs = []
    for dt in (2e-3, 1e-3):
        q, qd, _, a, w = _sines(int(2.0 / dt), dt)
        d = central_difference(q, dt)
        err = np.abs(d - qd)
        # Taylor remainder of (x(t+h) - x(t-h)) / 2h: h^2/6 max|x'''| (interior)
        assert np.all(err[1:-1] <= dt**2 / 6 * a * w**3 * 1.001 + 1e-9)
        errs.append(err.max())  # includes the one-sided ends
    assert 3.5 < errs[0] / errs[1] < 4.5  # second order, ends included


def test_second_difference_matches_analytic_with_dt2_error():
    errs = []
    for dt in (2e-3, 1e-3):
        q, _, qdd, a, w = _sines(int(2.0 / dt), dt)
        d = second_difference(q, dt)
        err = np.abs(d - qdd)
        # Taylor remainder of the 3-point stencil: h^2/12 max|x''''|, plus rounding ~ 4 eps |x| / h^2
        assert np.all(err[1:-1] <= dt**2 / 12 * a * w**4 * 1.001 + 8 * 2.3e-16 * a / dt**2)
        errs.append(err.max())
    assert 3.5 < errs[0] / errs[1] < 4.5


def test_difference_inputs_are_validated():
    with pytest.raises(ValueError, match="at least 3 samples"):
        central_difference(np.zeros((2, 4)), DT)
    with pytest.raises(ValueError, match="at least 4 samples"):
        second_difference(np.zeros((3, 4)), DT)
    with pytest.raises(ValueError, match="dt must be"):
        central_difference(np.zeros((5, 4)), -1.0)
    with pytest.raises(TypeError, match="x must be"):
        central_difference("abc", DT)


# ------------------------------------------------------------------------------------------- low-pass


@pytest.mark.parametrize("order", [2, 4])
def test_filtfilt_is_zero_phase_with_butterworth_gain(order):
    fc, f = 50.0, 30.0
    n = 3000
    t = np.arange(n) * DT
    q = np.stack([np.sin(2 * np.pi * f * t + k) for k in range(4)], axis=1)
    qf = lowpass_position(q, DT, fc, order)
    # digital Butterworth by the bilinear transform; forward-backward squares the magnitude, phase 0
    ratio = np.tan(np.pi * f * DT) / np.tan(np.pi * fc * DT)
    gain = 1.0 / (1.0 + ratio ** (2 * order))
    edge = default_edge_samples(DT, fc)
    mid = slice(2 * edge, n - 2 * edge)
    assert gain < 0.99  # the test would not see a phase error if the gain were ~1
    np.testing.assert_allclose(qf[mid], gain * q[mid], atol=1e-6)


def test_lowpass_leaves_slow_motion_and_removes_fast_noise():
    q, *_ = _sines(4000, DT)
    noise = 1e-3 * np.sin(2 * np.pi * 240 * np.arange(4000) * DT + 0.3)[:, None]
    qf = lowpass_position(q + noise, DT, 50.0)
    mid = slice(200, -200)
    assert np.abs(qf[mid] - q[mid]).max() < 1e-8  # 240 Hz: gain 1e-11 after both passes


def test_lowpass_bad_inputs():
    q = np.zeros((100, 4))
    with pytest.raises(ValueError, match=r"q must have shape \(n, n_joints\), one column per joint, got \(3,\)"):
        lowpass_position(np.zeros(3), DT, 20.0)
    with pytest.raises(ValueError, match="Nyquist"):
        lowpass_position(q, DT, 600.0)
    with pytest.raises(ValueError, match="cutoff_hz must be"):
        lowpass_position(q, DT, 0.0)
    with pytest.raises(TypeError, match="order must be an integer"):
        lowpass_position(q, DT, 20.0, order=2.5)
    with pytest.raises(ValueError, match="finite"):
        lowpass_position(np.full((100, 4), np.nan), DT, 20.0)
    with pytest.raises(ValueError, match="padlen must be"):
        lowpass_position(q, DT, 20.0, padlen=100)


def test_derivatives_valid_region_matches_analytic():
    q, qd, qdd, a, w = _sines(5000, DT)
    res = derivatives(q, DT, 50.0, timing="sample")  # the states at the sample instants
    assert isinstance(res, Derivatives)
    qf, qdf, qddf, valid = res
    assert valid == slice(default_edge_samples(DT, 50.0) + 2, 5000 - default_edge_samples(DT, 50.0) - 2)
    # stencil truncation (dt^2/6 a w^3, dt^2/12 a w^4) plus what is left of the edge transient after `trim`
    # (measured: ~1e-7 rad, 4e-4 rad/s, 0.02 rad/s^2 at the first valid samples, against 0.5 rad, 10 rad/s)
    np.testing.assert_allclose(qf[valid], q[valid], rtol=0, atol=2e-7)
    np.testing.assert_allclose(qdf[valid], qd[valid], rtol=0, atol=(DT**2 / 6 * a * w**3).max() + 5e-4)
    np.testing.assert_allclose(qddf[valid], qdd[valid], rtol=0, atol=(DT**2 / 12 * a * w**4).max() + 2e-2)
    with pytest.raises(ValueError, match="more than 2\\*trim"):
        derivatives(q[:50], DT, 50.0)


def test_hold_timing_gives_the_mid_step_states():
    """timing="hold": the regressor's states at t_k + dt/2 (a torque held over [t_k, t_k + dt)), to the stencils'
    Taylor remainders: q by the mean (dt^2/8 |qdd|), qd by the forward difference (dt^2/24 |d3q|), qdd by the
    mean of two second differences (dt^2/12 |d4q| + dt^2/8 |d4q| from the averaging)."""
    n = 5000
    q, _, _, a, w = _sines(n, DT)
    t_mid = (np.arange(n)[:, None] + 0.5) * DT
    ph = np.arange(4)[None, :]
    q_mid, qd_mid, qdd_mid = (a * np.sin(w * t_mid + ph), a * w * np.cos(w * t_mid + ph),
                              -a * w**2 * np.sin(w * t_mid + ph))
    held = derivatives(q, DT, 50.0)  # "hold" is the default
    at = derivatives(q, DT, 50.0, timing="sample")
    assert DEFAULT_TORQUE_TIMING == "hold" and ProcessingSettings().torque_timing == DEFAULT_TORQUE_TIMING
    np.testing.assert_array_equal(held.qd, derivatives(q, DT, 50.0, timing="hold").qd)
    v = held.valid
    assert v == at.valid
    edge = (2e-7, 5e-4, 2e-2)  # what is left of the Butterworth edge transient (as in the test above)
    np.testing.assert_allclose(held.q[v], q_mid[v], rtol=0, atol=(DT**2 / 8 * a * w**2).max() + edge[0])
    np.testing.assert_allclose(held.qd[v], qd_mid[v], rtol=0, atol=(DT**2 / 24 * a * w**3).max() + edge[1])
    np.testing.assert_allclose(held.qdd[v], qdd_mid[v], rtol=0, atol=(5 * DT**2 / 24 * a * w**4).max() + edge[2])
    # half a step from the sample instants: qd moves by about dt/2 |qdd| (here up to 0.13 rad/s)
    assert np.abs(held.qd[v] - at.qd[v]).max() > 0.1
    with pytest.raises(ValueError, match="torque_timing must be one of 'sample', 'hold'.*got 'zoh'"):
        derivatives(q, DT, 50.0, timing="zoh")
    with pytest.raises(ValueError, match="torque_timing"):
        ProcessingSettings(torque_timing="middle")


# ------------------------------------------------------------------------------------------ parallel filter


def _dyadic_problem(rng, n, p, b):
    """W integer, theta multiples of 1/16, e multiples of b/2^20: y = W theta + e is exact in floating point."""
    W = rng.integers(-100, 101, size=(4 * n, p)).astype(float)
    theta = rng.integers(-32, 33, size=p) / 16.0
    e = b * rng.integers(-(2**20), 2**20 + 1, size=4 * n) / 2.0**20
    y = W @ theta + e
    return W, theta, e, y


def test_parallel_filter_matches_numpy_convolve_per_joint_and_column():
    rng = np.random.default_rng(1)
    n, p, factor = 500, 5, 4
    W = rng.normal(size=(4 * n, p))
    y = rng.normal(size=4 * n)
    fe = parallel_filter(W, y, 0.1, factor, numtaps=21)
    h = decimation_fir(factor, 21)
    for i in range(4):
        ref_y = np.convolve(y[i::4], h, mode="valid")[::factor]
        np.testing.assert_allclose(fe.y[i::4], ref_y, rtol=0, atol=1e-13)
        for c in range(p):
            ref = np.convolve(W[i::4, c], h, mode="valid")[::factor]
            np.testing.assert_allclose(fe.W[i::4, c], ref, rtol=0, atol=1e-13)
    m = (n - 21) // factor + 1
    assert fe.W.shape == (4 * m, p) and fe.y.shape == (4 * m,) and fe.bound.shape == (4 * m,)
    np.testing.assert_array_equal(fe.window_start, np.arange(m) * factor)
    np.testing.assert_array_equal(fe.sample_index, np.arange(m) * factor + 10)
    np.testing.assert_array_equal(fe.rows[:, 2], 4 * fe.sample_index + 2)


def test_parallel_filter_sample_index_is_the_time_the_output_represents():
    # a linear ramp is reproduced exactly by a symmetric unit-DC filter at the window centre
    n = 400
    t = np.arange(n, dtype=float)
    y = np.repeat(t, 4) + np.tile(np.arange(4) * 1000.0, n)
    fe = parallel_filter(np.zeros((4 * n, 1)), y, 0.0, 5)
    np.testing.assert_allclose(fe.y[0::4], fe.sample_index, rtol=1e-12)
    np.testing.assert_allclose(fe.y[3::4], fe.sample_index + 3000.0, rtol=1e-12)


def test_parallel_filter_keeps_joints_apart():
    rng = np.random.default_rng(2)
    n = 300
    W = np.zeros((4 * n, 2))
    W[2::4, 0] = rng.normal(size=n)  # column 0 lives on joint 2 only
    W[:, 1] = rng.normal(size=4 * n)
    fe = parallel_filter(W, np.zeros(4 * n), 1.0, 3, numtaps=31)
    for i in (0, 1, 3):
        assert np.all(fe.W[i::4, 0] == 0.0)
        assert np.all(fe.w_rounding[i::4, 0] <= 1e-299)
    assert np.abs(fe.W[2::4, 0]).max() > 0.05


def test_propagated_bound_holds_and_is_attained_by_worst_case_noise():
    rng = np.random.default_rng(3)
    n, p, factor, L = 240, 3, 8, 41
    b = 0.5 + rng.integers(0, 8, size=4 * n) / 8.0  # per-row bound
    W, theta, e, y = _dyadic_problem(rng, n, p, 1.0)
    e = e * b
    h = decimation_fir(factor, L)
    # worst case for output k0 of joint 1: e = b sign(h) reversed in time over its window
    k0, joint = 7, 1
    start = k0 * factor
    for j in range(L):
        r = 4 * (start + L - 1 - j) + joint
        e[r] = b[r] * np.sign(h[j])
    y = W @ theta + e  # exact: W integer, theta and e dyadic with few bits
    fe = parallel_filter(W, y, b, factor, taps=h, theta_abs_max=np.abs(theta))
    res = _exact_residual(fe.y, fe.W, theta)
    assert all(r <= Fraction(float(bd)) for r, bd in zip(res, fe.bound))
    target = 4 * k0 + joint
    exact_hb = sum(abs(Fraction(float(h[j]))) * Fraction(float(b[4 * (start + L - 1 - j) + joint]))
                   for j in range(L))
    assert float(res[target]) >= float(fe.bound[target]) * (1 - 1e-9)  # tight: attained up to rounding
    assert float(exact_hb) == pytest.approx(float(fe.bound[target]), rel=1e-9)


def test_scalar_bound_becomes_l1_norm_times_bound():
    rng = np.random.default_rng(4)
    W, theta, e, y = _dyadic_problem(rng, 300, 2, 0.25)
    fe = parallel_filter(W, y, 0.25, 5)
    l1 = np.abs(decimation_fir(5)).sum()
    assert fe.l1_norm >= l1 and fe.l1_norm == pytest.approx(l1, rel=1e-14)
    # W-side rounding not included yet: the bound is ||h||_1 b plus the y rounding term only
    assert not fe.w_rounding_included
    np.testing.assert_allclose(fe.bound, 0.25 * l1, rtol=1e-10)
    tb = fe.total_bound(np.abs(theta))
    assert np.all(tb >= fe.bound)
    np.testing.assert_allclose(tb, 0.25 * l1, rtol=1e-10)
    res = np.abs(fe.y.astype(np.longdouble) - fe.W.astype(np.longdouble) @ theta.astype(np.longdouble))
    assert np.all(res <= tb)


def test_propagate_mask_matches_a_window_loop():
    rng = np.random.default_rng(5)
    n = 200
    fe = parallel_filter(np.zeros((4 * n, 1)), np.zeros(4 * n), 1.0, 3, numtaps=11)
    mask = rng.random(4 * n) > 0.02
    out = fe.propagate_mask(mask)
    for k, s in enumerate(fe.window_start):
        for i in range(4):
            assert out[4 * k + i] == all(mask[4 * (s + j) + i] for j in range(11))
    assert out.shape == fe.y.shape and not out.all() and out.any()
    with pytest.raises(ValueError, match="row_mask must be"):
        fe.propagate_mask(np.ones(4 * n))


@settings(max_examples=60, deadline=None)
@given(
    L=st.integers(1, 25),
    factor=st.integers(1, 6),
    extra=st.integers(0, 40),
    p=st.integers(1, 4),
    seed=st.integers(0, 2**32 - 1),
    tap_scale=st.sampled_from([1e-3, 1.0, 1e3]),
)
def test_hypothesis_filtered_error_within_propagated_bound(L, factor, extra, p, seed, tap_scale):
    rng = np.random.default_rng(seed)
    n = L + extra
    taps = tap_scale * rng.normal(size=L)
    b = rng.integers(0, 2**10, size=4 * n) / 2.0**6  # per-row bounds, some zero
    W, theta, e, _ = _dyadic_problem(rng, n, p, 1.0)
    e = e * b
    y = W @ theta + e  # exact
    fe = parallel_filter(W, y, b, factor, taps=taps, theta_abs_max=np.abs(theta))
    res = _exact_residual(fe.y, fe.W, theta)
    assert all(r <= Fraction(float(bd)) for r, bd in zip(res, fe.bound))
    # and the exact |h * e| is below the exact |h| * b
    assert np.all(fe.bound >= 0)


def test_parallel_filter_bad_inputs():
    W = np.zeros((400, 3))
    y = np.zeros(400)
    with pytest.raises(ValueError, match=r"W must have shape \(4n, p\), got \(400,\)"):
        parallel_filter(y, y, 1.0, 2)
    with pytest.raises(ValueError, match="W must have 4n rows"):
        parallel_filter(np.zeros((401, 3)), np.zeros(401), 1.0, 2)
    with pytest.raises(ValueError, match=r"y must have shape \(400,\)"):
        parallel_filter(W, np.zeros(399), 1.0, 2)
    with pytest.raises(ValueError, match="bound must be >= 0"):
        parallel_filter(W, y, -1.0, 2)
    with pytest.raises(ValueError, match=r"bound must be a scalar or have shape \(400,\)"):
        parallel_filter(W, y, np.ones(3), 2)
    with pytest.raises(ValueError, match="factor must be an integer >= 1"):
        parallel_filter(W, y, 1.0, 0)
    with pytest.raises(TypeError, match="factor must be an integer"):
        parallel_filter(W, y, 1.0, 2.0)
    with pytest.raises(ValueError, match="numtaps must be odd"):
        parallel_filter(W, y, 1.0, 2, numtaps=10)
    with pytest.raises(ValueError, match="at least as many samples as taps"):
        parallel_filter(W, y, 1.0, 10)  # 201 taps > 100 samples
    with pytest.raises(ValueError, match="y must be finite"):
        parallel_filter(W, np.full(400, np.inf), 1.0, 2, numtaps=5)
    with pytest.raises(ValueError, match=r"theta_abs_max must have shape \(3,\)"):
        parallel_filter(W, y, 1.0, 2, numtaps=5, theta_abs_max=np.ones(2))
    with pytest.raises(ValueError, match="cutoff must be in"):
        parallel_filter(W, y, 1.0, 2, numtaps=5, cutoff=1.5)
    with pytest.raises(ValueError, match=r"W must have 3n rows \(3 joints per sample\), got 400"):
        parallel_filter(W, y, 1.0, 2, numtaps=5, joints=3)
    with pytest.raises(ValueError, match="joints must be an integer >= 1"):
        parallel_filter(W, y, 1.0, 2, numtaps=5, joints=0)
    with pytest.raises(ValueError, match="taps must be a non-empty 1-D array"):
        parallel_filter(W, y, 1.0, 2, taps=np.ones((2, 2)))


# ------------------------------------------------------------------------------------ low speed, settings


def test_exclude_low_speed_rows_and_samples():
    qd = np.array([[0.1, -0.01, 0.0, -0.5], [0.2, 0.3, -0.06, 0.04]])
    keep = exclude_low_speed(qd, 0.05)
    np.testing.assert_array_equal(keep, [True, False, False, True, True, True, True, False])
    keep = exclude_low_speed(qd, [0.0, 0.0, 0.0, 0.6])
    np.testing.assert_array_equal(keep, [True, True, True, False, True, True, True, False])
    keep = exclude_low_speed(np.abs(qd) + [[0, 0.1, 0.1, 0], [0, 0, 0, 0.1]], 0.05, whole_samples=True)
    np.testing.assert_array_equal(keep, [True] * 4 + [True] * 4)
    keep = exclude_low_speed(qd, 0.05, whole_samples=True)
    np.testing.assert_array_equal(keep, [False] * 8)
    with pytest.raises(ValueError, match=r"qd must have shape \(n, n_joints\), one column per joint, got \(4,\)"):
        exclude_low_speed(np.zeros(4), 0.1)
    with pytest.raises(ValueError, match="threshold must be finite and >= 0"):
        exclude_low_speed(qd, -0.1)
    with pytest.raises(ValueError, match=r"threshold must be a scalar or have shape \(4,\)"):
        exclude_low_speed(qd, [0.1, 0.2])


def test_processing_settings_defaults_and_validation():
    s = ProcessingSettings()
    h = s.taps()
    assert h.size == 20 * s.decimation + 1
    assert h.sum() == pytest.approx(1.0, abs=1e-12)
    # default FIR: pass-band flat at 10 Hz, cutoff (-6 dB) at 0.8 of the decimated Nyquist = 40 Hz
    H = lambda f: abs(np.sum(h * np.exp(-2j * np.pi * f * s.dt * np.arange(h.size))))  # noqa: E731
    assert H(10.0) == pytest.approx(1.0, abs=1e-3)
    assert H(40.0) == pytest.approx(0.5, abs=0.02)
    assert H(60.0) < 3e-3
    with pytest.raises(ValueError, match="position_cutoff_hz must be below the Nyquist"):
        ProcessingSettings(position_cutoff_hz=600.0)
    with pytest.raises(ValueError, match="decimation must be an integer >= 1"):
        ProcessingSettings(decimation=0)
    with pytest.raises(ValueError, match="speed_threshold must be finite"):
        ProcessingSettings(speed_threshold=-1.0)
    with pytest.raises(ValueError, match="numtaps must be odd"):
        ProcessingSettings(numtaps=20)


def test_filtered_equation_is_a_frozen_dataclass():
    fe = parallel_filter(np.zeros((40, 1)), np.zeros(40), 1.0, 1, numtaps=3)
    assert isinstance(fe, FilteredEquation)
    with pytest.raises(AttributeError):
        fe.factor = 2


# ------------------------------------------------------------------------------------------------ n joints


def test_chain_for_n_joints_is_joint_by_joint():
    """Any number of joints: each joint's derivatives, filtered rows and bounds are those of that joint alone
    (bit for bit), and the filtered rows equal numpy.convolve of the joint's column (an independent oracle)."""
    rng = np.random.default_rng(3)
    n, nj, p = 600, 6, 3
    t = np.arange(n)[:, None] * DT
    q = np.sin(2 * np.pi * (1.0 + np.arange(nj)) * t) + 0.01 * rng.standard_normal((n, nj))
    for timing in ("sample", "hold"):
        all_j = derivatives(q, DT, 50.0, timing=timing)
        for j in range(nj):
            one = derivatives(q[:, [j]], DT, 50.0, timing=timing)
            assert one.valid == all_j.valid
            for a, b in ((all_j.q, one.q), (all_j.qd, one.qd), (all_j.qdd, one.qdd)):
                np.testing.assert_array_equal(a[:, j], b[:, 0])
    W3 = rng.standard_normal((n, nj, p))
    Y = rng.standard_normal((n, nj))
    B = rng.uniform(0.5, 1.5, (n, nj))
    taps = decimation_fir(5, 21)
    fe = parallel_filter(W3.reshape(-1, p), Y.reshape(-1), B.reshape(-1), 5, taps=taps, theta_abs_max=np.ones(p),
                         joints=nj)
    assert fe.joints == nj and fe.rows.shape == (fe.sample_index.size, nj)
    m = fe.sample_index.size
    for j in range(nj):
        one = parallel_filter(W3[:, j], Y[:, j], B[:, j], 5, taps=taps, theta_abs_max=np.ones(p), joints=1)
        np.testing.assert_array_equal(fe.W.reshape(m, nj, p)[:, j], one.W)
        np.testing.assert_array_equal(fe.y.reshape(m, nj)[:, j], one.y)
        np.testing.assert_array_equal(fe.bound.reshape(m, nj)[:, j], one.bound)
        oracle = np.convolve(Y[:, j], taps, mode="valid")[::5]
        np.testing.assert_allclose(fe.y.reshape(m, nj)[:, j], oracle, rtol=0, atol=1e-12)
        # the bound covers the propagated raw bound |h| * b
        assert np.all(fe.bound.reshape(m, nj)[:, j] >= np.convolve(B[:, j], np.abs(taps), mode="valid")[::5])
    # a slow row masks exactly the outputs of its joint whose window holds it
    keep = np.ones((n, nj), dtype=bool)
    keep[100, 4] = False
    mask = fe.propagate_mask(keep.reshape(-1)).reshape(m, nj)
    inside = (fe.window_start <= 100) & (100 < fe.window_start + taps.size)
    np.testing.assert_array_equal(mask[:, 4], ~inside)
    assert mask[:, [0, 1, 2, 3, 5]].all()
    rows = exclude_low_speed(np.array([[0.1, 0.0, 0.2, 0.3, 0.0, 0.5]]), np.full(6, 0.05))
    np.testing.assert_array_equal(rows, [True, False, True, True, False, True])
    with pytest.raises(ValueError, match=r"threshold must be a scalar or have shape \(6,\)"):
        exclude_low_speed(np.ones((2, 6)), np.ones(4))
