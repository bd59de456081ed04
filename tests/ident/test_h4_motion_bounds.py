"""The certificate's reuse of the measured equation's motion-tube bounds (h4_certified.MotionBounds) against
independent oracles: containment checked by sampling tau, and the reused second-derivative bounds against central
differences of the enclosed point gradients at random states inside the exact positions' tubes."""

import numpy as np
import pytest

from h4bench import sim
from h4bench.ident.numerics.jets import MR
from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.robots.h4_certified import MotionBounds, Processing, certified_steps
from h4bench.sim.kinematics import inverse_kinematics
from tests.ident.h4_hessian_oracle import assert_hessians_within


@pytest.fixture(scope="module")
def geometry():
    return sim.H4Geometry.from_model(sim.load_model())


def _log(geometry, n=61, h=1e-3):
    """A smooth true motion (n, 4) [rad] around the home pose and its quantised measurement (2 pi / 20000)."""
    t = np.arange(n) * h
    x = geometry.x_home + np.stack([0.02 * np.sin(9 * t), 0.015 * np.cos(7 * t), 0.01 * np.sin(5 * t + 0.3),
                                    0.1 * np.sin(6 * t)], axis=1)
    q_true = inverse_kinematics(geometry, x)
    res = 2 * np.pi / 20000
    return q_true, np.round(q_true / res) * res, res


def _spec(res, q_true, h=1e-3):
    qd = np.diff(q_true, axis=0) / h
    qdd = np.diff(q_true, 2, axis=0) / h**2
    return ErrorSpec(n_joints=4, sample_period=h, position_resolution=res, torque_error=1.0,
                     qd_max=2 * np.abs(qd).max(axis=0) + 0.1, qdd_max=2 * np.abs(qdd).max(axis=0) + 1.0)


def test_covers_agrees_with_sampled_containment():
    rng = np.random.default_rng(3)
    c, a = rng.normal(size=(50, 4)), rng.normal(size=(50, 4)) * 1e-2
    outer = MotionBounds(q_tube=MR(c, np.full((50, 4), 1e-3), a), v_tube=MR(c, np.full((50, 4), 0.5)),
                         HP=np.zeros((50, 4, 2, 8, 8)), HF=np.zeros((50, 4, 2, 8, 8)), proven=np.ones(50, bool))
    # inner tubes: half of them shifted (centre, slope or radius) by up to twice the room
    dc, da = rng.uniform(-1, 1, (2, 50, 4)) * 4e-4
    r = np.full((50, 4), 2e-4) * rng.uniform(0.5, 3.0, (50, 1))
    inner_q, inner_v = MR(c + dc, r, a + da), MR(c, np.full((50, 4), 0.4))
    got = outer.covers(inner_q, inner_v)
    taus = np.linspace(-1, 1, 201)[:, None, None]
    lo_in, hi_in = inner_q.c + inner_q.a * taus - inner_q.r, inner_q.c + inner_q.a * taus + inner_q.r
    lo_out, hi_out = outer.q_tube.c + outer.q_tube.a * taus - 1e-3, outer.q_tube.c + outer.q_tube.a * taus + 1e-3
    sampled = np.all((lo_in >= lo_out) & (hi_in <= hi_out), axis=(0, 2))
    assert np.all(sampled[got])  # every covered tube is inside at every sampled tau
    # the containment test is exact for these linear tubes (max over tau at the ends): it misses none beyond a hair
    assert np.array_equal(got, sampled) and 5 < got.sum() < 45
    wide_v = MR(c, np.full((50, 4), 0.6))
    assert not outer.covers(inner_q, wide_v).any()
    unproven = MotionBounds(outer.q_tube, outer.v_tube, outer.HP, outer.HF, np.zeros(50, bool))
    assert not unproven.covers(inner_q, inner_v).any()


def test_exact_equation_reuses_bounds_that_hold_inside_its_own_tubes(geometry):
    q_true, q_meas, res = _log(geometry)
    spec = _spec(res, q_true)
    h = spec.sample_period
    measured = certified_steps(geometry, q_meas, spec, Processing())
    exact = certified_steps(geometry, q_true, spec, Processing(), position_error=0.0, motion=measured.motion)
    own = certified_steps(geometry, q_true, spec, Processing(), position_error=0.0)
    assert measured.motion.covers(exact.motion.q_tube, exact.motion.v_tube).all()
    assert exact.proven_motion.all()
    np.testing.assert_array_equal(exact.motion.HP, measured.motion.HP)
    # the reused bounds (over the bigger tubes) are at least about the exact tubes' own ones
    assert np.median(exact.motion.HF.sum(axis=(-1, -2)) / own.motion.HF.sum(axis=(-1, -2))) >= 1.0
    # oracle: central differences of the enclosed point gradients at random states inside the EXACT tubes
    rng = np.random.default_rng(7)
    steps = np.arange(0, q_true.shape[0] - 1, 6)
    Qt, Vt = exact.motion.q_tube[steps], exact.motion.v_tube[steps]
    HP, HF = exact.motion.HP[steps], exact.motion.HF[steps]
    for _ in range(3):
        tau = rng.uniform(-1, 1, (steps.size, 1))
        zq = Qt.c + Qt.a * tau + rng.uniform(-1, 1, Qt.shape) * Qt.r
        zv = Vt.c + rng.uniform(-1, 1, Vt.shape) * Vt.r
        assert_hessians_within(geometry, zq, zv, HP, HF)
    # a log that is not the measured one's truth (shifted by 10 counts): nothing is reused, the jets run
    shifted = certified_steps(geometry, q_true + 10 * res, spec, Processing(), position_error=0.0,
                              motion=measured.motion)
    assert not measured.motion.covers(shifted.motion.q_tube, shifted.motion.v_tube).any()
    assert shifted.proven_motion.all()


