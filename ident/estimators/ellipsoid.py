"""Optimal bounding ellipsoid of the feasible set, by recursive minimum-volume strip updates.

Fogel & Huang, "On the value of information in system identification - bounded noise case",
Automatica 18(2):229-238, 1982. The ellipsoid ``E = {theta : (theta - c)^T P^-1 (theta - c) <= 1}`` starts
around the prior box (centre its midpoint, ``P = p diag(half-width^2)``, which contains the box) and is
updated row by row with the strip ``|y_k - w_k theta| <= b_k``.

The update. In the coordinates ``z = L^-1 (theta - c)`` (``P = L L^T``) the ellipsoid is the unit ball and the
strip is ``l <= t <= h`` along the unit direction ``u = L^T w / g``, ``g = sqrt(w^T P w)``,
``t = u^T z``, with ``l = (y - b - w^T c) / g`` and ``h = (y + b - w^T c) / g`` clipped to ``[-1, 1]``. Every
ellipsoid of the family ``|z|^2 + mu (t - l)(t - h) <= 1``, ``mu >= 0``, contains the ball's intersection with
the strip (the second term is ``<= 0`` inside the strip): this is Fogel & Huang's one-parameter family. Its
volume is proportional to ``r^(n/2) (1 + mu)^(-1/2)`` with ``r = 1 - mu l h + mu^2 (l + h)^2 / (4 (1 + mu))``;
setting the derivative to zero gives, for ``m = 1 + mu``, the quadratic
``(n - 1)(h - l)^2 m^2 + (2 (l + h)^2 - 4 - 4 l h) m - (n + 1)(l + h)^2 = 0`` with exactly one positive root
(the optimal mu of Fogel & Huang; the same ellipsoid as the minimum-volume ellipsoid of a ball cut by two
parallel hyperplanes of Todd, "On minimum volume ellipsoids containing part of a given ellipsoid",
Math. Oper. Res. 7(2), 1982). A row with ``mu <= 0`` does not reduce the volume and is skipped. Back in
theta: ``c+ = c + tau P w / g`` with ``tau = mu (l + h) / (2 m)`` and
``P+ = r (P - (1 - 1/m) P w w^T P / g^2)``, one rank-one update per row.

For ``p = 1`` the set is an interval and the update is the exact intersection.

Not rigorous in floating point: the updates are rounded to nearest. As a safeguard the shape is
inflated by ``1 + 16 (p + 2) u`` at each update (``u = 2^-53``) and symmetrised; this covers the usual
rounding of the update's few p x p operations but is not a proof, so ``rigorous = False``. Against collapse,
``1 + mu`` is capped at 1e8 (any ``mu >= 0`` gives a containing ellipsoid, so the cap only loses volume) and a
row with ``w^T P w <= 0`` in floating point is skipped.
The box is the ellipsoid's projection ``c_j +- sqrt(P_jj)`` intersected with the prior.
"""

from __future__ import annotations

import math

import numpy as np

from h4bench.ident import Box
from h4bench.ident.estimators.registry import declare
from h4bench.ident.estimators._common import check_inputs, inconsistent, set_box

__all__ = ["ellipsoid", "strip_update"]

_U = 2.0**-53
_M_MAX = 1e8  # cap of 1 + mu: shrinks the ellipsoid's width along one row by at most 1e-4 per update


def _optimal_m(n: int, l: float, h: float) -> float:
    """The positive root m = 1 + mu of the volume's stationarity quadratic (see module docstring), n >= 2,
    -1 <= l < h <= 1 not both at the ends (so A > 0 and the root is finite)."""
    s = l + h
    A = (n - 1) * (h - l) ** 2
    B = 2.0 * s * s - 4.0 - 4.0 * l * h
    C = -(n + 1) * s * s
    disc = math.sqrt(max(B * B - 4.0 * A * C, 0.0))
    if B > 0:  # the cancellation-free form of the positive root
        return (-2.0 * C) / (B + disc)
    return (-B + disc) / (2.0 * A)


