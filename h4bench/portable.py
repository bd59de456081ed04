"""Small linear algebra whose results are the same bits on any CPU and BLAS thread count (numpy only).

OpenBLAS picks its kernel by CPU (``OPENBLAS_CORETYPE`` forces one) and splits products over threads; the
kernels differ in the order of their sums and in fused multiply-adds, so ``@``, ``np.dot``, ``np.linalg.solve``,
``eigh``, ``svd``, ``qr`` and ``cond`` give results that differ in their last bits from one machine to another.
Where such a result chooses something (an optimiser's step, a feasibility decision, a hashed trajectory), the
computation here replaces it: element-wise IEEE operations (+, -, *, /, sqrt: correctly rounded everywhere)
and ``np.einsum`` without ``optimize`` (numpy's own loops, never BLAS), in an order fixed by the code.

- :func:`matmul`: ``A @ B`` over the last two axes (batched);
- :func:`det4`, :func:`solve4`: determinant and solution of 4 x 4 systems by cofactors (batched);
- :func:`jacobi_svd`: singular values (and right singular vectors) by one-sided Jacobi rotations (batched),
  :func:`cond`: the 2-norm condition number from them, :func:`lstsq`: the minimum-norm least-squares solution
  with a relative cut-off (``np.linalg.lstsq``'s ``rcond``), :func:`qr_pivoted`: the column order and R's diagonal
  of a Householder QR with column pivoting (ties broken by the column order, not by rounding);
- :func:`atan2`, :func:`arccos`, :func:`arcsin`, :func:`exp`, :func:`log`, :func:`tanh`, :func:`nearest_power_of_two`: numpy's
  transcendental ufuncs (``np.arccos``, ``np.exp``, ``np.log``, ``np.tanh``, ``np.log2``, sometimes
  ``np.arctan2``) run SIMD code chosen at run time by CPU (AVX2, AVX-512: ``np.show_runtime()``), whose last bits
  differ from one CPU to another (measured: ``NPY_DISABLE_CPU_FEATURES`` changed the trajectory design); these
  evaluate fixed polynomials and rational functions by the correctly rounded operations, within a few units in
  the last place of the true values;
- :func:`smallest`, :func:`largest`: the indices of the k smallest or largest values, ties by index
  (``np.argpartition`` and the default ``np.argsort`` run CPU-specific SIMD code that orders ties differently).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PIVOT_TIE", "arccos", "arcsin", "atan2", "cond", "det4", "exp", "jacobi_svd", "largest", "log", "lstsq",
           "matmul", "nearest_power_of_two", "qr_pivoted", "smallest", "solve4", "tanh"]


def matmul(a, b) -> np.ndarray:
    """``a @ b`` (..., m, k) x (..., k, n) -> (..., m, n), with ``@``'s rules for a vector operand ((k,) on the
    left or the right), by ``np.einsum`` (no BLAS: the same bits on any CPU; each sum in the order of k, so
    the usual ``gamma_k |a| |b|`` bound of its rounding error holds)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim == 1 and b.ndim == 1:
        return np.einsum("j,j->", a, b)
    if a.ndim == 1:
        return np.einsum("j,...jk->...k", a, b)
    if b.ndim == 1:
        return np.einsum("...ij,j->...i", a, b)
    return np.einsum("...ij,...jk->...ik", a, b)


def _minors(a):
    """The twelve 2 x 2 minors of the row pairs (0, 1) and (2, 3) of 4 x 4 matrices a (..., 4, 4)."""
    s = [a[..., 0, i] * a[..., 1, j] - a[..., 1, i] * a[..., 0, j] for i, j in _PAIRS]
    c = [a[..., 2, i] * a[..., 3, j] - a[..., 3, i] * a[..., 2, j] for i, j in _PAIRS]
    return s, c


_PAIRS = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))


def _det(s, c):
    return s[0] * c[5] - s[1] * c[4] + s[2] * c[3] + s[3] * c[2] - s[4] * c[1] + s[5] * c[0]


def det4(a) -> np.ndarray:
    """Determinants (...,) of 4 x 4 matrices a (..., 4, 4) (Laplace expansion on the 2 x 2 minors)."""
    return _det(*_minors(np.asarray(a, float)))


