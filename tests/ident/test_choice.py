"""The certified equation's processing chosen from the specification (:mod:`ident.processing.choice`).

Oracles: a naive loop for the relative row radius; a synthetic score function whose minimum is known; the H4's
certified equation evaluated directly at every candidate (the rule's score recomputed outside the rule)."""

import numpy as np
import pytest

from h4bench import sim
from h4bench.ident.processing.choice import (MIN_KERNEL_STEPS, candidate_lengths, choose_kernel, relative_radius,
                                             sample_starts)
from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.robots import h4_certified as hc


def test_candidate_lengths_grid():
    c = candidate_lengths(12001, 1e-3)
    assert c[0] == 40 and c[-1] <= 800 and all(b > a for a, b in zip(c, c[1:]))
    assert all(L % 2 == 0 for L in c)
    assert all(1.4 < b / a < 1.8 for a, b in zip(c, c[1:]))  # geometric, factor ~1.6
    short = candidate_lengths(1001, 1e-3, even=False)  # at most a tenth of the log
    assert max(short) <= 100 and min(short) >= MIN_KERNEL_STEPS
    assert candidate_lengths(101, 1e-3) == [MIN_KERNEL_STEPS]  # a short log keeps the shortest accepted kernel


def test_sample_starts_spread_inside_the_log():
    s = sample_starts(5000, 400, count=24, margin=3)
    assert s.size == 24 and s[0] == 3 and s[-1] == 5000 - 1 - 400 - 3
    assert np.all(np.diff(s) > 0)
    assert sample_starts(100, 400).size == 0


def test_relative_radius_against_a_loop():
    rng = np.random.default_rng(0)
    Wc, D = rng.normal(size=(30, 5)), rng.uniform(0, 0.1, (30, 5))
    b, t = rng.uniform(0.1, 1, 30), rng.uniform(-2, 2, 5)
    Wc[3] = 0.0
    got = relative_radius(Wc, D, b, t)
    for k in range(30):
        sig = sum(abs(Wc[k, j]) * abs(t[j]) for j in range(5))
        rad = b[k] + sum(D[k, j] * abs(t[j]) for j in range(5))
        assert got[k] == (np.inf if sig == 0 else pytest.approx(rad / sig, rel=1e-14))


def test_choose_kernel_takes_the_least_median_score_and_the_shorter_on_a_tie():
    calls = []

    def evaluate(L):  # relative radius (1 + (L - 90)^2 / 1e3) / 10 on every row: least at L = 90
        calls.append(L)
        rho = 1.0 + (L - 90) ** 2 / 1e3
        return np.ones((8, 2)), np.zeros((8, 2)), np.full(8, rho)

    ch = choose_kernel(evaluate, [40, 64, 90, 130, 200], np.ones(2))
    assert calls == [40, 64, 90, 130, 200]
    assert ch.steps == 90 and ch.scores[90] == pytest.approx(0.5)
    assert ch.to_dict()["scores"]["90"] == pytest.approx(0.5)
    tie = choose_kernel(lambda L: (np.ones((4, 1)), np.zeros((4, 1)), np.ones(4)), [60, 30], np.ones(1))
    assert tie.steps == 30
    with pytest.raises(ValueError, match="candidates must hold at least one"):
        choose_kernel(evaluate, [], np.ones(2))


@pytest.fixture(scope="module")
def h4_log():
    """A short H4 motion (sines within the workspace), quantised to 2^16 counts; torques are not read by the rule
    (zeros)."""
    geometry = sim.H4Geometry.from_model(sim.load_model())
    h = 1e-3
    t = np.arange(1201) * h
    q0 = sim.inverse_kinematics(geometry, np.array([0.0, 0.0, -0.55, 0.0]))
    q = q0 + 0.05 * np.sin(2 * np.pi * np.array([1.1, 1.7, 2.3, 1.3]) * t[:, None] + np.arange(4))
    res = 2 * np.pi / 2**16
    spec = ErrorSpec(n_joints=4, sample_period=h, position_resolution=res, torque_error=1.0, qd_max=3.0,
                     qdd_max=40.0)
    return geometry, np.round(q / res) * res, spec


def test_h4_chooses_the_rules_argmin_and_refuses_short_kernels(h4_log):
    geometry, q, spec = h4_log
    tau = np.zeros_like(q)
    eq = hc.certified_equation(geometry, q, tau, spec, hc.Processing(stride=10))
    ch = eq.info["kernel_choice"]
    scores = {int(k): v for k, v in ch["scores"].items()}
    assert eq.info["kernel_steps"] == ch["steps"] == min(scores, key=lambda k: (scores[k], k))
    # the score recomputed outside the rule, from the equation of the same sample of windows
    steps = hc.certified_steps(geometry, q, spec, hc.Processing())
    L = ch["steps"]
    from h4bench.ident.processing.weakform import RowWindows, make_kernel

    windows = RowWindows(start=sample_starts(q.shape[0], L), steps=L)
    rows = hc.certified_rows(steps, make_kernel(L, spec.sample_period), windows, tau)
    assert np.median(relative_radius(rows.Wc, rows.D, rows.bound, np.full(14, 2.0))) == pytest.approx(
        scores[L], rel=1e-9)
    # an explicit length wins and gives the rows of that kernel
    fixed = hc.certified_equation(geometry, q, tau, spec, hc.Processing(kernel_steps=50, stride=10))
    assert fixed.info["kernel_steps"] == 50 and "kernel_choice" not in fixed.info
    with pytest.raises(ValueError, match=r"kernel_steps must be an integer >= 10 .* got 7"):
        hc.certified_equation(geometry, q, tau, spec, hc.Processing(kernel_steps=7))
