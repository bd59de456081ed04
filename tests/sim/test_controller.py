"""Tests of sim.control_design and sim.controller: the design against independent computations, the discrete
law in closed loop.

Oracles: closed-loop poles from numpy.roots of the characteristic polynomial written out by hand; the -3 dB
bandwidth and phase margin from |T(jw)|, L(jw) evaluated with numpy on a dense grid; the plant discretised
exactly with scipy.linalg.expm (zero-order hold) and simulated in a plain loop; scipy.signal.lfilter for the
difference equations; the linear tracking-error formula of the cascade evaluated at s = j w.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from h4bench.sim.control_design import ControllerDesign, LoopReport, design_joint_controller
from h4bench.sim.controller import JointController, VelocityFilter

DT = 1e-3
J = np.array([0.02, 0.03, 0.04, 0.05])
FV = np.array([0.05, 0.1, 0.15, 0.2])


@pytest.fixture(scope="module")
def design():
    return design_joint_controller(J, FV, bandwidth_hz=20.0, dt=DT, phase_margin_deg=60.0)


def _loop_polys(d: ControllerDesign, i: int):
    """Numerator and characteristic polynomial of L = (Kv + Ki/s)(Kp + s/(tau s + 1)) / (s (J s + Fv))."""
    tau = d.tau_v
    pi_num = np.array([d.kv[i], d.ki[i]])
    outer = np.polyadd(d.kp[i] * np.array([tau, 1.0]), np.array([1.0, 0.0]))  # Kp (tau s + 1) + s
    num = np.polymul(pi_num, outer)
    den = np.polymul(np.polymul([1.0, 0.0], [tau, 1.0]), [d.J[i], d.Fv[i], 0.0])  # s (tau s+1) s (J s+Fv)
    return num, np.polyadd(den, num), den


def _zoh_plant(j: int, dt: float = DT):
    """Exact zero-order-hold discretisation of J qdd + Fv qd = tau, state (q, qd)."""
    a = np.array([[0.0, 1.0], [0.0, -FV[j] / J[j]]])
    b = np.array([[0.0], [1.0 / J[j]]])
    m = scipy.linalg.expm(np.block([[a, b], [np.zeros((1, 3))]]) * dt)
    return m[:2, :2], m[:2, 2]


def _simulate(d, ref, n, *, tau_max=15.0, disturbance=0.0, quantum=None, full_ff=False):
    """Closed loop: plant (exact ZOH), optional encoder quantisation, VelocityFilter, JointController."""
    ctrl = d.controller(tau_max=tau_max)
    vf = VelocityFilter(DT, d.velocity_filter_hz)
    plants = [_zoh_plant(j) for j in range(4)]
    x = np.zeros((4, 2))
    q_log, tau_log, integ = np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 4))
    for k in range(n):
        r, rd, rdd = ref(k * DT)
        q_meas = x[:, 0] if quantum is None else np.round(x[:, 0] / quantum) * quantum
        tau = ctrl(r, rd, q_meas, vf(q_meas), qdd_ref=rdd, feedforward=FV * rd if full_ff else None)
        for j, (ad, bd) in enumerate(plants):
            x[j] = ad @ x[j] + bd * (tau[j] - disturbance)
        q_log[k], tau_log[k], integ[k] = x[:, 0], tau, ctrl.integrator
    return q_log, tau_log, integ


# ------------------------------------------------------------------------------------------------ design


def test_continuous_poles_match_numpy_roots_of_the_characteristic_polynomial(design):
    for i in range(4):
        _, char, _ = _loop_polys(design, i)
        ours = np.sort_complex(np.roots(char))
        np.testing.assert_allclose(np.sort_complex(design.continuous[i].poles), ours, rtol=1e-8)
        np.testing.assert_allclose(np.sort_complex(ct.poles(design.systems(i)["tracking"])), ours, rtol=1e-8)
        assert np.all(ours.real < 0) and design.continuous[i].stable
        np.testing.assert_allclose(design.systems(i)["char"] / char[0], char / char[0], rtol=1e-10)


def test_continuous_bandwidth_and_phase_margin_from_a_dense_grid(design):
    w = np.logspace(0, 4, 400001)
    s = 1j * w
    for i in range(4):
        num, char, den = _loop_polys(design, i)
        T = np.abs(np.polyval(num, s) / np.polyval(char, s))
        bw_hz = w[np.argmax(T < 1 / math.sqrt(2))] / (2 * math.pi)
        assert bw_hz == pytest.approx(20.0, rel=1e-3)
        assert design.continuous[i].bandwidth_hz == pytest.approx(bw_hz, rel=1e-3)
        half_power_db = 20 * math.log10(1 / math.sqrt(2))  # -3.0103 dB (ct's default is exactly -3 dB)
        bw_ct = ct.bandwidth(design.systems(i)["tracking"], dbdrop=half_power_db) / (2 * math.pi)
        assert bw_ct == pytest.approx(bw_hz, rel=1e-3)
        L = np.polyval(num, s) / np.polyval(den, s)
        k = np.argmin(np.abs(np.abs(L) - 1.0))
        pm = 180.0 + np.degrees(np.angle(L[k]))
        assert design.continuous[i].phase_margin_deg == pytest.approx(pm, abs=0.05)
        # the continuous design keeps w_c dt/2 in reserve for the sample-and-hold
        assert pm == pytest.approx(60.0 + np.degrees(w[k] * DT / 2), abs=0.1)


def test_sampled_loop_meets_the_phase_margin_and_is_stable(design):
    for i in range(4):
        rep = design.discrete[i]
        assert isinstance(rep, LoopReport) and rep.stable
        assert np.abs(rep.poles).max() < 1.0
        assert rep.phase_margin_deg == pytest.approx(60.0, abs=0.5)
        assert rep.gain_margin > 10.0  # > 20 dB before the sampled loop goes unstable (measured 27 dB)
        assert 0.0 < rep.lower_gain_margin < 0.2  # conditionally stable type-2 loop: the gain may drop 5x
        assert rep.bandwidth_hz == pytest.approx(20.0, rel=0.1)
        # discrete poles: roots of the char polynomial assembled from ct.c2d pieces
        sysd = design.systems(i, discrete=True)
        assert sysd["loop"].dt == DT
        np.testing.assert_allclose(np.sort_complex(rep.poles), np.sort_complex(np.roots(sysd["char"])),
                                   rtol=1e-9)


def test_gain_margin_is_where_the_sampled_loop_goes_unstable(design):
    i = 1
    sysd = design.systems(i, discrete=True)
    num, den = sysd["loop"].num[0][0], sysd["loop"].den[0][0]
    gm = design.discrete[i].gain_margin
    for factor, stable in ((0.98 * gm, True), (1.02 * gm, False)):
        assert bool(np.abs(np.roots(np.polyadd(den, factor * np.asarray(num)))).max() < 1.0) is stable


def test_lower_gain_margin_is_where_the_type2_loop_goes_unstable(design):
    for i in (0, 3):
        for discrete in (False, True):
            sysx = design.systems(i, discrete=discrete)
            num, den = np.asarray(sysx["loop"].num[0][0]), np.asarray(sysx["loop"].den[0][0])
            rep = design.discrete[i] if discrete else design.continuous[i]
            gl = rep.lower_gain_margin
            assert 0.0 < gl < 1.0
            for factor, stable in ((1.02 * gl, True), (0.98 * gl, False)):
                roots = np.roots(np.polyadd(den, factor * num))
                ok = np.abs(roots).max() < 1.0 if discrete else roots.real.max() < 0.0
                assert bool(ok) is stable


@pytest.mark.filterwarnings("ignore:stability_margins. Falling back:UserWarning")
def test_phase_margins_agree_with_python_control_on_the_default_design(design):
    for i in range(4):
        _, pm_c, *_ = ct.stability_margins(design.systems(i)["loop"])
        assert design.continuous[i].phase_margin_deg == pytest.approx(pm_c, abs=0.05)
        _, pms, *_ = ct.stability_margins(design.systems(i, discrete=True)["loop"], returnall=True)
        assert np.min(np.abs(np.asarray(pms) - design.discrete[i].phase_margin_deg)) < 0.05


def test_margins_where_python_control_reports_spurious_crossovers():
    # exact velocity, PM 85: ct.stability_margins (python-control 0.10.2) on the sampled loop also lists gain
    # crossovers near w = 0.09 rad/s with PM -161 and 177 deg, where |L| is far from 1 (see the grid below)
    d = design_joint_controller(0.02, 0.05, bandwidth_hz=20.0, phase_margin_deg=85.0, velocity_filter_hz=None)
    rep = d.discrete[0]
    assert rep.stable and rep.phase_margin_deg == pytest.approx(85.0, abs=0.5)
    loop = d.systems(0, discrete=True)["loop"]
    w = np.logspace(-3, math.log10(math.pi / DT) - 1e-9, 200001)
    mag = np.abs(np.polyval(loop.num[0][0], np.exp(1j * w * DT)) / np.polyval(loop.den[0][0], np.exp(1j * w * DT)))
    crossings = w[np.flatnonzero(np.diff(np.sign(mag - 1.0)))]
    assert crossings.size == 1
    assert rep.crossover_hz * 2 * math.pi == pytest.approx(crossings[0], rel=1e-3)


def test_exact_velocity_design_and_other_settings():
    d = design_joint_controller(0.03, 0.1, bandwidth_hz=10.0, phase_margin_deg=50.0, velocity_filter_hz=None)
    assert d.J.shape == (4,) and np.all(d.J == 0.03)
    for rep in d.discrete:
        assert rep.stable and rep.phase_margin_deg == pytest.approx(50.0, abs=0.5)
    for rep in d.continuous:
        assert rep.bandwidth_hz == pytest.approx(10.0, rel=1e-3)
    # zero friction is allowed (double integrator)
    d0 = design_joint_controller(0.03, 0.0)
    assert all(rep.stable for rep in d0.discrete)


def test_report_is_readable(design):
    text = design.report()
    assert text.count("\n") >= 12
    for word in ("axis 1", "axis 4", "Kp", "PM", "bw", "sampled", "continuous", "rise", "overshoot"):
        assert word in text


def test_design_bad_inputs():
    with pytest.raises(ValueError, match="J must be > 0"):
        design_joint_controller(-0.03, 0.1)
    with pytest.raises(ValueError, match="Fv must be >= 0"):
        design_joint_controller(0.03, -0.1)
    with pytest.raises(ValueError, match=r"J must be a scalar or have shape \(4,\), got \(3,\)"):
        design_joint_controller(np.ones(3), 0.1)
    with pytest.raises(ValueError, match="bandwidth_hz must be below the Nyquist frequency"):
        design_joint_controller(0.03, 0.1, bandwidth_hz=600.0)
    with pytest.raises(ValueError, match="bandwidth_hz must be a finite number > 0"):
        design_joint_controller(0.03, 0.1, bandwidth_hz=0.0)
    with pytest.raises(ValueError, match=r"phase_margin_deg must be in \(0, 90\)"):
        design_joint_controller(0.03, 0.1, phase_margin_deg=95.0)
    with pytest.raises(ValueError, match="cannot reach|unstable|cannot be reached"):
        design_joint_controller(0.03, 0.1, bandwidth_hz=300.0)
    with pytest.raises(TypeError, match="dt must be a real number"):
        design_joint_controller(0.03, 0.1, dt="1e-3")
    with pytest.raises(ValueError, match="velocity_filter_hz must be below"):
        design_joint_controller(0.03, 0.1, velocity_filter_hz=500.0)


# -------------------------------------------------------------------------------------- discrete pieces


def test_velocity_filter_is_the_tustin_filtered_derivative():
    rng = np.random.default_rng(0)
    q = np.cumsum(rng.normal(size=(500, 4)), axis=0) * 1e-3
    vf = VelocityFilter(DT, 100.0)
    vf.reset(q0=np.zeros(4))
    out = np.array([vf(qk) for qk in q])
    sysd = ct.c2d(ct.tf([1.0, 0.0], [1.0 / (2 * math.pi * 100.0), 1.0]), DT, "tustin")
    ref = scipy.signal.lfilter(sysd.num[0][0], sysd.den[0][0], q, axis=0)
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match=r"q must have shape \(4,\), got \(3,\)"):
        vf(np.zeros(3))


def test_unsaturated_law_is_the_tustin_pi(design):
    rng = np.random.default_rng(1)
    e = rng.normal(size=(300, 4))
    ctrl = JointController(np.zeros(4), design.kv, design.ki, dt=DT, tau_max=1e9)
    out = np.array([ctrl(np.zeros(4), ek, np.zeros(4), np.zeros(4)) for ek in e])
    for i in range(4):
        pid = ct.c2d(ct.tf([design.kv[i], design.ki[i]], [1.0, 0.0]), DT, "tustin")
        ref = scipy.signal.lfilter(pid.num[0][0], pid.den[0][0], e[:, i])
        np.testing.assert_allclose(out[:, i], ref, rtol=1e-9, atol=1e-9)


# ----------------------------------------------------------------------------------------- closed loop


def test_step_with_constant_disturbance_has_zero_steady_state_error(design):
    step = lambda t: (np.full(4, 0.1), np.zeros(4), np.zeros(4))  # noqa: E731
    q, tau, _ = _simulate(design, step, 3000, disturbance=0.5)  # 0.5 N m load (gravity share, friction)
    assert np.all(np.abs(q[-1] - 0.1) < 1e-9)
    np.testing.assert_allclose(tau[-1], 0.5, atol=1e-6)  # integral holds the load
    # rise time of the simulated step agrees with ct.step_info on the sampled model (no disturbance)
    q0, _, _ = _simulate(design, step, 1000)
    k10, k90 = np.argmax(q0 >= 0.01, axis=0), np.argmax(q0 >= 0.09, axis=0)
    rise = (k90 - k10) * DT
    np.testing.assert_allclose(rise, [rep.rise_time for rep in design.discrete], atol=2.5 * DT)


def _sine(amp, w):
    def ref(t):
        return (np.full(4, amp * math.sin(w * t)), np.full(4, amp * w * math.cos(w * t)),
                np.full(4, -amp * w * w * math.sin(w * t)))
    return ref


def _predicted_error(d, w, amp, viscous_ff):
    """Linear steady-state error amplitude of the cascade at s = j w (continuous approximation).

    J e'' + Fv e' = Fv r' (1 - viscous_ff) - C_I (Kp e + r' - V q) with V q = V r - V e, so
    e = r (Fv s (1 - viscous_ff) - C_I (s - V)) / (J s^2 + Fv s + C_I (Kp + V)).
    """
    s = 1j * w
    v = s if d.tau_v is None else s / (d.tau_v * s + 1)
    ci = d.kv + d.ki / s
    num = FV * s * (0.0 if viscous_ff else 1.0) - ci * (s - v)
    return amp * np.abs(num / (J * s**2 + FV * s + ci * (d.kp + v)))


def test_sine_tracking_error_is_small_and_matches_the_linear_prediction(design):
    amp, w = 0.5, 2 * math.pi * 1.0
    n = 4000
    t = (np.arange(n) + 1) * DT  # q_log[k] is the state after step k
    q, tau, _ = _simulate(design, _sine(amp, w), n, quantum=2 * math.pi / 2**16)  # 16-bit encoder
    err = np.abs(amp * np.sin(w * t)[:, None] - q)[2000:].max(axis=0)
    assert np.all(err < 3e-3 * amp)  # measured 1.4e-3 to 2.8e-3 of the amplitude
    assert np.abs(tau).max() < 15.0
    np.testing.assert_allclose(err, _predicted_error(design, w, amp, False), rtol=0.1)
    # with the viscous feed-forward too, what is left is the velocity filter's lag against the exact qd_ref
    q2, _, _ = _simulate(design, _sine(amp, w), n, full_ff=True)
    err2 = np.abs(amp * np.sin(w * t)[:, None] - q2)[2000:].max(axis=0)
    np.testing.assert_allclose(err2, _predicted_error(design, w, amp, True), rtol=0.1)


def test_exact_velocity_and_full_feed_forward_track_almost_exactly():
    d = design_joint_controller(J, FV, velocity_filter_hz=None)
    ctrl = d.controller()
    plants = [_zoh_plant(j) for j in range(4)]
    amp, w = 0.5, 2 * math.pi * 1.0
    ref = _sine(amp, w)
    x = np.zeros((4, 2))
    x[:, 1] = amp * w  # start on the trajectory
    worst = 0.0
    for k in range(2000):
        r, rd, rdd = ref(k * DT)
        tau = ctrl(r, rd, x[:, 0], x[:, 1], qdd_ref=rdd, feedforward=FV * rd)
        for j, (ad, bd) in enumerate(plants):
            x[j] = ad @ x[j] + bd * tau[j]
        worst = max(worst, np.abs(x[:, 0] - ref((k + 1) * DT)[0]).max())
    # only the sample-and-hold of a smooth feed-forward is left, of order amp (w dt)^2
    assert worst < amp * (w * DT) ** 2
    assert np.all(_predicted_error(d, w, amp, True) < 1e-12)


def test_saturation_and_anti_windup(design):
    big = lambda t: (np.full(4, 3.0), np.zeros(4), np.zeros(4))  # noqa: E731
    q, tau, integ = _simulate(design, big, 4000, tau_max=2.0)
    assert np.abs(tau).max() <= 2.0
    assert np.any(np.abs(tau) == 2.0)  # the limit was actually reached
    # conditional integration keeps the integrator far from its +-tau_max clamp (measured 0.29 N m; without
    # it, it winds up to the 2 N m clamp) and the overshoot small (measured 3.3-4.3 %; 4.2-6.6 % without)
    assert np.abs(integ).max() < 0.5 * 2.0
    assert np.all(q.max(axis=0) < 3.0 * 1.05)
    np.testing.assert_allclose(q[-1], 3.0, atol=1e-4)
    ctrl = JointController(design.kp, design.kv, design.ki, tau_max=[1.0, 2.0, 3.0, 4.0])
    out = ctrl(np.full(4, 100.0), np.zeros(4), np.zeros(4), np.zeros(4))
    np.testing.assert_array_equal(out, [1.0, 2.0, 3.0, 4.0])
    assert ctrl.saturated.all()
    ctrl.reset()
    assert not ctrl.saturated.any() and np.all(ctrl.integrator == 0)


def test_controller_bad_inputs(design):
    ctrl = JointController(design.kp, design.kv, design.ki)
    z = np.zeros(4)
    with pytest.raises(ValueError, match=r"q must have shape \(4,\), got \(3,\)"):
        ctrl(z, z, np.zeros(3), z)
    with pytest.raises(ValueError, match="inertia_ff is None"):
        ctrl(z, z, z, z, qdd_ref=z)
    with pytest.raises(ValueError, match="qd_ref must be finite"):
        ctrl(z, np.full(4, np.nan), z, z)
    with pytest.raises(ValueError, match="tau_max must be > 0"):
        JointController(design.kp, design.kv, design.ki, tau_max=0.0)
    with pytest.raises(ValueError, match=r"kp must be a scalar or have shape \(4,\), got \(2,\)"):
        JointController(np.ones(2), design.kv, design.ki)
    with pytest.raises(TypeError, match="design must be a ControllerDesign"):
        JointController.from_design({"kp": 1.0})
    with pytest.raises(ValueError, match="cutoff_hz must be below the Nyquist"):
        VelocityFilter(DT, 800.0)
    assert np.all(JointController.from_design(design).inertia_ff == J)
