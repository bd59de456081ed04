"""Safe (rigorous) bounds of linear programs from any dual guess (Neumaier & Shcherbina, Math. Program. 99, 2004).

:class:`SafeBound` (with :func:`safe_lower_bound`, :func:`safe_upper_bound`, :func:`shifted_safe_bound`) and
:class:`SafeBounds` (many LPs over the same rows at once) turn the duals an LP solver returns (or any others) into
a rigorous bound over a box: every product and sum is rounded outward, so neither the scaling of the model the
solver saw nor its tolerances can affect rigour (:mod:`ident.numerics.lp` solves the LPs).
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.numerics.interval import TINY, U, down, mul, point_matmul, sub, sum_down, up
from h4bench.portable import matmul as pmatmul

__all__ = ["SafeBound", "SafeBounds", "safe_lower_bound", "safe_upper_bound", "shifted_safe_bound"]


class SafeBound:
    """Neumaier-Shcherbina lower bound of ``min c^T x  s.t.  bl <= A x <= bu`` for a dual guess ``y``, to be
    evaluated over one or more column boxes (:meth:`over`), optionally around a float point ``x0``.

    A : (m, n) float; bl, bu : (m,) (may be -inf / +inf); c : (n,); y : (m,); x0 : (n,) or None.
    Neumaier & Shcherbina (2004): for every feasible x, ``c^T x = y^T A x - r^T x`` with ``r = A^T y - c``,
    and each term is bounded below over its box. Entries of ``y`` that would multiply an infinite row
    bound are set to zero first (any ``y`` is allowed). ``r`` is enclosed with rigorous dot-product error
    bounds and every product and the final sum are rounded downward. The row terms and ``r`` do not depend on
    the box, so a second box (e.g. a box already proven to enclose the set) costs only ``n`` products.

    With ``x0``: ``x = x0 + z``, ``bl - A x0 <= A z <= bu - A x0`` (``A x0`` enclosed, bounds rounded outward),
    ``z in [xl - x0, xu - x0]`` (rounded outward) and ``c^T x = c^T x0 + c^T z`` (bounded below). The terms
    are then of the size of the strips rather than of ``|y| |bl|``, which keeps the bound tight when the
    strips are narrow (bounds of 1e-13 relative).
    """

    def __init__(self, A, bl, bu, c, y, x0=None) -> None:
        A = np.asarray(A, dtype=float)
        bl = np.asarray(bl, dtype=float)
        bu = np.asarray(bu, dtype=float)
        c = np.asarray(c, dtype=float)
        y = np.array(y, dtype=float)
        self.x0 = None if x0 is None else np.asarray(x0, dtype=float)
        self.cx0 = 0.0
        if self.x0 is not None:
            if A.shape[0]:
                alo, ahi = point_matmul(A, self.x0)
                bl = np.where(np.isneginf(bl), -np.inf, down(bl - ahi))
                bu = np.where(np.isposinf(bu), np.inf, up(bu - alo))
            self.cx0 = float(sum_down(down(c * self.x0)))  # each product rounded down, then the sum
        y[np.isneginf(bl) & (y > 0)] = 0.0  # y_i > 0 pairs with bl_i, y_i < 0 with bu_i
        y[np.isposinf(bu) & (y < 0)] = 0.0
        y[~np.isfinite(y)] = 0.0
        keep = y != 0.0
        A, bl, bu, y = A[keep], bl[keep], bu[keep], y[keep]
        # rows: min(y bl, y bu) = y bl if y > 0 else y bu; one product, rounded down
        self.rows = down(np.where(y > 0, y * np.where(y > 0, bl, 0.0), y * np.where(y < 0, bu, 0.0)))
        # r = A^T y - c, enclosed
        if A.shape[0]:
            glo, ghi = point_matmul(A.T, y)
        else:
            glo = ghi = np.zeros_like(c)
        self.rlo, self.rhi = sub(glo, ghi, c, c)

    def over(self, xl, xu) -> float:
        """The bound over the column box ``[xl, xu]`` (finite)."""
        xl = np.asarray(xl, dtype=float)
        xu = np.asarray(xu, dtype=float)
        if not (np.all(np.isfinite(xl)) and np.all(np.isfinite(xu))):
            raise ValueError("safe_lower_bound needs finite column bounds xl, xu")
        if self.x0 is not None:
            xl, xu = down(xl - self.x0), up(xu - self.x0)
        # min over r in [rlo, rhi], x in [xl, xu] of -r x: bilinear, attained at a corner
        plo, _ = mul(-self.rhi, -self.rlo, xl, xu)
        mu = float(sum_down(np.concatenate([self.rows, plo])))
        return mu if self.x0 is None else float(down(mu + self.cx0))


def _dot_constant(counts) -> np.ndarray:
    """``2 (n + 2) u`` for each count n (the constant of :func:`ident.numerics.interval.dot_error`)."""
    return 2.0 * (np.asarray(counts, dtype=float) + 2.0) * U


class SafeBounds:
    """:class:`SafeBound` for k LPs over the same rows at once: ``min c_j^T x  s.t.  bl <= A x <= bu`` with the
    dual guesses ``Y[:, j]``, around one float point ``x0`` (e.g. the 2p LPs of an interval hull).

    A : (m, n) float; bl, bu : (m,) finite; C : (k, n) the costs; Y : (m, k) the duals (a zero entry: the row is
    not in that LP's guess; non-finite entries are dropped, any y being valid); x0 : (n,).
    The same maths as :class:`SafeBound` (Neumaier & Shcherbina, Math. Program. 99, 2004): the shifted row
    bounds ``bl - A x0``, ``bu - A x0`` (rounded outward) computed once for all LPs, the residuals
    ``A^T Y - C^T`` by one enclosed product. Every dot product and sum of LP j is bounded as a sum of its own
    ``nnz(Y[:, j])`` (+ n) non-zero terms: the zero entries add exactly in any order, so the error bound of a
    sum of that many terms holds (Rump et al. 2009's constants, :mod:`ident.numerics.interval`).
    """

    def __init__(self, A, bl, bu, C, Y, x0) -> None:
        A = np.asarray(A, dtype=float)
        C = np.asarray(C, dtype=float)
        Y = np.array(Y, dtype=float)
        self.x0 = np.asarray(x0, dtype=float)
        Y[~np.isfinite(Y)] = 0.0
        counts = np.count_nonzero(Y, axis=0)
        alo, ahi = point_matmul(A, self.x0)
        sbl, sbu = down(np.asarray(bl, float) - ahi), up(np.asarray(bu, float) - alo)  # strips around x0
        rows = down(np.where(Y > 0, Y * np.where(Y > 0, sbl[:, None], 0.0),
                             Y * np.where(Y < 0, sbu[:, None], 0.0)))
        self.rows = np.where(Y != 0.0, rows, 0.0)  # (m, k): min(y bl, y bu) rounded down, exact zeros elsewhere
        g = pmatmul(A.T, Y)  # (n, k); einsum, not BLAS (the same bits on any CPU)
        e = up(up(_dot_constant(counts) * pmatmul(np.abs(A).T, np.abs(Y))) + TINY)
        none = counts == 0  # no row: the product is exactly zero
        self.rlo, self.rhi = sub(np.where(none, 0.0, down(g - e)), np.where(none, 0.0, up(g + e)), C.T, C.T)
        self.cx0 = sum_down(down(C * self.x0), axis=1)  # (k,) c_j^T x0, rounded down
        self.n_terms = counts + A.shape[1]

    def over(self, xl, xu) -> np.ndarray:
        """The k bounds (k,) over the column box ``[xl, xu]`` (finite)."""
        xl = np.asarray(xl, dtype=float)
        xu = np.asarray(xu, dtype=float)
        if not (np.all(np.isfinite(xl)) and np.all(np.isfinite(xu))):
            raise ValueError("SafeBounds.over needs finite column bounds xl, xu")
        zl, zu = down(xl - self.x0), up(xu - self.x0)
        plo, _ = mul(-self.rhi, -self.rlo, zl[:, None], zu[:, None])  # (n, k) min of -r z over the box
        v = np.vstack([self.rows, plo])
        s = np.sum(v, axis=0)
        mu = down(s - up(up(_dot_constant(self.n_terms) * np.sum(np.abs(v), axis=0)) + TINY))
        return down(mu + self.cx0)


def safe_lower_bound(A, bl, bu, xl, xu, c, y) -> float:
    """Rigorous lower bound of ``min c^T x  s.t.  bl <= A x <= bu, xl <= x <= xu`` for any dual guess ``y``.

    A : (m, n) float; bl, bu : (m,) (may be -inf / +inf); xl, xu : (n,) finite; c : (n,); y : (m,).
    See :class:`SafeBound` (Neumaier & Shcherbina 2004).
    """
    return SafeBound(A, bl, bu, c, y).over(xl, xu)


def shifted_safe_bound(A, bl, bu, xl, xu, c, y, x0) -> float:
    """:func:`safe_lower_bound` evaluated around a float point ``x0`` (same guarantee, smaller rounding;
    see :class:`SafeBound`)."""
    return SafeBound(A, bl, bu, c, y, x0).over(xl, xu)


def safe_upper_bound(A, bl, bu, xl, xu, c, y, x0=None) -> float:
    """Rigorous upper bound of ``max c^T x  s.t.  bl <= A x <= bu, xl <= x <= xu`` for any dual guess ``y``
    of the equivalent ``min -c^T x`` (e.g. :meth:`LPModel.solve`'s duals for the cost ``-c``); optionally
    evaluated around ``x0``. See :class:`SafeBound` (Neumaier & Shcherbina 2004)."""
    return -SafeBound(A, bl, bu, -np.asarray(c, dtype=float), y, x0).over(xl, xu)
