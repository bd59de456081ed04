"""The interval regressor (ident.estimators.uncertain) against independent oracles.

* Oettli-Prager hull vs vertex enumeration: the feasible set of every vertex matrix of [W] (all 2^(m p) of them
  on tiny problems, a random sample plus the all-lower / all-upper ones on larger ones) is a point-regressor
  polytope whose hull scipy's linprog computes; the union of these hulls must lie inside the interval hull.
  With theta >= 0 and ``D_kj * max theta_j <= b_k`` (each vertex step of a row's value is at most the strip
  width, so some vertex value falls in every strip the row's interval meets) the union IS the Oettli-Prager
  set, and the hulls must be equal.
* Encoder radii vs the processing operator built independently with scipy (sosfiltfilt + numpy.gradient on
  the identity), and the worst-case error that attains them.
* The H4 interval regressor vs Monte Carlo: W at random states inside the boxes (and at their corners) lies in
  [Wc - D, Wc + D].
* The interval parallel filter vs filtering random matrices drawn inside [W].
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.signal
from scipy.optimize import linprog

from h4bench import ident
from h4bench.ident.processing.filtering import ProcessingSettings, default_edge_samples, parallel_filter
from h4bench.ident.estimators import uncertain_signed
from h4bench.ident.estimators.uncertain import uncertain_hull
from h4bench.ident.estimators.uncertain_signed import signed_uncertain_hull
from h4bench.ident.numerics import lp
from h4bench.ident.robots.h4_interval import (
    Distortion,
    encoder_radii,
    filter_interval,
    interval_equation,
    interval_regressor,
)


def lp_hull(W, y, b, lo, hi):
    A = np.vstack([W, -W])
    rhs = np.concatenate([y + b, b - y])
    out = []
    for sign in (1.0, -1.0):
        vals = []
        for i in range(W.shape[1]):
            c = np.zeros(W.shape[1])
            c[i] = sign
            r = linprog(c, A_ub=A, b_ub=rhs, bounds=list(zip(lo, hi)), method="highs")
            if r.status == 2:
                return None
            vals.append(sign * r.fun)
        out.append(np.array(vals))
    return out[0], out[1]


def vertex_union(Wc, D, y, b, lo, hi, vertices):
    L, U = np.full(Wc.shape[1], np.inf), np.full(Wc.shape[1], -np.inf)
    for signs in vertices:
        res = lp_hull(Wc + np.asarray(signs).reshape(Wc.shape) * D, y, b, lo, hi)
        if res is not None:
            L, U = np.minimum(L, res[0]), np.maximum(U, res[1])
    return L, U


@pytest.mark.parametrize("seed, m, p", [(0, 3, 2), (1, 4, 2), (2, 3, 2), (3, 4, 2)])
def test_oettli_prager_hull_equals_the_vertex_hull(seed, m, p):
    rng = np.random.default_rng(seed)
    lo, hi = np.zeros(p), 2.0 * np.ones(p)
    Wc = rng.uniform(-2, 2, (m, p))
    b = rng.uniform(0.5, 1.0, m)
    D = rng.uniform(0, 1, (m, p)) * b[:, None] / hi[None, :]  # D_kj hi_j <= b_k: the vertex union is the whole set
    theta = rng.uniform(0.2, 1.8, p)
    y = Wc @ theta + rng.uniform(-0.5, 0.5, m) * b
    box = uncertain_hull(Wc, D, y, b, (lo, hi))
    L, U = vertex_union(Wc, D, y, b, lo, hi, itertools.product((-1.0, 1.0), repeat=m * p))
    assert np.all(box.lower <= L + 1e-9) and np.all(box.upper >= U - 1e-9)  # outer
    np.testing.assert_allclose(box.lower, L, atol=1e-7)
    np.testing.assert_allclose(box.upper, U, atol=1e-7)


def test_vertex_sample_inside_the_interval_hull_when_gaps_are_wide():
    """Larger radii (the union of vertex sets may then be smaller than the set): still inside the hull."""
    rng = np.random.default_rng(7)
    m, p = 14, 3
    lo, hi = np.zeros(p), 3.0 * np.ones(p)
    Wc = rng.uniform(-2, 2, (m, p))
    D = rng.uniform(0, 0.6, (m, p))
    theta = rng.uniform(0.5, 2.0, p)
    W_true = Wc + rng.uniform(-1, 1, (m, p)) * D
    y = W_true @ theta + rng.uniform(-0.3, 0.3, m)
    box = uncertain_hull(Wc, D, y, 0.3, (lo, hi))
    assert box.contains(theta).all()
    vertices = [np.ones(m * p), -np.ones(m * p)] + [rng.choice([-1.0, 1.0], m * p) for _ in range(150)]
    L, U = vertex_union(Wc, D, y, 0.3 * np.ones(m), lo, hi, vertices)
    assert np.all(box.lower <= L + 1e-9) and np.all(box.upper >= U - 1e-9)


def test_interval_hull_converges_and_is_tight_on_many_rows():
    """2000 rows: the stacked one-sided rows must not defeat constraint generation (each row's violation is
    measured against its own finite range); the box equals linprog's hull of the 4000 stacked inequalities."""
    rng = np.random.default_rng(11)
    m, p = 2000, 5
    theta = rng.uniform(0.5, 1.5, p)
    Wc = rng.standard_normal((m, p)) * 10.0 ** rng.uniform(-1, 1, p)
    D = rng.uniform(0, 0.05, (m, p)) * np.abs(Wc)
    y = (Wc + rng.uniform(-1, 1, (m, p)) * D) @ theta + rng.uniform(-0.5, 0.5, m)
    prior = (np.zeros(p), 3 * np.ones(p))
    box = uncertain_hull(Wc, D, y, 0.5, prior)
    assert box.info["converged"] and box.info["working_rows"] < m
    A = np.vstack([Wc - D, -(Wc + D)])
    rhs = np.concatenate([y + 0.5, 0.5 - y])
    for i in range(p):
        c = np.zeros(p)
        c[i] = 1.0
        lo = linprog(c, A_ub=A, b_ub=rhs, bounds=[(0, 3)] * p, method="highs").fun
        hi = -linprog(-c, A_ub=A, b_ub=rhs, bounds=[(0, 3)] * p, method="highs").fun
        assert box.lower[i] <= lo + 1e-9 and box.upper[i] >= hi - 1e-9
        assert box.lower[i] == pytest.approx(lo, abs=1e-7) and box.upper[i] == pytest.approx(hi, abs=1e-7)