def test_two_processes_give_the_same_bits(geometry, monkeypatch):
    """certified_equation(processes=2): the later half of the interval jets' chunks in a worker process, for the
    measured log and for the exact one reusing its bounds on part of the steps; every array equal bit for bit."""
    from h4bench.ident.robots import h4_jets
    from h4bench.ident.robots.h4_certified import certified_equation

    monkeypatch.setattr(h4_jets, "BOX_CHUNK", 16)  # 60 steps: 4 chunks, 2 in each process
    monkeypatch.setattr(h4_jets, "POINT_CHUNK", 16)  # and the point jets likewise
    q_true, q_meas, res = _log(geometry)
    spec = _spec(res, q_true)
    rng = np.random.default_rng(5)
    tau = rng.normal(size=q_meas.shape)
    processing = Processing(kernel_steps=40)
    for_one = certified_equation(geometry, q_meas, tau, spec, processing, processes=1)
    for_two = certified_equation(geometry, q_meas, tau, spec, processing, processes=2)
    shifted = q_true.copy()
    shifted[30:] += 10 * res  # the later steps' tubes leave the measured ones: the jets run on part of the steps
    own = certified_equation(geometry, shifted, tau, spec, processing, position_error=0.0).motion
    assert 0 < int(for_one.motion.covers(own.q_tube, own.v_tube).sum()) < 60
    exact = [certified_equation(geometry, shifted, tau, spec, processing, position_error=0.0,
                                motion=for_one.motion, processes=p) for p in (1, 2)]
    for a, b in ((for_one, for_two), tuple(exact)):
        for name in ("Wc", "D", "y", "bound"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        for name in ("HP", "HF", "proven"):
            np.testing.assert_array_equal(getattr(a.motion, name), getattr(b.motion, name))
        for k in a.terms:
            np.testing.assert_array_equal(a.terms[k], b.terms[k])
    with pytest.raises(ValueError, match="processes must be 1 or 2"):
        certified_equation(geometry, q_meas, tau, spec, processing, processes=3)


def test_nonlinear_rows_any_chunk_and_a_loop_oracle(geometry):
    """nonlinear_rows gives the same bits for any row chunk; its first-order encoder radius equals a per-row loop
    that sums |d row / d q_u| e_u from the per-step derivatives (the summation by parts written out)."""
    from h4bench.ident.processing.weakform import make_kernel, nonlinear_rows, row_windows

    q_true, q_meas, res = _log(geometry)
    spec = _spec(res, q_true)
    st = certified_steps(geometry, q_meas, spec, Processing()).nonlinear
    h = spec.sample_period
    kernel, windows = make_kernel(40, h, "hann"), row_windows(q_meas.shape[0], 40, 3)
    outs = [nonlinear_rows(st, windows, kernel, chunk=c) for c in (None, 1, 4, 1000)]
    for other in outs[1:]:
        for a, b in zip(outs[0], other):
            np.testing.assert_array_equal(a, b)
    value, meas = outs[0][0], outs[0][1]
    s, K = kernel.slopes, kernel.integrals
    for r, j0 in enumerate(windows.start):
        v = sum(-h * s[w] * st.P[j0 + w] + K[w] * st.F[j0 + w] for w in range(40))
        np.testing.assert_allclose(value[r], v, rtol=1e-12, atol=1e-15)
        g = np.zeros((41,) + st.dPa.shape[1:])
        for w in range(40):
            g[w] += -h * s[w] * st.dPa[j0 + w] + K[w] * st.dFa[j0 + w]
            g[w + 1] += -h * s[w] * st.dPb[j0 + w] + K[w] * st.dFb[j0 + w]
        first = np.einsum("uica,ua->ic", np.abs(g), st.e[j0:j0 + 41])
        assert np.all(meas[r] >= first * (1 - 1e-12))  # the radius holds the plain first-order term
        assert np.all(meas[r] <= first * 1.5 + 1e-9)  # and not much more (radii of the enclosures, rounding)


def test_encoder_from_tube_rule():
    """``"auto"`` takes a step's encoder bounds from its tube where, on every joint, the encoder's speed error is at
    most the motion's ``qdd_max h / 2``."""
    from h4bench.ident.robots.h4_certified import encoder_from_tube

    h, qdd = 1e-3, np.array([600.0, 800.0, 1000.0, 1200.0])
    ev = np.array([[0.3, 0.4, 0.5, 0.6],     # each exactly at qdd h / 2
                   [0.2, 0.2, 0.2, 0.2],     # below everywhere
                   [0.2, 0.2, 0.2, 0.61],    # one joint above
                   [1.53, 1.53, 1.53, 1.53]])  # a 4 096-count encoder
    np.testing.assert_array_equal(encoder_from_tube(ev, qdd, h), [True, True, False, False])
    with pytest.raises(ValueError, match="encoder_jets must be one of"):
        Processing(encoder_jets="sampled")


def test_encoder_bounds_from_the_tube_hold_over_the_encoder_box(geometry):
    """``encoder_jets = "tube"``: every step's encoder bounds are its motion tube's (one evaluation); they hold at
    random states of the encoder box (the oracle: central differences of the enclosed point gradients); ``"auto"``
    gives the bits of ``"box"`` where the stated qdd_max is small against the encoder's speed error and those of
    ``"tube"`` where it is large."""
    from h4bench.ident.robots.h4_certified import certified_equation

    q_true, q_meas, res = _log(geometry)
    spec = _spec(res, q_true)  # qdd_max a few rad/s^2: qdd_max h / 2 far below the encoder's 2 e / h = 0.31 rad/s
    h, S = spec.sample_period, q_meas.shape[0] - 1
    tube = certified_steps(geometry, q_meas, spec, Processing(encoder_jets="tube"))
    assert tube.encoder_from_tube == S and tube.proven.all()
    rng = np.random.default_rng(11)
    steps = np.arange(0, S, 5)
    e = spec.position_error(q_meas)
    qm, vm = 0.5 * (q_meas[:-1] + q_meas[1:]), np.diff(q_meas, axis=0) / h
    em, ev = 0.5 * (e[:-1] + e[1:]), (e[:-1] + e[1:]) / h
    for _ in range(3):
        zq = qm[steps] + rng.uniform(-1, 1, (steps.size, 4)) * em[steps]
        zv = vm[steps] + rng.uniform(-1, 1, (steps.size, 4)) * ev[steps]
        assert_hessians_within(geometry, zq, zv, tube.motion.HP[steps], tube.motion.HF[steps])
    tau = rng.normal(size=q_meas.shape)
    eqs = {m: certified_equation(geometry, q_meas, tau, spec, Processing(kernel_steps=40, encoder_jets=m))
           for m in ("auto", "box", "tube")}
    assert eqs["auto"].info["encoder_boxes_from_tube"] == 0 and eqs["tube"].info["encoder_boxes_from_tube"] == S
    fast = ErrorSpec(n_joints=4, sample_period=h, position_resolution=res, torque_error=1.0, qd_max=spec.qd_max,
                     qdd_max=np.full(4, 2000.0))  # qdd_max h / 2 = 1 rad/s: every step from the tube
    fast_eqs = {m: certified_equation(geometry, q_meas, tau, fast, Processing(kernel_steps=40, encoder_jets=m))
                for m in ("auto", "tube")}
    assert fast_eqs["auto"].info["encoder_boxes_from_tube"] == S
    for a, b in ((eqs["auto"], eqs["box"]), (fast_eqs["auto"], fast_eqs["tube"])):
        for name in ("Wc", "D", "y", "bound"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # the two are other enclosures of the same terms (interval jets are not monotone in the box: either may be the
    # tighter on a slow motion, where the tube is barely bigger than the encoder box)
    assert not np.array_equal(eqs["tube"].D, eqs["box"].D)


def test_the_kernels_rows_in_a_worker_give_the_same_bits(geometry):
    """A family's rows with about half of its kernels computed in a worker process (certified_equation with
    processes=2): every kernel's arrays equal those computed here, bit for bit, and the motion bounds re-attached."""
    import concurrent.futures
    import multiprocessing

    from h4bench.ident.robots.h4_certified import _family_rows

    q_true, q_meas, res = _log(geometry)
    spec = _spec(res, q_true)
    steps = certified_steps(geometry, q_meas, spec, Processing())
    tau = np.random.default_rng(9).normal(size=q_meas.shape)
    pairs = [(40, 2), (44, 3), (48, 2), (52, 5)]
    here = _family_rows(steps, pairs, "hann", tau)
    with concurrent.futures.ProcessPoolExecutor(max_workers=1,
                                                mp_context=multiprocessing.get_context("forkserver")) as pool:
        split = _family_rows(steps, pairs, "hann", tau, pool)
    assert [e.info["kernel_steps"] for e in split] == [40, 44, 48, 52]
    for a, b in zip(here, split):
        for name in ("Wc", "D", "y", "bound", "sample", "joint"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        for k in a.terms:
            np.testing.assert_array_equal(a.terms[k], b.terms[k])
        assert b.motion is steps.motion
