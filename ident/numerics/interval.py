"""Rigorous interval arithmetic on numpy arrays, in the default round-to-nearest mode.

An interval array is a pair of float arrays ``lo <= hi`` of the same shape (:class:`Interval` wraps the
pair). Every operation returns an array pair that contains the exact real result for every choice of the
operands inside their intervals. Two techniques make this rigorous without switching the rounding mode
(``fesetround`` is per thread and BLAS threads ignore it, so it is never used here):

* **Elementwise operations** (``+ - * /``) compute the nearest float and step outward to (at least) the
  neighbouring float with :func:`up` / :func:`down` (the successor/predecessor formula of Rump,
  Zimmermann, Boldo & Melquiond 2009, valid in round-to-nearest, subnormals included). The computed
  result is within half an ulp of the exact one, so one step is enough.
* **Sums and dot products** use the a-priori error bound that holds for *any* summation order, blocked or
  fused (BLAS, FMA): ``|fl(x^T y) - x^T y| <= gamma_n |x|^T |y| + n eta`` with ``gamma_n = n u / (1 - n u)``,
  ``u = 2^-53`` and ``eta = 2^-1074`` for underflow (Higham, *Accuracy and Stability of Numerical
  Algorithms*, 2nd ed., sec. 3.1; Rump, BIT 39(3), 1999). The code uses the larger constant
  ``_k(n) = 2 (n + 2) u``, which also absorbs the error of evaluating ``|x|^T |y|`` itself, and the absolute
  term ``1e-300`` (larger than ``n eta`` for any ``n < 10^23``). Every error term is itself evaluated with
  outward ``nextafter`` steps, so the final radius is an upper bound.

Products of interval matrices use the midpoint-radius form (Rump 1999):
``<Ac, Ar> <Bc, Br> subset <Ac Bc, |Ac| Br + Ar (|Bc| + Br)>``, so they cost a few BLAS calls.

All bounds must be finite; the module does not handle infinities or NaN (:class:`Interval` rejects them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench.portable import matmul as pmatmul

__all__ = [
    "Interval",
    "U",
    "add",
    "div",
    "down",
    "dot_error",
    "dot_rows",
    "gram",
    "intersect",
    "matmul",
    "mid_rad",
    "mul",
    "neg",
    "nonneg_upper",
    "point_matmul",
    "point_matvec",
    "sub",
    "sum_down",
    "sum_up",
    "up",
]

U = 2.0**-53  # unit roundoff of binary64, round to nearest
TINY = 1e-300  # absolute term covering underflow in n-term dot products (n * 2^-1074 < 1e-300 for n < 1e23)
_INF = np.inf


_PHI = U * (1.0 + 2.0 * U)  # Rump, Zimmermann, Boldo & Melquiond, BIT 49 (2009) 419-431, algorithm 2
_ETA = 2.0**-1074  # smallest positive subnormal


def up(x):
    """A float ``>= `` the successor of ``x`` (elementwise): ``fl(x + fl(phi |x| + eta))``.

    Rump et al. (2009) prove that in round-to-nearest this is the successor of ``x`` or the one after it,
    so ``up(fl(a op b)) >= a op b`` for one rounded operation. About 8x faster than ``np.nextafter``.
    ``x`` must be finite or ``+inf``.
    """
    x = np.asarray(x, dtype=float)
    return x + (np.abs(x) * _PHI + _ETA)


def down(x):
    """A float ``<=`` the predecessor of ``x`` (elementwise); ``x`` finite or ``-inf``. See :func:`up`."""
    x = np.asarray(x, dtype=float)
    return x - (np.abs(x) * _PHI + _ETA)


def _k(n: int) -> float:
    """Relative error constant for an ``n``-term dot product with computed ``|x|^T |y|``: ``2 (n + 2) u``.

    ``gamma_n / (1 - gamma_n) <= 2 (n + 2) u`` whenever ``n u <= 1/4``; ``2(n+2)`` is a small integer times
    a power of two, so the constant itself is exact.
    """
    if n * U > 0.25:
        raise ValueError(f"dot products of length n must have n * 2^-53 <= 1/4, got n = {n}")
    return 2.0 * (n + 2) * U


def dot_error(abs_product, n: int):
    """Upper bound of ``gamma_n T + n eta`` given ``abs_product = fl(T)``, ``T = |x|^T |y| >= 0``.

    ``fl(T) >= T (1 - gamma_n)``, so ``gamma_n T <= gamma_n / (1 - gamma_n) fl(T) <= _k(n) fl(T)``.
    """
    return up(up(_k(n) * abs_product) + TINY)


def nonneg_upper(computed, n: int):
    """Upper bound of an exact ``n``-term dot product of non-negative numbers from its computed value."""
    return up(computed + dot_error(computed, n))


# ---------------------------------------------------------------------------------------------- elementwise
def add(alo, ahi, blo, bhi):
    """``[a] + [b]``, outward rounded."""
    return down(np.add(alo, blo)), up(np.add(ahi, bhi))


def sub(alo, ahi, blo, bhi):
    """``[a] - [b]``, outward rounded."""
    return down(np.subtract(alo, bhi)), up(np.subtract(ahi, blo))


def neg(alo, ahi):
    """``-[a]`` (exact)."""
    return -np.asarray(ahi), -np.asarray(alo)


def _endpoint_hull(op, alo, ahi, blo, bhi):
    """Outward-rounded hull of ``op`` at the four endpoint pairs (exact for ``*`` and for ``/`` by an
    interval without zero, where the extremes sit at endpoints)."""
    r1, r2, r3, r4 = op(alo, blo), op(alo, bhi), op(ahi, blo), op(ahi, bhi)
    lo = np.minimum(np.minimum(r1, r2), np.minimum(r3, r4))
    hi = np.maximum(np.maximum(r1, r2), np.maximum(r3, r4))
    return down(lo), up(hi)


def mul(alo, ahi, blo, bhi):
    """``[a] * [b]`` elementwise (endpoint products, outward rounded). Bounds must be finite."""
    return _endpoint_hull(np.multiply, alo, ahi, blo, bhi)


def div(alo, ahi, blo, bhi):
    """``[a] / [b]`` elementwise for ``[b]`` not containing zero (raises ``ZeroDivisionError`` otherwise)."""
    blo = np.asarray(blo, dtype=float)
    bhi = np.asarray(bhi, dtype=float)
    if np.any((blo <= 0.0) & (bhi >= 0.0)):
        raise ZeroDivisionError("interval division: the divisor contains zero")
    return _endpoint_hull(np.divide, alo, ahi, blo, bhi)


def intersect(alo, ahi, blo, bhi):
    """``[a] & [b]`` (exact); components with ``lo > hi`` are empty, see :func:`np.any(lo > hi)`."""
    return np.maximum(alo, blo), np.minimum(ahi, bhi)


def mid_rad(lo, hi):
    """Midpoint ``c`` and radius ``r`` with ``[c - r, c + r] ⊇ [lo, hi]`` (``r`` rounded up)."""
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    c = 0.5 * lo + 0.5 * hi  # no overflow for finite bounds; c may be off the true centre by rounding
    r = np.maximum(up(c - lo), up(hi - c))
    return c, r


# ----------------------------------------------------------------------------------------------- reductions
def sum_up(v, axis=-1):
    """Upper bound of the exact sum of ``v`` along ``axis`` (any summation order)."""
    v = np.asarray(v, dtype=float)
    n = v.shape[axis] if v.ndim else 1
    s = np.sum(v, axis=axis)
    return up(s + dot_error(np.sum(np.abs(v), axis=axis), n))


def sum_down(v, axis=-1):
    """Lower bound of the exact sum of ``v`` along ``axis`` (any summation order)."""
    v = np.asarray(v, dtype=float)
    n = v.shape[axis] if v.ndim else 1
    s = np.sum(v, axis=axis)
    return down(s - dot_error(np.sum(np.abs(v), axis=axis), n))


def dot_rows(alo, ahi, xlo, xhi):
    """Enclosure of ``sum_j [a]_{ij} [x]_j`` for every row ``i`` (elementwise products + rigorous sums).

    alo, ahi : (m, n); xlo, xhi : (n,). A second, independent route to interval matrix-vector products
    (endpoint products instead of midpoint-radius), used by the dense reference contractor.
    """
    plo, phi = mul(alo, ahi, xlo, xhi)
    return sum_down(plo, axis=-1), sum_up(phi, axis=-1)


# ------------------------------------------------------------------------------------------------- products
# The float products below are h4bench.portable.matmul (numpy's einsum, never BLAS): the same bits on any CPU
# and thread count, and the gamma_n error bound holds for its order as for any other.
def point_matmul(A, B):
    """Enclosure ``(lo, hi)`` of the exact product ``A @ B`` of two float matrices (or matrix-vector)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n = A.shape[-1]
    z = pmatmul(A, B)
    e = dot_error(pmatmul(np.abs(A), np.abs(B)), n)
    return down(z - e), up(z + e)