def test_zero_radius_is_the_point_hull():
    rng = np.random.default_rng(1)
    W = rng.standard_normal((80, 4))
    y = W @ np.ones(4) + rng.uniform(-1, 1, 80)
    prior = (np.zeros(4), 3 * np.ones(4))
    box = uncertain_hull(W, 0.0, y, 1.0, prior)
    plain = ident.estimate(W, y, 1.0, prior)
    np.testing.assert_allclose(box.lower, plain.lower, atol=1e-9)
    np.testing.assert_allclose(box.upper, plain.upper, atol=1e-9)


def test_inconsistent_interval_data_are_reported():
    rng = np.random.default_rng(2)
    Wc = rng.uniform(0.5, 1.5, (30, 2))
    y = Wc @ np.ones(2)
    y[3] += 50.0
    with pytest.raises(ident.InconsistentDataError) as err:
        uncertain_hull(Wc, 0.01, y, 0.5, (np.zeros(2), 3 * np.ones(2)))
    assert err.value.scale_lower > 1.0
    # the reported smallest consistent bound is indeed consistent
    box = uncertain_hull(Wc, 0.01, y, err.value.min_bound, (np.zeros(2), 3 * np.ones(2)))
    assert np.all(box.lower <= box.upper)


def test_bad_interval_inputs_are_named():
    Wc = np.ones((5, 2))
    prior = (np.zeros(2), np.ones(2))
    with pytest.raises(ValueError, match="D must be >= 0"):
        uncertain_hull(Wc, -np.ones((5, 2)), np.ones(5), 1.0, prior)
    with pytest.raises(ValueError, match="D must be a scalar or have the shape of Wc"):
        uncertain_hull(Wc, np.ones((4, 2)), np.ones(5), 1.0, prior)
    with pytest.raises(ValueError, match="y must have shape"):
        uncertain_hull(Wc, 0.1, np.ones(4), 1.0, prior)
    with pytest.raises(ValueError, match="Wc must have shape"):
        uncertain_hull(np.ones(5), 0.1, np.ones(5), 1.0, prior)
    with pytest.raises(ValueError, match="prior lower must be >= 0"):
        uncertain_hull(Wc, 0.1, np.ones(5), 1.0, (-np.ones(2), np.ones(2)))
    with pytest.raises(ValueError, match="bound must be finite and > 0"):
        uncertain_hull(Wc, 0.1, np.ones(5), 0.0, prior)
    with pytest.raises(ValueError, match="counts_per_turn must be an integer >= 1"):
        encoder_radii(0, 1e-3, 20.0)
    with pytest.raises(ValueError, match="r_qdd must be finite and >= 0"):
        interval_regressor(lambda q, qd, qdd: np.zeros((4, 14)), np.zeros((1, 4)), np.zeros((1, 4)),
                           np.zeros((1, 4)), 0.0, 0.0, -1.0)


