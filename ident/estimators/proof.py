"""Points proven to lie in the feasible set, and the proof that a box is not an outer enclosure.

The feasible set is ``S = {theta in [lo, hi] : |y_k - W_k theta| <= b_k for every row k}``. A float point x is
*proven* in S when it lies in the prior and the rigorous (outward-rounded) upper bound of ``max_k |y_k - W_k x| /
b_k`` is at most 1 (:func:`~ident.estimators.chebyshev.scaled_residual_upper`). :func:`proven_points` proves candidate
points (e.g. the exact hull's LP solutions, ``Box.info["points"]`` of ``ident.estimate(..., method="hull")``): a
candidate that fails is pulled towards a proven point of S c (the candidates' mean, else the Chebyshev centre)
along the segment, ``x_t = c + t (x - c)`` for ``t = 1 - 10^-k``, k = 12, 9, 6, 3, 2, 1, until it passes (S is
convex, so a point of the segment is in S when it passes), or dropped. :func:`excluded_point` finds a proven point
that a box excludes: the proof that the box does not enclose S. Used by the judging of the scenarios and by
:func:`ident.estimators.conformance.check_estimator`.
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.estimators.chebyshev import chebyshev, scaled_residual_upper

__all__ = ["PULLS", "excluded_point", "proven_points"]

PULLS = (1 - 1e-12, 1 - 1e-9, 1 - 1e-6, 1 - 1e-3, 0.99, 0.9)  #: the pull factors t, tried in this order


def _centre(W, y, b, lo, hi, X) -> np.ndarray | None:
    """A proven point of S: the candidates' mean, else the Chebyshev centre; None when neither is proven."""
    c = np.clip(X.mean(axis=1), lo, hi)
    if scaled_residual_upper(W, y, b, c) <= 1.0:
        return c
    try:
        c = np.clip(chebyshev(W, y, b, lo, hi, center=c).theta, lo, hi)
    except Exception:  # noqa: BLE001 - no centre: the failing candidates are dropped
        return None
    return c if scaled_residual_upper(W, y, b, c) <= 1.0 else None


def proven_points(W, y, b, lo, hi, points) -> np.ndarray:
    """The candidates proven in S, pulled towards a proven centre where needed (module docstring).

    W (N, p), y (N,), b (N,) > 0 float arrays; lo, hi (p,) the prior; points (p, m) the candidates (None or
    empty: none). Returns (p, k) proven points, k <= m (one per candidate that passes, in their order).
    """
    p = len(lo)
    if points is None or not np.size(points):
        return np.zeros((p, 0))
    X = np.clip(np.array(points, dtype=float).reshape(p, -1), lo[:, None], hi[:, None])
    ok = scaled_residual_upper(W, y, b, X) <= 1.0
    if not ok.all():
        centre = _centre(W, y, b, lo, hi, X)
        for t in PULLS if centre is not None else ():
            bad = np.flatnonzero(~ok)
            if not bad.size:
                break
            Xt = np.clip(centre[:, None] + t * (X[:, bad] - centre[:, None]), lo[:, None], hi[:, None])
            good = scaled_residual_upper(W, y, b, Xt) <= 1.0
            X[:, bad[good]] = Xt[:, good]
            ok[bad[good]] = True
    return X[:, ok]


def excluded_point(lower, upper, proven) -> tuple[int, np.ndarray] | None:
    """A proven point outside the box ``[lower, upper]``: ``(j, x)`` with x (p,) a column of ``proven`` (p, k)
    and j a coordinate where ``x_j`` lies outside ``[lower_j, upper_j]`` (the farthest outside, relative to the
    box's width); None when the box contains every proven point."""
    proven = np.asarray(proven, dtype=float)
    if not proven.size:
        return None
    lower = np.asarray(lower, dtype=float)[:, None]
    upper = np.asarray(upper, dtype=float)[:, None]
    out = np.maximum(lower - proven, proven - upper)  # > 0 outside
    if not np.any(out > 0):
        return None
    scale = np.maximum(upper - lower, np.finfo(float).tiny)
    j, k = np.unravel_index(int(np.argmax(np.where(out > 0, out / scale, -np.inf))), out.shape)
    return int(j), proven[:, k].copy()