def point_matvec(A, xlo, xhi):
    """Enclosure of ``{A x : x in [x]}`` for a float matrix ``A`` (m, n) and an interval ``[x]`` (n,) or (n, k).

    Midpoint-radius: ``A [x] subset A c +- |A| r`` with ``[c - r, c + r] ⊇ [x]``; the float errors of both
    products are bounded by :func:`dot_error`.
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[-1]
    c, r = mid_rad(xlo, xhi)
    absA = np.abs(A)
    z = pmatmul(A, c)
    zr = pmatmul(absA, r)
    e = up(nonneg_upper(zr, n) + dot_error(pmatmul(absA, np.abs(c)), n))
    return down(z - e), up(z + e)


def matmul(Alo, Ahi, Blo, Bhi):
    """Enclosure of ``{A B : A in [A], B in [B]}`` (midpoint-radius, Rump 1999).

    ``<Ac, Ar> <Bc, Br> subset <Ac Bc, |Ac| Br + Ar (|Bc| + Br)>``; shapes as for ``@`` (matrix or vector B).
    """
    Ac, Ar = mid_rad(Alo, Ahi)
    Bc, Br = mid_rad(Blo, Bhi)
    n = Ac.shape[-1]
    absAc = np.abs(Ac)
    z = pmatmul(Ac, Bc)
    rad = up(nonneg_upper(pmatmul(absAc, Br), n) + nonneg_upper(pmatmul(Ar, up(np.abs(Bc) + Br)), n))
    e = up(rad + dot_error(pmatmul(absAc, np.abs(Bc)), n))
    return down(z - e), up(z + e)


def gram(W, chunk: int = 8192):
    """Enclosure ``(lo, hi)`` of the exact Gram matrix ``W^T W`` of a tall float matrix W (N, p).

    Accumulated over row blocks (a summation order like any other, so the ``gamma_N`` bound still holds);
    temporaries are one block of ``|W|``.
    """
    W = np.asarray(W, dtype=float)
    n, p = W.shape
    g = np.zeros((p, p))
    a = np.zeros((p, p))
    for s in range(0, n, chunk):
        blk = W[s : s + chunk]
        g += pmatmul(blk.T, blk)
        ab = np.abs(blk)
        a += pmatmul(ab.T, ab)
    e = dot_error(a, max(n, 1))
    return down(g - e), up(g + e)


# ------------------------------------------------------------------------------------------------- wrapper
@dataclass(frozen=True)
class Interval:
    """An interval array ``[lo, hi]`` (any shape, finite bounds, ``lo <= hi``) with rigorous operators.

    ``+ - *`` accept an :class:`Interval` or a float array (treated as a point interval); ``@`` is the
    interval matrix product (:func:`matmul`, or :func:`point_matvec` when the left operand is a float array
    via ``Interval.__rmatmul__``). Components of an :meth:`intersect` may be empty (``lo > hi``): check
    :meth:`is_empty` before further arithmetic.
    """

    lo: np.ndarray
    hi: np.ndarray

    __array_ufunc__ = None  # make ``ndarray @ Interval`` and ``ndarray + Interval`` defer to this class

    def __post_init__(self) -> None:
        lo = np.array(self.lo, dtype=float)
        hi = np.array(self.hi, dtype=float)
        if lo.shape != hi.shape:
            raise ValueError(f"Interval lo and hi must have the same shape, got {lo.shape} and {hi.shape}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("Interval bounds must be finite")
        if np.any(lo > hi):
            raise ValueError("Interval lo must be <= hi")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @classmethod
    def point(cls, x) -> Interval:
        x = np.asarray(x, dtype=float)
        return cls(x, x)

    @property
    def shape(self) -> tuple[int, ...]:
        return self.lo.shape

    @property
    def mid(self) -> np.ndarray:
        return mid_rad(self.lo, self.hi)[0]

    @property
    def rad(self) -> np.ndarray:
        return mid_rad(self.lo, self.hi)[1]

    @property
    def width(self) -> np.ndarray:
        return self.hi - self.lo

    def is_empty(self) -> bool:
        return bool(np.any(self.lo > self.hi))

    def contains(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return (self.lo <= x) & (x <= self.hi)

    def __getitem__(self, key) -> Interval:
        return Interval(self.lo[key], self.hi[key])

    @staticmethod
    def _pair(other):
        if isinstance(other, Interval):
            return other.lo, other.hi
        other = np.asarray(other, dtype=float)
        return other, other

    def __add__(self, other) -> Interval:
        return Interval(*add(self.lo, self.hi, *self._pair(other)))

    __radd__ = __add__

    def __sub__(self, other) -> Interval:
        return Interval(*sub(self.lo, self.hi, *self._pair(other)))

    def __rsub__(self, other) -> Interval:
        return Interval(*sub(*self._pair(other), self.lo, self.hi))

    def __neg__(self) -> Interval:
        return Interval(*neg(self.lo, self.hi))

    def __mul__(self, other) -> Interval:
        return Interval(*mul(self.lo, self.hi, *self._pair(other)))

    __rmul__ = __mul__

    def __truediv__(self, other) -> Interval:
        return Interval(*div(self.lo, self.hi, *self._pair(other)))

    def __matmul__(self, other) -> Interval:
        return Interval(*matmul(self.lo, self.hi, *self._pair(other)))

    def __rmatmul__(self, other) -> Interval:
        return Interval(*point_matvec(np.asarray(other, dtype=float), self.lo, self.hi))

    def intersect(self, other) -> Interval:
        lo, hi = intersect(self.lo, self.hi, *self._pair(other))
        return _RawInterval(lo, hi)


class _RawInterval(Interval):
    """An :class:`Interval` that may hold empty components (result of an intersection)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "lo", np.array(self.lo, dtype=float))
        object.__setattr__(self, "hi", np.array(self.hi, dtype=float))
