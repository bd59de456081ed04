"""Bounded-error experiment design: half-width LPs against scipy's linprog, their envelope-theorem gradients
against finite differences, the width = slack x geometry sandwich against the exact hull (ident.estimate), the
processed regressor against a direct convolution, the design grid against the processed figure, the H4-class
envelope and the design cache."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import scipy.signal

from h4bench import ident
from h4bench import sim
from h4bench import trajectories as tj
import h4bench.trajectories.excitation as tx
from h4bench.ident.processing.filtering import ProcessingSettings
from tests.conftest import bounded_noise_problem
from h4bench.trajectories.bounded import HalfwidthProblem, halfwidths, smooth_max

PAPER_PROCESSING = dict(position_cutoff_hz=20.0, butter_order=4, decimation=10, numtaps=41, fir_cutoff=0.8,
                        speed_threshold=0.05)  # scenarios/spec.py DEFAULTS["processing"]


def test_halfwidths_equal_scipy_linprog():
    rng = np.random.default_rng(3)
    W = rng.standard_normal((80, 6))
    hw = halfwidths(W)
    for j in range(6):  # oracle: scipy's HiGHS wrapper on max delta_j s.t. -1 <= W delta <= 1
        c = np.zeros(6)
        c[j] = -1.0
        res = scipy.optimize.linprog(c, A_ub=np.vstack([W, -W]), b_ub=np.ones(160), bounds=[(None, None)] * 6)
        assert res.status == 0
        assert hw.h[j] == pytest.approx(-res.fun, rel=1e-8)
        assert np.all(np.abs(W @ hw.delta[j]) <= 1 + 1e-9)
    assert np.allclose(hw.duals @ W, -np.eye(6), atol=1e-8)  # dual feasibility: W^T y_j = -e_j


def test_halfwidth_gradient_matches_finite_differences():
    rng = np.random.default_rng(5)
    W = rng.standard_normal((60, 5))
    hw = halfwidths(W)
    eps = 1e-6
    for trial in range(4):
        V = rng.standard_normal(W.shape)
        fd = (halfwidths(W + eps * V).h - halfwidths(W - eps * V).h) / (2 * eps)
        for j in range(5):
            assert np.sum(hw.gradient_of(j) * V) == pytest.approx(fd[j], rel=1e-5, abs=1e-9), (trial, j)
        w = rng.uniform(0.5, 2.0, 5)
        assert np.sum(hw.gradient(w) * V) == pytest.approx(w @ fd, rel=1e-5)


def test_smooth_max_weights_are_its_derivative():
    rng = np.random.default_rng(1)
    h, t = rng.uniform(0.1, 2.0, 7), rng.uniform(0.5, 1.5, 7)
    F, w = smooth_max(h, t)
    assert np.log(h / t).max() <= F <= np.log(h / t).max() + np.log(7) / 8.0  # LSE bounds, beta = 8
    for j in range(7):
        d = np.zeros(7)
        d[j] = 1e-7
        assert w[j] == pytest.approx((smooth_max(h + d, t)[0] - smooth_max(h - d, t)[0]) / 2e-7, rel=1e-6)


def test_hull_widths_lie_between_the_slack_bounds():
    """width_j in [2 (b - rho) h_j, 2 (b + rho) h_j] with rho = max|e| (oracle: ident.estimate's exact hull)."""
    rng = np.random.default_rng(11)
    W, theta, y = bounded_noise_problem(rng, 400, 5)
    rho = float(np.abs(y - W @ theta).max())
    h = halfwidths(W).h
    for b in (1.0, 1.5, 3.0):
        box = ident.estimate(W, y, b, (np.full(5, -100.0), np.full(5, 100.0)))
        assert np.all(box.width >= 2 * (b - rho) * h * (1 - 1e-7))
        assert np.all(box.width <= 2 * (b + rho) * h * (1 + 1e-7))


@pytest.fixture(scope="module")
def h_design(geometry):
    """A 4 s bounded-error design under the H4-class envelope (few iterations: a fixture, not a benchmark)."""
    return tj.design_excitation(geometry, 4.0, seed=2, processing=PAPER_PROCESSING, cache=False, max_iter=15)


def test_processed_regressor_equals_a_direct_convolution(geometry, h_design):
    s = ProcessingSettings(**PAPER_PROCESSING)
    W, joint = tj.processed_regressor(geometry, h_design.q, h_design.qd, h_design.qdd, s)
    raw = ident.regressor(geometry, h_design.q, h_design.qd, h_design.qdd).reshape(-1, 4, 14)
    taps = s.taps()
    L = taps.size
    expect = []
    for k in range(0, raw.shape[0] - L + 1, s.decimation):  # window k .. k + L - 1, same joint
        for i in range(4):
            if np.all(np.abs(h_design.qd[k:k + L, i]) >= s.speed_threshold):
                expect.append(taps[::-1] @ raw[k:k + L, i])  # sum_l h_l x[k + L - 1 - l]
    expect = np.array(expect)
    assert W.shape == expect.shape and np.allclose(W, expect, rtol=1e-12, atol=1e-12)
    assert set(np.unique(joint)) <= {0, 1, 2, 3}


def test_design_grid_criterion_is_close_to_the_processed_one(geometry):
    """The optimiser's grid (raw rows, 12 samples per period of the top harmonic) predicts the 100 Hz processed
    h_j of a 10 s H4-class start within 25 % (oracle: tj.design_criterion on the full 1 kHz reference)."""
    from h4bench.trajectories.fourier import PhaseSchedule, fourier_basis  # noqa: PLC0415

    traj = tj.fourier_excitation(geometry, 10.0, seed=0, optimise=False, limits=tj.Limits.h4_class(), harmonics=4,
                                 base_hz=0.75, criterion="h", processing=PAPER_PROCESSING)
    p = traj.parameters
    crit = tj.design_criterion(geometry, traj, ProcessingSettings(**PAPER_PROCESSING))
    sched = PhaseSchedule(np.asarray(p["schedule_knots"]), np.asarray(p["schedule_levels"]))
    phi, phid, phidd = sched(np.linspace(0, p["duration"], p["grid_points"]))
    scale = np.array([0.05, 0.05, 0.06, 0.25])
    prob = HalfwidthProblem(geometry, "cartesian", np.asarray(p["centre"]), fourier_basis(p["harmonics"], phi), phid,
                            phidd, scale, tj.Limits.h4_class(), tj.nominal_parameters(), 0.95,
                            targets=tj.nominal_parameters(), speed_threshold=0.05, half_window_s=0.02)
    z = np.stack([np.asarray(p["a"]), np.asarray(p["b"])]).ravel() / np.tile(scale, 2 * p["harmonics"])
    assert np.isfinite(prob.criterion(z))
    ratio = prob.last.h / np.asarray(crit["h"])
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio


def test_h_design_improves_its_start_on_the_processed_regressor(geometry, h_design):
    s = ProcessingSettings(**PAPER_PROCESSING)
    start = tj.fourier_excitation(geometry, 4.0, seed=2, optimise=False, limits=tj.Limits.h4_class(),
                                  harmonics=4, base_hz=0.75)
    before, after = tj.design_criterion(geometry, start, s), tj.design_criterion(geometry, h_design, s)
    assert after["smooth_max"] < before["smooth_max"]
    assert h_design.checks["feasible"] and h_design.parameters["criterion"] == "h"


def test_h4_class_limits_and_the_nacelle_checks(geometry, h_design):
    lim = tj.Limits.h4_class()
    assert (lim.qd_max, lim.qdd_max, lim.xd_max, lim.xdd_max) == ((30.0,) * 4, (2000.0,) * 4, 5.5, 165.0)
    assert lim.tau_allowed.tolist() == [12.0] * 4  # 0.8 x 15 N m (models/h4.xml ctrlrange)
    assert tj.Limits.from_dict(tj.Limits().to_dict()) == tj.Limits()
    # oracle for the nacelle speed: sim.cartesian_motion (xd = J qd)
    _, xd, xdd = sim.cartesian_motion(geometry, h_design.q, h_design.qd, h_design.qdd, x=h_design.x)
    speed = np.linalg.norm(xd[:, :3], axis=1)
    assert h_design.checks["peak_nacelle_speed"] == pytest.approx(speed.max(), rel=1e-9)
    assert h_design.checks["peak_nacelle_acceleration"] == pytest.approx(np.linalg.norm(xdd[:, :3], axis=1).max(),
                                                                          rel=1e-9)
    cap = 0.5 * speed.max()
    with pytest.raises(tj.InfeasibleTrajectoryError) as info:
        tj.check_trajectory(geometry, h_design, tj.Limits.h4_class(xd_max=cap))
    k = int(np.flatnonzero(speed > cap)[0])
    assert info.value.check == "nacelle_speed" and info.value.index == k and "nacelle translational speed" in str(
        info.value)
    with pytest.raises(ValueError, match="xd_max"):
        tj.Limits(xd_max=-1.0)


def test_design_excitation_cache(geometry, tmp_path, monkeypatch):
    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path))
    kw = dict(processing=PAPER_PROCESSING, max_iter=2)
    first = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    files = list((tmp_path / "trajectories").glob("*.npz"))
    assert len(files) == 1 and tj.cache_dir() == tmp_path / "trajectories"
    calls = []
    real = tx.fourier_excitation
    monkeypatch.setattr(tx, "fourier_excitation", lambda *a, **k: calls.append(1) or real(*a, **k))
    again = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert calls == [] and again.equals(first)  # served from the cache
    tj.design_excitation(geometry, 3.0, seed=5, **kw)  # another seed: another entry
    assert calls == [1] and len(list((tmp_path / "trajectories").glob("*.npz"))) == 2
    files[0].write_bytes(b"not a trajectory")  # corrupt entry: recomputed, never trusted
    fixed = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert calls == [1, 1]
    assert all(np.array_equal(getattr(fixed, n), getattr(first, n)) for n in ("t", "x", "q", "qd", "qdd"))
    # an entry whose stored inputs do not match its key is recomputed too
    bad = tj.Trajectory(t=first.t, x=first.x, q=first.q, qd=first.qd, qdd=first.qdd, kind=first.kind,
                        parameters=dict(first.parameters, cache={"key": "x", "inputs": {}}), checks=first.checks)
    bad.save(files[0])
    tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert calls == [1, 1, 1]
    tj.design_excitation(geometry, 3.0, seed=4, cache=False, **kw)
    assert calls == [1, 1, 1, 1]