# The adjugate by Laplace expansion on the 2 x 2 minors: entry (i, j) is (-1)^(i + j) times
# a[r, k0] M[n0] - a[r, k1] M[n1] + a[r, k2] M[n2], with r = _ADJ_ROWS[j], M the minors of the row pair that does not
# hold r (the bottom pair c for r in {0, 1}, the top pair s for r in {2, 3}), (k0, k1, k2) the columns other than i
# and (n0, n1, n2) the minors on the columns other than i and each k.
_ADJ_ROWS = (1, 0, 3, 2)
_ADJ_COLS = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))
_ADJ_MINORS = ((5, 4, 3), (5, 2, 1), (4, 2, 0), (3, 1, 0))


def solve4(a, b) -> np.ndarray:
    """x with ``a x = b`` for 4 x 4 matrices a (..., 4, 4) and right-hand sides b (..., 4, k) or (..., 4):
    the adjugate over the determinant (a singular a gives inf or nan, never an exception)."""
    a = np.asarray(a, float)
    s, c = _minors(a)
    det = _det(s, c)
    adj = np.empty(a.shape)
    for i, ((k0, k1, k2), (n0, n1, n2)) in enumerate(zip(_ADJ_COLS, _ADJ_MINORS)):
        for j, r in enumerate(_ADJ_ROWS):
            M = c if r < 2 else s
            t = a[..., r, k0] * M[n0] - a[..., r, k1] * M[n1] + a[..., r, k2] * M[n2]
            adj[..., i, j] = t if (i + j) % 2 == 0 else -t  # negation is exact: the same bits as -x + y - z
    b = np.asarray(b, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        if b.ndim == a.ndim - 1:
            return np.einsum("...ij,...j->...i", adj, b) / det[..., None]
        return np.einsum("...ij,...jk->...ik", adj, b) / det[..., None, None]


#: Sweeps of :func:`jacobi_svd` at most (each rotates every column pair once; quadratic convergence: 6-10 suffice).
MAX_SWEEPS = 30


def _rotation(up, uq, tol):
    """The Jacobi rotation of the column pairs (up, uq) (..., m): (rot, cs, sn), rot False where the pair is
    already orthogonal to ``tol`` relative (there cs = 1, sn = 0; both None when no pair rotates)."""
    alpha = np.einsum("...i,...i->...", up, up)
    beta = np.einsum("...i,...i->...", uq, uq)
    gamma = np.einsum("...i,...i->...", up, uq)
    rot = np.abs(gamma) > tol * np.sqrt(alpha * beta)
    if not np.any(rot):
        return rot, None, None
    g = np.where(rot, gamma, 1.0)
    zeta = (beta - alpha) / (2.0 * g)
    with np.errstate(over="ignore"):  # |zeta| > 1e154: t = 0 (its limit, ~1/(2 |zeta|), is below 1e-154)
        t = np.where(zeta >= 0, 1.0, -1.0) / (np.abs(zeta) + np.sqrt(1.0 + zeta * zeta))
    cs = np.where(rot, 1.0 / np.sqrt(1.0 + t * t), 1.0)
    return rot, cs, np.where(rot, cs * t, 0.0)


def _waves(n: int) -> list:
    """The cyclic order of the column pairs, (0, 1), (0, 2), ..., (0, n - 1), (1, 2), ..., grouped into waves:
    each pair goes one wave after the last earlier pair that shares a column with it, so a wave's pairs are
    disjoint (their rotations touch different columns) and every pair still follows each earlier pair it
    depends on: about 2 n waves instead of n (n - 1) / 2 steps."""
    last = [-1] * n
    waves: list = []
    for p in range(n - 1):
        for q in range(p + 1, n):
            w = max(last[p], last[q]) + 1
            last[p] = last[q] = w
            if w == len(waves):
                waves.append(([], []))
            waves[w][0].append(p)
            waves[w][1].append(q)
    return [(np.array(P), np.array(Q)) for P, Q in waves]


def jacobi_svd(a, vectors: bool = False, waves: bool = False):
    """Singular values (..., n) in descending order of a (..., m, n), m >= n, by one-sided (Hestenes) Jacobi
    rotations of the columns in a fixed cyclic order until every pair is orthogonal to ``n eps`` relative
    (at most :data:`MAX_SWEEPS` sweeps); with ``vectors``, also the right singular vectors V (..., n, n),
    column j for value j (``a^T a V = V diag(s^2)``). Same bits on any CPU (module docstring).

    waves : rotate the disjoint pairs of the cyclic order together (:func:`_waves`), about n / 4 times fewer
    array steps (10x faster at n = 69). The same rotations in the same dependency order, but their dot
    products run over gathered (contiguous) columns, which numpy sums in another order than the strided ones of
    the default: other last bits (the trajectory design keeps the default, its cached designs with it)."""
    u = np.array(np.swapaxes(np.asarray(a, float), -1, -2), copy=True)  # (..., n, m): column j is row j
    n = u.shape[-2]
    v = np.broadcast_to(np.eye(n), u.shape[:-2] + (n, n)).copy() if vectors else None
    tol = n * np.finfo(float).eps
    steps = _waves(n) if waves else [(p, q) for p in range(n - 1) for q in range(p + 1, n)]
    for _ in range(MAX_SWEEPS):
        rotated = False
        for p, q in steps:
            up, uq = u[..., p, :], u[..., q, :]
            rot, cs, sn = _rotation(up, uq, tol)
            if cs is None:  # no pair rotates
                continue
            rotated = True
            if waves:  # a pair that does not rotate keeps its bits
                r, cs, sn = rot[..., None], cs[..., None], sn[..., None]
                u[..., p, :] = np.where(r, cs * up - sn * uq, up)
                u[..., q, :] = np.where(r, sn * up + cs * uq, uq)
                if vectors:
                    r, cs, sn = (np.swapaxes(x, -1, -2) for x in (r, cs, sn))
                    vp, vq = v[..., :, p], v[..., :, q]
                    v[..., :, p] = np.where(r, cs * vp - sn * vq, vp)
                    v[..., :, q] = np.where(r, sn * vp + cs * vq, vq)
                continue
            cs, sn = cs[..., None], sn[..., None]
            u[..., p, :], u[..., q, :] = cs * up - sn * uq, sn * up + cs * uq
            if vectors:
                vp, vq = v[..., :, p].copy(), v[..., :, q].copy()
                v[..., :, p], v[..., :, q] = cs * vp - sn * vq, sn * vp + cs * vq
        if not rotated:
            break
    s = np.sqrt(np.einsum("...ji,...ji->...j", u, u))
    order = np.argsort(-s, axis=-1, kind="stable")
    s = np.take_along_axis(s, order, axis=-1)
    if not vectors:
        return s
    return s, np.take_along_axis(v, order[..., None, :], axis=-1)


def cond(a) -> np.ndarray:
    """2-norm condition numbers (...,) of a (..., m, n), m >= n: largest over smallest singular value
    (:func:`jacobi_svd`; inf for a singular matrix)."""
    s = jacobi_svd(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        return s[..., 0] / s[..., -1]


def lstsq(a, b, rcond: float = 1e-12) -> np.ndarray:
    """The minimum-norm least-squares solution x of ``a x ~ b`` for a (m, n), m >= n, b (m,) or (m, k) (x (n,) or
    (n, k)): singular values below ``rcond`` times the largest are dropped (as ``np.linalg.lstsq(a, b,
    rcond)[0]``), from :func:`jacobi_svd` (``waves``): ``x = V diag(1/s) U^T b`` with ``U = a V diag(1/s)``. Same
    bits on any CPU."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    s, v = jacobi_svd(a, vectors=True, waves=True)
    keep = s > rcond * s[0] if s.size and s[0] > 0 else np.zeros(s.shape, dtype=bool)
    u = matmul(a, v[:, keep]) / s[keep]
    if b.ndim == 2:
        return matmul(v[:, keep], matmul(u.T, b) / s[keep][:, None])
    return matmul(v[:, keep], matmul(b, u) / s[keep])


#: columns whose norm is within this factor of the largest are tied in :func:`qr_pivoted` (the first of them in the
#: original order is taken): rounding cannot choose between them
PIVOT_TIE = 1e-10


def qr_pivoted(a):
    """Householder QR with column pivoting (Businger and Golub) of a (m, n), m >= n: ``(d, piv)``, the magnitudes
    (n,) of R's diagonal and the column order (n,) (``a[:, piv] = Q R``). Each step takes the remaining column of
    largest norm, the norms recomputed from the reduced columns (never down-dated); columns within
    :data:`PIVOT_TIE` of the largest count as equal and the first of them in a's order is taken (LAPACK's
    ``geqp3`` leaves such ties to its rounding, which differs by CPU). Same bits on any CPU."""
    r = np.array(np.asarray(a, float).T, order="C")  # (n, m): column j of a is row j, contiguous
    n, m = r.shape
    if m < n:
        raise ValueError(f"a must have at least as many rows as columns, got shape {(m, n)}")
    piv = np.arange(n)
    d = np.zeros(n)
    for k in range(n):
        rest = r[k:, k:]
        norms = np.einsum("ji,ji->j", rest, rest)
        top = norms.max()
        tied = np.flatnonzero(norms >= top * (1.0 - PIVOT_TIE))
        j = k + int(tied[np.argmin(piv[k + tied])])
        if j != k:
            r[[k, j]] = r[[j, k]]
            piv[[k, j]] = piv[[j, k]]
        nx = float(np.sqrt(norms[j - k]))
        d[k] = nx
        if nx == 0.0:
            break  # every remaining column is zero: their diagonal entries stay 0
        x = r[k, k:].copy()
        x[0] -= -nx if x[0] >= 0 else nx
        vv = float(np.einsum("i,i->", x, x))
        if vv > 0.0 and k + 1 < n:
            below = r[k + 1:, k:]
            below -= np.einsum("ji,i->j", below, x)[:, None] * (2.0 / vv) * x
    return d, piv


# ------------------------------------------------------------------------------------- elementary functions
# Hart et al., Computer Approximations (1968), index 5077: atan(x) = x P(x^2) / Q(x^2) on |x| <= tan(pi / 8)
# (19.6 digits); P and Q from the highest power down, Q monic.
_ATAN_P = (16.1536412982230228262, 268.42548195503973794141, 1153.0293515404850115428136,
           1780.40631643319697105464587, 896.78597403663861959987488)
_ATAN_Q = (58.95697050844462222791, 536.265374031215315104235, 1666.7838148816337184521798,
           2079.33497444540981287275926, 896.78597403663861962481162)
_TAN_PI_8, _TAN_3PI_8 = 0.414213562373095048802, 2.414213562373095048802
_PI = 3.141592653589793
_LN2_HI = 6.93147180369123816490e-01  # ln 2 with its last 32 bits zero: n * _LN2_HI is exact for |n| < 2^20
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e+00
_SQRT_HALF = 0.7071067811865476


def _horner(z, coefficients, monic: bool = False):
    """The polynomial of the coefficients (highest power first; ``monic``: a leading 1 before them) at z."""
    p = z + coefficients[0] if monic else np.full_like(z, coefficients[0])
    for c in coefficients[1:]:
        p = p * z + c
    return p


def _atan_positive(a):
    """atan(a) for a >= 0 (inf allowed): reduced to |x| <= tan(pi / 8) by ``pi/2 - atan(1/a)`` and
    ``pi/4 + atan((a - 1) / (a + 1))``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(a < _TAN_PI_8, a, np.where(a > _TAN_3PI_8, -1.0 / a, (a - 1.0) / (a + 1.0)))
    z = x * x
    t = x * _horner(z, _ATAN_P) / _horner(z, _ATAN_Q, monic=True)
    return np.where(a < _TAN_PI_8, t, np.where(a > _TAN_3PI_8, _PI / 2 + t, _PI / 4 + t))


def atan2(y, x) -> np.ndarray:
    """``np.arctan2(y, x)`` [rad] in (-pi, pi], the same bits on any CPU (module docstring); atan2(0, 0) = 0."""
    y, x = np.broadcast_arrays(np.asarray(y, dtype=float), np.asarray(x, dtype=float))
    ay, ax = np.abs(y), np.abs(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _atan_positive(np.where((ay == 0) & (ax == 0), 0.0, ay / ax))
    t = np.where(np.signbit(x) & ~((ay == 0) & (ax == 0) & ~np.signbit(x)), _PI - t, t)
    t = np.where((ay == 0) & (ax == 0), np.where(np.signbit(x), _PI, 0.0), t)
    return np.copysign(t, y)


def arccos(x) -> np.ndarray:
    """``np.arccos(x)`` [rad] for x in [-1, 1] as ``atan2(sqrt((1 - x)(1 + x)), x)`` (:func:`atan2`; NaN outside)."""
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore"):
        return atan2(np.sqrt((1.0 - x) * (1.0 + x)), x)


_EXP_TAYLOR = tuple(1.0 / math_factorial for math_factorial in
                    (6227020800.0, 479001600.0, 39916800.0, 3628800.0, 362880.0, 40320.0, 5040.0, 720.0, 120.0,
                     24.0, 6.0, 2.0, 1.0, 1.0))  # 1 / k! for k = 13 .. 0 (the factorials are exact floats)


def arcsin(x) -> np.ndarray:
    """``np.arcsin(x)`` [rad] for x in [-1, 1] as ``atan2(x, sqrt((1 - x)(1 + x)))`` (:func:`atan2`; NaN outside)."""
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore"):
        return atan2(x, np.sqrt((1.0 - x) * (1.0 + x)))


def exp(x) -> np.ndarray:
    """``np.exp(x)``, the same bits on any CPU: ``x = n ln 2 + r``, |r| <= ln 2 / 2 (Cody and Waite), exp(r) by
    its Taylor polynomial of degree 13 (truncation under 5e-18 relative), times 2^n exactly."""
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        n = np.clip(np.rint(x * _INV_LN2), -1100.0, 1100.0)
        r = (x - n * _LN2_HI) - n * _LN2_LO
        out = np.ldexp(_horner(r, _EXP_TAYLOR), np.where(np.isfinite(n), n, 0.0).astype(np.int64))
    # beyond the float range: 0 below log(2^-1075), inf above log(DBL_MAX) (and NaN kept)
    return np.where(np.isnan(x), np.nan, np.where(x > 709.782712893384, np.inf, np.where(x < -745.1332191019412,
                                                                                          0.0, out)))


_LOG_SERIES = tuple(1.0 / k for k in (23.0, 21.0, 19.0, 17.0, 15.0, 13.0, 11.0, 9.0, 7.0, 5.0, 3.0))


def log(x) -> np.ndarray:
    """``np.log(x)``, the same bits on any CPU: ``x = m 2^e`` exactly (``frexp``, m in [sqrt(1/2), sqrt(2))),
    ``log m = 2 atanh(s)``, ``s = (m - 1) / (m + 1)`` (|s| <= 0.172) by its series to s^23 (truncation under
    1e-19), plus ``e ln 2`` in two parts. 0 gives -inf, a negative number NaN."""
    x = np.asarray(x, dtype=float)
    m, e = np.frexp(x)
    small = m < _SQRT_HALF
    m = np.where(small, 2.0 * m, m)
    e = (e - small).astype(float)
    f = m - 1.0  # exact (Sterbenz)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = f / (2.0 + f)
        z = s * s
        log_m = 2.0 * s + 2.0 * s * (z * _horner(z, _LOG_SERIES))
        out = e * _LN2_HI + (log_m + e * _LN2_LO)
    special = np.where(x == 0, -np.inf, np.where(x < 0, np.nan, x))
    return np.where((x > 0) & np.isfinite(x), out, special)


def tanh(x) -> np.ndarray:
    """``np.tanh(x)``, the same bits on any CPU: ``(1 - t) / (1 + t)`` with ``t = exp(-2 |x|)`` (:func:`exp`), its
    sign x's (absolute error about 1e-16 near 0, relative error a few ulp elsewhere)."""
    x = np.asarray(x, dtype=float)
    t = exp(-2.0 * np.abs(x))
    return np.copysign((1.0 - t) / (1.0 + t), x)


def nearest_power_of_two(v) -> np.ndarray:
    """``np.rint(np.log2(v))`` for v > 0 (an int array), decided exactly: ``v = m 2^e`` (``frexp``, m in
    [1/2, 1)) is nearer 2^e than 2^(e - 1) on the log scale when m >= sqrt(1/2) (never a tie: sqrt(1/2) is not a
    float)."""
    m, e = np.frexp(np.asarray(v, dtype=float))
    return (e - (m < _SQRT_HALF)).astype(np.int64)


def smallest(x, k: int) -> np.ndarray:
    """The indices of the ``k`` smallest values of the 1-D array x, in increasing order of value, ties by index
    (a stable sort: the same on any CPU, where ``np.argpartition`` is not); all of them when k >= x.size."""
    return np.argsort(np.asarray(x), kind="stable")[:max(int(k), 0)]


def largest(x, k: int) -> np.ndarray:
    """The indices of the ``k`` largest values of the 1-D array x, the largest first, ties by index
    (:func:`smallest` of -x)."""
    return smallest(-np.asarray(x), k)