# ----------------------------------------------------------------------------------------- encoder radii
def scipy_operator(n, dt, fc, order=4):
    """The processing operator (n x n) for each derivative order, built with scipy directly."""
    sos = scipy.signal.butter(order, fc, output="sos", fs=1 / dt)
    pad = min(default_edge_samples(dt, fc), n - 1)
    qf = scipy.signal.sosfiltfilt(sos, np.eye(n), axis=0, padtype="odd", padlen=pad)
    qd = np.gradient(qf, dt, axis=0, edge_order=2)
    qdd = np.empty_like(qf)
    qdd[1:-1] = (qf[2:] - 2 * qf[1:-1] + qf[:-2]) / dt**2
    qdd[0] = (2 * qf[0] - 5 * qf[1] + 4 * qf[2] - qf[3]) / dt**2
    qdd[-1] = (2 * qf[-1] - 5 * qf[-2] + 4 * qf[-3] - qf[-4]) / dt**2
    return qf, qd, qdd


@pytest.mark.parametrize("n", [600, 2400])
def test_encoder_radii_match_the_operator_and_are_attained(n):
    dt, fc, counts = 1e-3, 50.0, 4096
    radii = encoder_radii(counts, dt, fc, n=n)
    trim = default_edge_samples(dt, fc) + 2
    ops = scipy_operator(n, dt, fc)
    eps = np.pi / counts
    for o, P in enumerate(ops):
        rows = np.abs(P[trim: n - trim]).sum(axis=1)
        assert radii[o] >= rows.max() * eps  # outer
        assert radii[o] <= rows.max() * eps * (1 + 1e-5)  # and tight
        k = trim + int(np.argmax(rows))
        worst = eps * np.sign(P[k])  # the quantisation error that attains the radius at sample k
        assert abs(P[k] @ worst) == pytest.approx(radii[o], rel=1e-5)
        rng = np.random.default_rng(o)
        e = rng.uniform(-eps, eps, n)
        assert np.all(np.abs((P @ e)[trim: n - trim]) <= radii[o])


