"""h4bench.ident.wls against numpy.linalg.lstsq on the weighted system, and %sigma on cases worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident import PARAMETER_NAMES


def stacked_problem(seed=0, n_samples=500, p=14, sigmas=(0.1, 0.5, 1.0, 2.0)):
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((4 * n_samples, p))
    theta = rng.uniform(0.5, 2.0, p)
    noise = rng.standard_normal(4 * n_samples) * np.tile(sigmas, n_samples)  # row 4k + i is joint i
    return W, W @ theta + noise, theta


def test_wls_matches_lstsq_on_the_independently_weighted_system():
    W, y, theta = stacked_problem()
    res = ident.wls(W, y, joints=4)
    # oracle: weights from each joint's own OLS, then numpy.linalg.lstsq on the weighted system
    sig = []
    for j in range(4):
        th_j = np.linalg.lstsq(W[j::4], y[j::4], rcond=None)[0]
        e = y[j::4] - W[j::4] @ th_j
        sig.append(np.sqrt(e @ e / (W[j::4].shape[0] - W.shape[1])))
    w = np.tile(1.0 / np.array(sig), W.shape[0] // 4)
    Wt, Yt = W * w[:, None], y * w
    th, ss, _, _ = np.linalg.lstsq(Wt, Yt, rcond=None)
    s2 = ss[0] / (W.shape[0] - W.shape[1])
    std = np.sqrt(np.diag(s2 * np.linalg.inv(Wt.T @ Wt)))
    np.testing.assert_allclose(res.joint_sigma, sig, rtol=1e-12)
    np.testing.assert_allclose(res.theta, th, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(res.std, std, rtol=1e-8)
    np.testing.assert_allclose(res.rel_std_percent, 100 * std / np.abs(th), rtol=1e-8)
    assert res.names == tuple(f"theta{j + 1}" for j in range(14)) and res.dof == W.shape[0] - 14  # generic names
    assert ident.wls(W, y, joints=4, names=PARAMETER_NAMES).names == PARAMETER_NAMES
    # statistical sanity: the per-joint sigmas recover the simulated noise levels
    np.testing.assert_allclose(res.joint_sigma, (0.1, 0.5, 1.0, 2.0), rtol=0.1)


def test_rel_std_by_hand_single_joint_mean():
    """W = 1, y = (1, 2, 3, 4): theta = 2.5, residuals (-1.5, -0.5, 0.5, 1.5), SS = 5, s2 = 5/3 on the
    unweighted rows; the weighted system has s2 = 1 and C = sigma^2 / 4 = 5/12, so std = sqrt(5/12) =
    0.645497..., %sigma = 100 * 0.645497 / 2.5 = 25.8199 %, sigma_joint = sqrt(5/3) = 1.290994."""
    res = ident.wls(np.ones((4, 1)), np.array([1.0, 2.0, 3.0, 4.0]), joints=1)
    assert res.theta[0] == pytest.approx(2.5, rel=1e-14)
    assert res.joint_sigma[0] == pytest.approx(np.sqrt(5 / 3), rel=1e-14)
    assert res.s2 == pytest.approx(1.0, rel=1e-14)
    assert res.std[0] == pytest.approx(np.sqrt(5 / 12), rel=1e-14)
    assert res.rel_std_percent[0] == pytest.approx(25.819888974716115, rel=1e-13)


def test_rel_std_by_hand_two_joints_with_rank_deficient_subsystems():
    """Two joints, three samples, W rows (1, 0) for joint 0 and (0, 1) for joint 1.

    Joint 0: y = 1, 2, 3 -> own OLS theta1 = 2, SS = 2, rank 1, dof 2 -> sigma0^2 = 1.
    Joint 1: y = 10, 10, 13 -> theta2 = 11, SS = 6, dof 2 -> sigma1^2 = 3.
    Weighted: theta = (2, 11); SS = 2/1 + 6/3 = 4, r - c = 6 - 2 = 4 -> s2 = 1;
    W^T W = diag(3/1, 3/3) -> C = diag(1/3, 1); std = (0.57735, 1); %sigma = (28.8675, 9.0909).
    """
    W = np.tile([[1.0, 0.0], [0.0, 1.0]], (3, 1))
    y = np.array([1.0, 10.0, 2.0, 10.0, 3.0, 13.0])
    res = ident.wls(W, y, joints=2)
    np.testing.assert_allclose(res.joint_sigma, [1.0, np.sqrt(3.0)], rtol=1e-14)
    np.testing.assert_allclose(res.theta, [2.0, 11.0], rtol=1e-14)
    assert res.s2 == pytest.approx(1.0, rel=1e-13)
    np.testing.assert_allclose(res.std, [np.sqrt(1 / 3), 1.0], rtol=1e-13)
    np.testing.assert_allclose(res.rel_std_percent, [100 * np.sqrt(1 / 3) / 2, 100 / 11], rtol=1e-13)
    assert res.names == ("theta1", "theta2")


def test_rank_deficient_regressor_names_the_undetermined_parameters():
    W, y, _ = stacked_problem(n_samples=100)
    W[:, 7] = W[:, 2]  # Fv2 and Imot3 enter the data only through their sum
    W[:, 12] = 0.0  # Fs3 never excited
    with pytest.raises(ident.UnidentifiableError) as err:
        ident.wls(W, y, names=PARAMETER_NAMES)
    assert set(err.value.names) == {"Imot3", "Fv2", "Fs3"}
    assert "Fs3" in str(err.value) and isinstance(err.value, ValueError)


def test_ill_conditioned_parameters_are_flagged_not_nan():
    W, y, _ = stacked_problem(n_samples=200)
    rng = np.random.default_rng(1)
    W[:, 5] = W[:, 4] + 1e-11 * rng.standard_normal(W.shape[0])  # numerically almost collinear
    res = ident.wls(W, y, names=PARAMETER_NAMES)
    assert np.all(np.isfinite(res.theta)) and np.all(np.isfinite(res.std))
    assert set(res.poorly_identified) == {"Mnac", "Ibc"}


@pytest.mark.parametrize(
    "W, y, joints, exc, match",
    [
        (np.ones((10, 2)), np.ones(10), 4, ValueError, "multiple of joints=4"),
        (np.ones((8, 2)), np.ones(8), 0, ValueError, "multiple of joints=0"),
        (np.ones((8, 2)), np.ones(8), 2.0, TypeError, "joints must be an int"),
        (np.ones((8, 2)), np.ones(7), 4, ValueError, r"y must have shape \(m,\) = \(8,\)"),
        (np.ones((3, 14)), np.ones(3), 1, ValueError, r"W must have shape \(m, p\) with m > p for a variance estimate, got \(3, 14\)"),
        (np.full((8, 2), np.nan), np.ones(8), 4, ValueError, "W must be finite, got 16 NaN"),
    ],
)
def test_bad_input_is_rejected_with_a_message_naming_the_argument(W, y, joints, exc, match):
    with pytest.raises(exc, match=match):
        ident.wls(W, y, joints=joints)


def test_noise_free_joint_has_no_weight():
    W = np.random.default_rng(0).standard_normal((40, 2))
    with pytest.raises(ValueError, match="joint 1: the OLS residual"):
        ident.wls(W, W @ np.array([1.0, 2.0]), joints=4)


def test_joint_of_row_matches_the_stacked_layout_and_allows_dropped_rows():
    """Rows labelled by joint give the same estimate as the 4k + i stacking; dropping rows is then allowed
    and equals the stacked fit on the rows kept (oracle: the same computation with explicit weights)."""
    rng = np.random.default_rng(9)
    W = rng.normal(size=(400, 6))
    y = W @ rng.uniform(0.5, 2.0, 6) + rng.normal(scale=0.1, size=400) * np.tile([1.0, 2.0, 0.5, 1.5], 100)
    labels = np.tile(np.arange(4), 100)
    a = ident.wls(W, y, joints=4)
    b = ident.wls(W, y, joints=4, joint_of_row=labels)
    np.testing.assert_allclose(a.theta, b.theta, rtol=1e-12)
    keep = rng.random(400) > 0.1
    c = ident.wls(W[keep], y[keep], joints=4, joint_of_row=labels[keep])
    sig = np.array([np.sqrt(np.sum((y[keep][labels[keep] == j] - W[keep][labels[keep] == j]
                                    @ np.linalg.lstsq(W[keep][labels[keep] == j], y[keep][labels[keep] == j],
                                                      rcond=None)[0]) ** 2) / (np.sum(labels[keep] == j) - 6))
                    for j in range(4)])
    w = 1.0 / sig[labels[keep]]
    ref = np.linalg.lstsq(W[keep] * w[:, None], y[keep] * w, rcond=None)[0]
    np.testing.assert_allclose(c.theta, ref, rtol=1e-10)
    with pytest.raises(ValueError, match="joint_of_row must be"):
        ident.wls(W, y, joints=4, joint_of_row=labels[:-1])