def test_an_unwritable_cache_never_costs_the_design(geometry, tmp_path, monkeypatch):
    """H4BENCH_CACHE naming a file (NotADirectoryError) or a read-only folder: the design is returned, same as
    uncached, with a CacheWarning naming the folder."""
    kw = dict(processing=PAPER_PROCESSING, max_iter=2)
    reference = tj.design_excitation(geometry, 3.0, seed=4, cache=False, **kw)
    (tmp_path / "a-file").write_text("not a folder")
    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path / "a-file"))
    with pytest.warns(tx.CacheWarning, match="a-file/trajectories.*cannot be written"):
        got = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert all(np.array_equal(getattr(got, n), getattr(reference, n)) for n in ("t", "x", "q", "qd", "qdd"))
    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path / "ro"))
    real_save = tj.Trajectory.save

    def refuse(self, path):  # a read-only folder (root ignores permission bits, so the refusal is simulated)
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(tj.Trajectory, "save", refuse)
    with pytest.warns(tx.CacheWarning, match="ro/trajectories.*Permission denied"):
        got = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert got.equals(reference) or np.array_equal(got.q, reference.q)
    monkeypatch.setattr(tj.Trajectory, "save", real_save)


def test_design_excitation_rejects_bad_arguments(geometry):
    with pytest.raises(ValueError, match="criterion"):
        tj.design_excitation(geometry, 3.0, criterion="volume")
    with pytest.raises(TypeError, match="geometry"):
        tj.design_excitation("h4", 3.0)
    with pytest.raises(ValueError, match="targets"):
        tj.design_excitation(geometry, 3.0, targets=np.ones(3), cache=False)
    with pytest.raises(ValueError, match="processing"):
        tj.design_excitation(geometry, 3.0, processing={"bogus": 1}, cache=False)