# ------------------------------------------------------------------------------ interval H4 regressor
@pytest.mark.parametrize("radii", [(2e-4, 0.01, 0.5), (2e-3, 0.2, 20.0)])
def test_h4_interval_regressor_contains_sampled_states(geometry, exact_recording, radii):
    rec = exact_recording
    idx = np.arange(100, rec["q"].shape[0] - 100, 40)
    q, qd, qdd = rec["q"][idx], rec["qd"][idx], rec["qdd"][idx]

    def fn(q, qd, qdd):
        return ident.regressor(geometry, q, qd, qdd)

    Wc, D = interval_regressor(fn, q, qd, qdd, *radii, sign_radius=np.full((idx.size, 4), radii[1]))
    rng = np.random.default_rng(0)
    r = [np.full((idx.size, 4), v) for v in radii]
    sign_sure = np.repeat(D[:, 10:14].max(axis=1) == 0, 1)  # rows whose sign entries are certain
    for trial in range(60):
        if trial < 8:  # corners of the state boxes (all + / all - per order)
            s = [np.sign(rng.standard_normal((idx.size, 4))) for _ in range(3)]
        else:
            s = [rng.uniform(-1, 1, (idx.size, 4)) for _ in range(3)]
        W = fn(q + s[0] * r[0], qd + s[1] * r[1], qdd + s[2] * r[2])
        outside = np.abs(W - Wc) > D * (1 + 1e-12) + 1e-12
        outside[:, 10:14] &= sign_sure[:, None]  # sign columns: checked where the sign is declared certain
        assert not outside.any(), np.argwhere(outside)[:5]
    # the linear columns get exactly the state radius (times the stated margin)
    rows_joint0 = np.arange(0, 4 * idx.size, 4)
    np.testing.assert_allclose(D[rows_joint0, 0], radii[2] * 1.1, rtol=1e-9)
    np.testing.assert_allclose(D[rows_joint0, 6], radii[1] * 1.1, rtol=1e-9)


def test_sign_column_becomes_an_interval_near_zero_speed():
    n = 6
    qd = np.zeros((n, 4))
    qd[:, 0] = [1.0, 0.5, 0.05, -0.02, -0.6, -1.0]

    def fn(q, qd, qdd):
        w = np.zeros((q.shape[0], 4, 14))
        w[..., 10:14] = np.eye(4)[None] * np.sign(qd)[:, :, None]
        return w.reshape(-1, 14)

    Wc, D = interval_regressor(fn, np.zeros((n, 4)), qd, np.zeros((n, 4)), 0.0, 0.1, 0.0)
    rows = 4 * np.arange(n)
    # certain where this sample and the next are beyond the radius with the same sign
    np.testing.assert_array_equal(D[rows, 10], [0, 1, 1, 1, 0, 1])  # the last sample has no next: uncertain
    np.testing.assert_array_equal(Wc[rows, 10], [1, 0, 0, 0, -1, 0])


def test_interval_filter_contains_filtered_members():
    rng = np.random.default_rng(3)
    n, p = 120, 3
    Wc = rng.standard_normal((4 * n, p))
    D = rng.uniform(0, 0.2, (4 * n, p))
    y = rng.standard_normal(4 * n)
    h = scipy.signal.firwin(21, 0.2)
    Wf, Df, yf, bf, fe = filter_interval(Wc, D, y, 0.1, 5, h)
    assert np.all(Df >= 0)
    for _ in range(20):
        W = Wc + rng.uniform(-1, 1, Wc.shape) * D
        Wm = parallel_filter(W, y, 0.1, 5, taps=h).W
        assert np.all(np.abs(Wm - Wf) <= Df)
    np.testing.assert_array_equal(yf, parallel_filter(Wc, y, 0.1, 5, taps=h).y)


@pytest.mark.parametrize("decimation, numtaps", [(10, 41), (1, 1)])
def test_interval_equation_encloses_a_noise_free_recording(geometry, exact_recording, decimation, numtaps):
    """On MuJoCo's exact states and torques, exact angles (no encoder part) and the distortion measured on the
    same record, the truth is in the interval feasible set, with and without the parallel filter."""
    rec = exact_recording
    settings = ProcessingSettings(dt=rec["h"], position_cutoff_hz=20.0, decimation=decimation, numtaps=numtaps)

    def fn(q, qd, qdd):
        return ident.regressor(geometry, q, qd, qdd)

    from h4bench.ident.robots.h4_interval import regressor_distortion

    dist = regressor_distortion(fn, rec["q"], rec["qd"], rec["qdd"], settings)
    ieq = interval_equation(fn, rec["q"], rec["tau"], 1e-3, settings, counts_per_turn=None,
                            distortion=dist, sign_band=0.05)
    from h4bench import sim

    theta = sim.true_parameters(sim.load_model())
    lo_v = (ieq.Wc - ieq.D) @ theta - ieq.y - ieq.bound
    hi_v = ieq.y - ieq.bound - (ieq.Wc + ieq.D) @ theta
    assert max(lo_v.max(), hi_v.max()) <= 0.0
    assert isinstance(dist, Distortion) and dist.regressor.shape == (4, 14)