def strip_update(c, P, w, lo_k, hi_k):
    """Minimum-volume ellipsoid of the family containing ``E(c, P) ∩ {lo_k <= w^T theta <= hi_k}``.

    c : (n,) centre; P : (n, n) shape (symmetric positive definite); w : (n,) row; lo_k < hi_k : the strip.
    Returns ``(c, P, cut)``, ``cut`` False when the row leaves the ellipsoid unchanged, or raises
    ``ValueError`` when the strip misses the ellipsoid.
    """
    n = c.size
    Pw = P @ w
    g2 = float(w @ Pw)
    if not g2 > 0.0:
        return c, P, False
    g = math.sqrt(g2)
    wc = float(w @ c)
    l = (lo_k - wc) / g
    h = (hi_k - wc) / g
    if l > 1.0 or h < -1.0:
        raise ValueError("the strip does not meet the ellipsoid")
    l = max(l, -1.0)
    h = min(h, 1.0)
    if (l <= -1.0 and h >= 1.0) or not h > l:  # no cut, or a strip touching at one point (kept: still valid)
        return c, P, False
    if n == 1:  # the exact interval [l, h] in z, i.e. centre (l + h)/2 and half-width (h - l)/2
        return c + (0.5 * (l + h) / g) * Pw, P * (0.5 * (h - l)) ** 2, True
    # any mu >= 0 gives a containing ellipsoid: capping m keeps P positive definite under rounding
    m = min(_optimal_m(n, l, h), _M_MAX)
    if not m > 1.0:
        return c, P, False
    mu = m - 1.0
    s = l + h
    tau = mu * s / (2.0 * m)
    r = 1.0 - mu * l * h + mu * mu * s * s / (4.0 * m)
    c = c + (tau / g) * Pw
    P = r * (P - ((1.0 - 1.0 / m) / g2) * np.outer(Pw, Pw))
    return c, P, True


@declare(kind="guaranteed", rigorous=False, context=(),
         description="optimal bounding ellipsoid: recursive minimum-volume strip updates (not rigorous in fp)",
         citation="E. Fogel, Y. F. Huang, On the value of information in system identification - bounded noise "
                  "case, Automatica 18(2):229-238, 1982")
def ellipsoid(W, y, bound, prior) -> Box:
    """Optimal bounding ellipsoid (Fogel & Huang 1982): recursive minimum-volume strip updates.

    Parameters
    ----------
    W : (N, p) regressor; y : (N,) observations; bound : (N,) or scalar > 0, the error bound of each
        row in y's units; prior : ident.Box with finite bounds (the first ellipsoid contains it).

    Returns
    -------
    ident.Box
        The ellipsoid's projection intersected with the prior; ``info["set"]`` the ellipsoid
        (``{"type": "ellipsoid", "center", "shape"}``), ``info["cuts"]`` the rows that cut.

    Raises
    ------
    ident.InconsistentDataError
        when a strip misses the ellipsoid (the feasible set is then empty, up to rounding).
    """
    W, y, b, lo, hi, names = check_inputs(W, y, bound, prior)
    N, p = W.shape
    c = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    # a zero half-width gives a degenerate ellipsoid; keep it positive definite (the box is clipped at the end)
    half = np.maximum(half, 1e-12 * max(float(np.max(np.abs(c))), 1.0))
    P = p * np.diag(half**2)
    ylo = y - b
    yhi = y + b
    inflate = 1.0 + 16.0 * (p + 2) * _U
    cuts = 0
    for k in range(N):
        try:
            c, P, cut = strip_update(c, P, W[k], ylo[k], yhi[k])
        except ValueError:
            raise inconsistent(f"the bounding ellipsoid misses the strip of row {k}: the data appear inconsistent "
                               "with the prior and the bound", W, y, b, prior) from None
        if cut:
            cuts += 1
            P = 0.5 * (P + P.T) * inflate
    rad = np.sqrt(np.maximum(np.diag(P), 0.0)) * inflate
    return set_box("ellipsoid", c, rad, lo, hi, names, W, y, b, prior,
                   {"type": "ellipsoid", "center": c.tolist(), "shape": P.tolist()}, cuts=cuts)