def test_design_gradient_matches_finite_differences_of_the_criterion(geometry):
    """The chain rule through the grid (envelope theorem on the LPs, dW/dz from per-sample differences) against
    central differences of the criterion itself along random directions of the coefficients."""
    from h4bench.trajectories.fourier import PhaseSchedule, fourier_basis  # noqa: PLC0415

    sched = PhaseSchedule.slow_fast(4.0, 0.3, 0.2, 0.5, 0.5, 1.0)
    phi, phid, phidd = sched(np.linspace(0, 4.0, 150))
    scale = np.array([0.05, 0.05, 0.06, 0.25])
    prob = HalfwidthProblem(geometry, "cartesian", np.asarray(geometry.x_home, float), fourier_basis(3, phi), phid,
                            phidd, scale, tj.Limits.h4_class(), tj.nominal_parameters(), 0.95,
                            targets=tj.nominal_parameters(), speed_threshold=0.05, half_window_s=0.02)
    rng = np.random.default_rng(8)
    z0 = rng.standard_normal(prob.size)
    z = 0.9 * prob.largest_feasible_scale(z0) * z0  # inside the limits, away from the workspace edges
    F, _, grad, _ = prob.evaluate(z, gradient=True)
    assert np.isfinite(F)
    eps = 1e-5
    for _ in range(3):
        v = rng.standard_normal(prob.size)
        v /= np.linalg.norm(v)
        fd = (prob.criterion(z + eps * v) - prob.criterion(z - eps * v)) / (2 * eps)
        assert grad @ v == pytest.approx(fd, rel=1e-4)  # measured: agreement to ~1e-7


