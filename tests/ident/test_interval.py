"""Containment properties of ident.numerics.interval, checked against exact rational arithmetic (python-flint fmpq).

Every expected value is the exact real result of the same operation on the same floats, computed in
rationals; the computed interval must contain it. Hypothesis draws magnitudes from subnormal to 1e100
(products stay finite) and cancellation-prone mixes of scales.
"""

from __future__ import annotations

import numpy as np
import pytest
from flint import fmpq
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from h4bench.ident.numerics import interval as iv
from h4bench.ident.numerics.interval import Interval

FINITE = st.floats(min_value=-1e100, max_value=1e100, allow_nan=False, allow_infinity=False)
# mixes of scales make cancellation likely (1e16 + 1 - 1e16) and exercise the dot-product error bounds
SCALED = st.builds(lambda m, e: m * 10.0**e, st.floats(-1, 1, allow_nan=False), st.integers(-30, 30))
ANY = st.one_of(FINITE, SCALED, st.sampled_from([0.0, 5e-324, -5e-324, 2.0**-1022, 1.0, -1.0, 0.1, 1e16]))


def q(x: float) -> fmpq:
    """The exact rational value of a float."""
    return fmpq(*float(x).as_integer_ratio())


def qmat(a) -> list:
    a = np.atleast_2d(np.asarray(a, dtype=float))
    return [[q(v) for v in row] for row in a]


def qdot(row, col) -> fmpq:
    s = fmpq(0)
    for a, b in zip(row, col):
        s += a * b
    return s


def inside(lo: float, exact: fmpq, hi: float) -> bool:
    return q(lo) <= exact <= q(hi)


def interval_arrays(n: int):
    """Strategy for (lo, hi) float arrays of length n with lo <= hi."""
    return st.lists(st.tuples(ANY, ANY), min_size=n, max_size=n).map(
        lambda pairs: (np.array([min(a, b) for a, b in pairs]), np.array([max(a, b) for a, b in pairs]))
    )


# ------------------------------------------------------------------------------------------ up / down
@settings(deadline=None)  # no wall-clock deadline: the 2-core test machine is shared
@given(ANY)
def test_up_down_bracket_the_neighbouring_floats(x):
    assert iv.up(x) >= np.nextafter(x, np.inf) > x
    assert iv.down(x) <= np.nextafter(x, -np.inf) < x


# ----------------------------------------------------------------------------------------- elementwise
@settings(deadline=None)
@given(interval_arrays(4), interval_arrays(4))
def test_add_sub_mul_contain_every_corner_exactly(a, b):
    (alo, ahi), (blo, bhi) = a, b
    slo, shi = iv.add(alo, ahi, blo, bhi)
    dlo, dhi = iv.sub(alo, ahi, blo, bhi)
    mlo, mhi = iv.mul(alo, ahi, blo, bhi)
    for k in range(4):
        for x in (alo[k], ahi[k]):
            for y in (blo[k], bhi[k]):
                # sums and differences are monotone, products bilinear: the corners are the extremes
                assert inside(slo[k], q(x) + q(y), shi[k])
                assert inside(dlo[k], q(x) - q(y), dhi[k])
                assert inside(mlo[k], q(x) * q(y), mhi[k])


@settings(deadline=None)
@given(interval_arrays(3), interval_arrays(3))
def test_div_contains_every_corner_exactly(a, b):
    (alo, ahi), (blo, bhi) = a, b
    # make the divisor sign-definite (and not tiny, so quotients stay finite)
    blo, bhi = np.abs(blo) + 1e-3, np.abs(bhi) + 1e-3
    blo, bhi = np.minimum(blo, bhi), np.maximum(blo, bhi)
    lo, hi = iv.div(alo, ahi, blo, bhi)
    for k in range(3):
        for x in (alo[k], ahi[k]):
            for y in (blo[k], bhi[k]):
                assert inside(lo[k], q(x) / q(y), hi[k])


def test_div_by_an_interval_containing_zero_raises():
    with pytest.raises(ZeroDivisionError):
        iv.div(1.0, 2.0, -1.0, 1.0)


# ------------------------------------------------------------------------------------------ reductions
@settings(deadline=None)
@given(hnp.arrays(float, st.integers(1, 40), elements=ANY))
def test_sums_bracket_the_exact_sum(v):
    exact = fmpq(0)
    for x in v:
        exact += q(x)
    assert inside(iv.sum_down(v), exact, iv.sum_up(v))


def test_sum_bound_survives_catastrophic_cancellation():
    v = np.array([1e16, 1.0, -1e16, 1.0, 1e-300] * 7)
    exact = sum((q(x) for x in v), fmpq(0))
    assert inside(iv.sum_down(v), exact, iv.sum_up(v))


# -------------------------------------------------------------------------------------------- products
SHAPES = st.tuples(st.integers(1, 5), st.integers(1, 6), st.integers(1, 3))