def _op_problem(m=600, p=5, seed=11):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.5, 1.5, p)
    Wc = rng.standard_normal((m, p)) * 10.0 ** rng.uniform(-1, 1, p)
    D = rng.uniform(0, 0.05, (m, p)) * np.abs(Wc)
    y = (Wc + rng.uniform(-1, 1, (m, p)) * D) @ theta + rng.uniform(-0.5, 0.5, m)
    return Wc, D, y, theta


def test_uncertain_hull_counts_budget_fallbacks_and_stays_outer(monkeypatch):
    """Every HiGHS run limited to 3 iterations: the LPs fall back (counted, warned, named), and the box still
    contains the unlimited run's box (itself linprog's hull: test_interval_hull_converges_and_is_tight_on_many_rows)."""
    Wc, D, y, theta = _op_problem()
    prior = ident.Box(np.zeros(5), 3 * np.ones(5), names=("a", "b", "c", "d", "e"))
    full = uncertain_hull(Wc, D, y, 0.5, prior)
    assert (full.info["lp_limit_hits"], full.info["lp_retries"], full.info["lp_fallbacks"]) == (0, 0, 0)
    assert full.info["lp_fallback_parameters"] == []
    monkeypatch.setattr(lp, "ITERATIONS_FLOOR", 3)
    monkeypatch.setattr(lp, "ITERATIONS_PER_LINE", 0)
    with pytest.warns(ident.LPFallbackWarning, match="per-solve budget") as record:
        cut = uncertain_hull(Wc, D, y, 0.5, prior)
    info = cut.info
    assert info["lp_fallbacks"] >= 1 and info["lp_retries"] >= 1 and info["lp_limit_hits"] >= 2
    assert info["lp_fallback_parameters"] and set(info["lp_fallback_parameters"]) <= set("abcde")
    assert any(name in str(w.message) for w in record for name in info["lp_fallback_parameters"])
    assert np.all(cut.lower <= full.lower) and np.all(cut.upper >= full.upper) and cut.contains(theta).all()
    assert np.all(cut.lower >= prior.lower) and np.all(cut.upper <= prior.upper)


def test_signed_hull_sums_the_budget_counters_over_its_rounds(monkeypatch):
    Wc, D, y, theta = _op_problem(400, 4, seed=3)
    prior = ident.Box(-3 * np.ones(4), 3 * np.ones(4), names=("a", "b", "c", "d"))
    full = signed_uncertain_hull(Wc, D, y, 0.5, prior, refine=2)
    calls = []
    real = uncertain_signed.uncertain_hull_rows

    def spy(*args, **kwargs):
        box, warm = real(*args, **kwargs)
        calls.append(box.info)
        return box, warm

    monkeypatch.setattr(uncertain_signed, "uncertain_hull_rows", spy)
    monkeypatch.setattr(lp, "ITERATIONS_FLOOR", 4)
    monkeypatch.setattr(lp, "ITERATIONS_PER_LINE", 0)
    with pytest.warns(ident.LPFallbackWarning, match="per-solve budget"):
        cut = signed_uncertain_hull(Wc, D, y, 0.5, prior, refine=2)
    assert len(calls) == 3
    for key in ("lp_solves", "lp_iterations", "lp_limit_hits", "lp_retries", "lp_fallbacks"):
        assert cut.info[key] == sum(c[key] for c in calls)
    assert cut.info["lp_fallbacks"] >= 1
    assert set(cut.info["lp_fallback_parameters"]) == set().union(*(c["lp_fallback_parameters"] for c in calls))
    assert np.all(cut.lower <= full.lower) and np.all(cut.upper >= full.upper) and cut.contains(theta).all()