def test_h_design_draws_another_start_when_the_first_keeps_too_few_rows(geometry, monkeypatch):
    """An infinite criterion at the start (too few rows above the speed threshold) would stop the optimiser at
    once: the design draws another start from the same seed's generator, and says how many it drew."""
    from h4bench.trajectories.bounded import HalfwidthProblem

    kwargs = dict(seed=3, optimise=False, limits=tj.Limits.h4_class(), criterion="h", harmonics=4, base_hz=0.75,
                  processing=PAPER_PROCESSING)
    plain = tj.fourier_excitation(geometry, 4.0, **kwargs)
    assert plain.parameters["optimisation"]["start_draws"] == 1
    calls = {"n": 0}
    original = HalfwidthProblem.log_cond

    def first_start_infinite(self, z):
        calls["n"] += 1
        return np.inf if calls["n"] == 1 else original(self, z)

    monkeypatch.setattr(HalfwidthProblem, "log_cond", first_start_infinite)
    redrawn = tj.fourier_excitation(geometry, 4.0, **kwargs)
    assert redrawn.parameters["optimisation"]["start_draws"] == 2
    assert redrawn.checks["feasible"] and not np.allclose(redrawn.q, plain.q)
    monkeypatch.setattr(HalfwidthProblem, "log_cond", lambda self, z: np.inf)
    with pytest.raises(tj.InfeasibleTrajectoryError, match="seed 3.*finite 'h' criterion in 8 draws.*speed_threshold"):
        tj.fourier_excitation(geometry, 4.0, **kwargs)
