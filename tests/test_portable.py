"""h4bench.portable against numpy's LAPACK/BLAS (oracle: np.linalg and ``@`` to a stated tolerance), and the
properties that make it portable: a batch gives each member's own bits, and no BLAS is needed."""

import numpy as np
import pytest

from h4bench import portable


@pytest.fixture(scope="module")
def rng():
    return np.random.default_rng(11)


def test_matmul_follows_the_rules_of_the_at_operator(rng):
    a, b, v = rng.standard_normal((5, 3, 4)), rng.standard_normal((5, 4, 2)), rng.standard_normal(4)
    for x, y in ((a, b), (a, v), (v, b), (v, v), (a[0], b[0])):
        assert portable.matmul(x, y).shape == np.shape(x @ y)
        np.testing.assert_allclose(portable.matmul(x, y), x @ y, rtol=1e-13, atol=1e-14)


def test_solve4_and_det4_match_lapack_and_a_batch_gives_each_members_bits(rng):
    a = rng.standard_normal((200, 4, 4)) + 3 * np.eye(4)  # well conditioned: cond < ~50
    b = rng.standard_normal((200, 4, 3))
    x = portable.solve4(a, b)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(portable.det4(a), np.linalg.det(a), rtol=1e-12)
    assert np.array_equal(portable.solve4(a[7], b[7]), x[7])  # no dependence on the batch (no blocking)
    np.testing.assert_allclose(portable.solve4(a, b[..., 0]), x[..., 0], rtol=1e-15)  # vector right-hand sides
    with np.errstate(all="ignore"):
        assert not np.all(np.isfinite(portable.solve4(np.ones((4, 4)), np.ones(4))))  # singular: no exception


def test_jacobi_svd_matches_lapacks_singular_values_and_vectors(rng):
    a = rng.standard_normal((60, 7)) * np.logspace(-4, 2, 7)  # columns of very different sizes
    s, v = portable.jacobi_svd(a, vectors=True)
    ref = np.linalg.svd(a, compute_uv=False)
    np.testing.assert_allclose(s, ref, rtol=1e-12, atol=1e-15 * 100 * ref[0])  # a backward-stable SVD: ~eps s_max
    np.testing.assert_allclose(a.T @ a @ v, v * s**2, rtol=1e-9, atol=1e-9 * s[0] ** 2)
    np.testing.assert_allclose(v.T @ v, np.eye(7), atol=1e-13)
    batch = rng.standard_normal((50, 4, 4))
    np.testing.assert_allclose(portable.cond(batch), np.linalg.cond(batch), rtol=1e-10)
    assert np.array_equal(portable.jacobi_svd(batch[3]), portable.jacobi_svd(batch)[3])
    # the disjoint pairs rotated together (waves): LAPACK's values and vectors too, a batch member's own bits
    s_w, v_w = portable.jacobi_svd(a, vectors=True, waves=True)
    np.testing.assert_allclose(s_w, ref, rtol=1e-12, atol=1e-15 * 100 * ref[0])
    np.testing.assert_allclose(a.T @ a @ v_w, v_w * s_w**2, rtol=1e-9, atol=1e-9 * s_w[0] ** 2)
    np.testing.assert_allclose(v_w.T @ v_w, np.eye(7), atol=1e-13)
    wide = rng.standard_normal((3, 80, 69)) * np.logspace(-3, 3, 69)
    got = portable.jacobi_svd(wide, waves=True)
    np.testing.assert_allclose(got, np.linalg.svd(wide, compute_uv=False), rtol=1e-10)
    assert np.array_equal(portable.jacobi_svd(wide[1], waves=True), got[1])
    assert portable.cond(np.array([[1.0, 2.0], [2.0, 4.0]])) == np.inf or portable.cond(
        np.array([[1.0, 2.0], [2.0, 4.0]])) > 1e15


def test_lstsq_is_numpys_minimum_norm_solution_with_the_same_cutoff(rng):
    a = rng.standard_normal((40, 6))
    b = rng.standard_normal(40)
    np.testing.assert_allclose(portable.lstsq(a, b), np.linalg.lstsq(a, b, rcond=None)[0], rtol=1e-11)
    deficient = np.column_stack([a[:, :5], a[:, 0] + a[:, 1]])  # rank 5: the minimum-norm solution
    np.testing.assert_allclose(portable.lstsq(deficient, b, rcond=1e-12),
                               np.linalg.lstsq(deficient, b, rcond=1e-12)[0], rtol=1e-9, atol=1e-12)


def test_lstsq_takes_several_right_hand_sides(rng):
    a, b = rng.standard_normal((50, 7)), rng.standard_normal((50, 3))
    x = portable.lstsq(a, b)
    np.testing.assert_allclose(x, np.linalg.lstsq(a, b, rcond=None)[0], rtol=1e-11)
    assert np.array_equal(x[:, 1], portable.lstsq(a, b[:, 1]))  # or each column alone: the same bits


def test_qr_pivoted_is_lapacks_column_order_and_breaks_ties_by_the_columns_order(rng):
    import scipy.linalg

    a = rng.standard_normal((300, 40)) * np.logspace(-2, 2, 40)  # distinct norms at every step
    d, piv = portable.qr_pivoted(a)
    _, R, piv_lapack = scipy.linalg.qr(a, mode="economic", pivoting=True)
    np.testing.assert_array_equal(piv, piv_lapack)
    np.testing.assert_allclose(d, np.abs(np.diag(R)), rtol=1e-12)
    # equal columns (3 and 7; 0 scaled by -1 as 8): the first of them in a's order goes first, the others to the
    # null part, whatever the rounding of their norms
    b = np.column_stack([a[:, :5], a[:, 0] * 0.5, a[:, 1] + a[:, 2], a[:, 3], -a[:, 0]])
    d, piv = portable.qr_pivoted(b)
    assert piv.tolist().index(3) < piv.tolist().index(7) and piv.tolist().index(0) < piv.tolist().index(8)
    assert np.all(d[5:] < 1e-12 * d[0]) and np.all(d[:5] > 1e-3 * d[0])
    assert not {7, 8} & set(piv[:5].tolist())  # the later copies are the dependent ones
    with pytest.raises(ValueError, match="rows"):
        portable.qr_pivoted(np.ones((2, 3)))


def test_the_design_iterates_are_snapped_to_a_binary_grid():
    from h4bench.trajectories.design import SNAP, snap

    z = np.array([0.1, -0.3333333333, 1.0 + 1e-12, 2.0**-30])
    s = snap(z)
    assert np.array_equal(snap(s), s) and np.all(np.abs(s - z) <= SNAP / 2)
    assert np.array_equal(s / SNAP, np.round(s / SNAP))  # exact multiples of the grid
