"""Rigorous residuals, envelopes and coverage checks of a bounded-error equation ``y = W theta + e``, ``|e| <= b``.

The checks a scenario makes on an estimator's box or on the truth, with every floating-point step rounded outward
(:mod:`ident.numerics.interval`), so that the caller does no interval arithmetic itself:

- :func:`residual_bound`: per row a float ``>= |y_k - W_k theta|`` in exact arithmetic;
- :func:`box_envelope`: ``[lo, hi]`` containing ``W_k theta`` for every theta in a box (a point ``W``);
- :func:`interval_envelope`: the same for an interval regressor ``W in [Wc - D, Wc + D]``;
- :func:`covered`: whether each ``y_k`` lies in an envelope widened by its bound, ``[lo_k - b_k, hi_k + b_k]``,
  the widened envelope rounded outward (a row counts as covered when it lies in the exact widened envelope).
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.numerics.interval import down, matmul, point_matmul, point_matvec, up

__all__ = ["box_envelope", "covered", "interval_envelope", "residual_bound"]


def residual_bound(W, y, theta) -> np.ndarray:
    """(m,) floats ``b_k >= |y_k - W_k theta|`` in exact arithmetic (outward-rounded interval evaluation).

    W : (m, p) regressor; y : (m,) [N m]; theta : (p,) parameters.
    """
    lo, hi = point_matmul(np.asarray(W, float), np.asarray(theta, float))
    y = np.asarray(y, float)
    r_lo, r_hi = down(y - hi), up(y - lo)
    return np.maximum(np.abs(r_lo), np.abs(r_hi))


def box_envelope(W, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` (m,) with ``lo_k <= W_k theta <= hi_k`` for every theta in ``[lower, upper]`` (p,) (exact for a
    linear function over a box up to the outward rounding). W : (m, p)."""
    return point_matvec(W, lower, upper)


def interval_envelope(W_centre, W_radius, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` (m,) containing ``W_k theta`` for every ``W`` in ``[W_centre - W_radius, W_centre + W_radius]``
    (m, p), the ends rounded outward, and theta in ``[lower, upper]`` (p,) (midpoint-radius,
    :func:`ident.numerics.interval.matmul`)."""
    Wc, D = np.asarray(W_centre, float), np.asarray(W_radius, float)
    return matmul(down(Wc - D), up(Wc + D), lower, upper)


def covered(y, lo, hi, bound) -> np.ndarray:
    """(m,) bool: ``y_k`` in ``[lo_k - b_k, hi_k + b_k]``, the ends rounded outward.

    y, lo, hi : (m,) [N m]; bound : scalar or (m,) >= 0 [N m]. The outward rounding keeps the widened envelope an
    outer enclosure of the exact one: a row inside the exact envelope is never reported outside.
    """
    y = np.asarray(y, float)
    b = np.asarray(bound, float)
    return (y >= down(np.asarray(lo, float) - b)) & (y <= up(np.asarray(hi, float) + b))