@settings(max_examples=60, deadline=None)
@given(SHAPES, st.data())
def test_point_matmul_contains_the_exact_product(shape, data):
    m, n, k = shape
    A = data.draw(hnp.arrays(float, (m, n), elements=ANY))
    B = data.draw(hnp.arrays(float, (n, k), elements=ANY))
    lo, hi = iv.point_matmul(A, B)
    QA, QB = qmat(A), qmat(B)
    for i in range(m):
        for j in range(k):
            assert inside(lo[i, j], qdot(QA[i], [QB[t][j] for t in range(n)]), hi[i, j])


def exact_linear_range(QA_row, xlo, xhi):
    """Exact range of sum_j a_j x_j over the box: each term independently at its best endpoint."""
    lo = hi = fmpq(0)
    for a, l, h in zip(QA_row, xlo, xhi):
        p1, p2 = a * q(l), a * q(h)
        lo += min(p1, p2)
        hi += max(p1, p2)
    return lo, hi


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.data())
def test_point_matvec_contains_the_exact_range(m, n, data):
    A = data.draw(hnp.arrays(float, (m, n), elements=ANY))
    xlo, xhi = data.draw(interval_arrays(n))
    lo, hi = iv.point_matvec(A, xlo, xhi)
    QA = qmat(A)
    for i in range(m):
        elo, ehi = exact_linear_range(QA[i], xlo, xhi)
        assert q(lo[i]) <= elo and ehi <= q(hi[i])


def exact_interval_dot(alo, ahi, blo, bhi):
    """Exact range of sum_j a_j b_j over the boxes (terms independent; each term bilinear: corners)."""
    lo = hi = fmpq(0)
    for al, ah, bl, bh in zip(alo, ahi, blo, bhi):
        c = [q(x) * q(y) for x in (al, ah) for y in (bl, bh)]
        lo += min(c)
        hi += max(c)
    return lo, hi


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.integers(1, 5), st.integers(1, 3), st.data())
def test_interval_matmul_contains_the_exact_range(m, n, k, data):
    A = [data.draw(interval_arrays(n)) for _ in range(m)]
    B = [data.draw(interval_arrays(n)) for _ in range(k)]  # columns of B
    Alo = np.array([a[0] for a in A])
    Ahi = np.array([a[1] for a in A])
    Blo = np.array([b[0] for b in B]).T
    Bhi = np.array([b[1] for b in B]).T
    lo, hi = iv.matmul(Alo, Ahi, Blo, Bhi)
    for i in range(m):
        for j in range(k):
            elo, ehi = exact_interval_dot(Alo[i], Ahi[i], Blo[:, j], Bhi[:, j])
            assert q(lo[i, j]) <= elo and ehi <= q(hi[i, j])
    # the endpoint route used by the dense reference must contain the same exact ranges
    for j in range(k):
        dlo, dhi = iv.dot_rows(Alo, Ahi, Blo[:, j], Bhi[:, j])
        for i in range(m):
            elo, ehi = exact_interval_dot(Alo[i], Ahi[i], Blo[:, j], Bhi[:, j])
            assert q(dlo[i]) <= elo and ehi <= q(dhi[i])


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 60), st.integers(1, 4), st.data())
def test_gram_contains_exact_WtW_across_blocks(n, p, data):
    W = data.draw(hnp.arrays(float, (n, p), elements=SCALED))
    lo, hi = iv.gram(W, chunk=7)  # several blocks: the accumulation order differs from one BLAS call
    QW = qmat(W)
    for i in range(p):
        for j in range(p):
            exact = qdot([r[i] for r in QW], [r[j] for r in QW])
            assert inside(lo[i, j], exact, hi[i, j])


def test_products_are_tight_for_benign_data():
    """Outward rounding must not be wasteful: radii of a few ulps times the data scale."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((50, 14))
    x = rng.standard_normal(14)
    lo, hi = iv.point_matvec(A, x, x)
    assert np.all(hi - lo <= 1e-13 * (np.abs(A) @ np.abs(x)))
    lo, hi = iv.gram(A)
    assert np.all(hi - lo <= 1e-13 * (np.abs(A).T @ np.abs(A)))


# ------------------------------------------------------------------------------------------- wrapper
def test_interval_class_operators_match_the_functions():
    a = Interval([1.0, -2.0], [1.5, 3.0])
    b = Interval([0.5, 0.25], [2.0, 0.5])
    A = np.array([[1.0, 2.0], [3.0, -4.0]])
    assert np.array_equal((a + b).lo, iv.add(a.lo, a.hi, b.lo, b.hi)[0])
    assert np.array_equal((a * b).hi, iv.mul(a.lo, a.hi, b.lo, b.hi)[1])
    assert np.array_equal((A @ a).lo, iv.point_matvec(A, a.lo, a.hi)[0])
    assert (a - 1.0).contains(a.mid - 1.0).all()
    assert (2.0 - a).contains(2.0 - a.mid).all()
    assert a.intersect(Interval([2.0, 0.0], [3.0, 1.0])).is_empty()
    with pytest.raises(ValueError, match="lo must be <= hi"):
        Interval([1.0], [0.0])
    with pytest.raises(ValueError, match="finite"):
        Interval([np.nan], [0.0])
