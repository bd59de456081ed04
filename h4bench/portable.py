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
  of a Householder QR with column pivoting (ties broken by the column order, not by rounding).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PIVOT_TIE", "cond", "det4", "jacobi_svd", "lstsq", "matmul", "qr_pivoted", "solve4"]


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
