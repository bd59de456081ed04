"""Shared argument checks of the reference estimators (the estimator protocol's inputs).

Every reference estimator takes ``W`` (N, p), ``y`` (N,), ``bound`` (N,) or a scalar (the error model
``|y - W theta| <= bound`` row by row, in y's units) and ``prior`` (an :class:`ident.Box` with finite bounds).
"""

from __future__ import annotations

import numpy as np

from h4bench.ident import Box
from h4bench.ident.estimators.checks import check_finite, real_array
from h4bench.ident.numerics import interval as ia  # noqa: F401  (re-exported for the contractor)


def _real(x, name: str, ndim: int) -> np.ndarray:
    arr = real_array(x, name)
    if ndim >= 0 and arr.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-dimensional, got shape {arr.shape}")
    check_finite(arr, name)
    return arr


def check_inputs(W, y, bound, prior):
    """Validate the protocol's inputs.

    Returns ``(W, y, b, lo, hi, names)``: W (N, p), y (N,), b (N,) > 0 float arrays, the prior's bounds
    lo, hi (p,) and its names. Raises ``TypeError`` / ``ValueError`` naming the argument.
    """
    W = _real(W, "W", 2)
    N, p = W.shape
    if p < 1 or N < 1:
        raise ValueError(f"W must have shape (N, p) with N >= 1 and p >= 1, got {W.shape}")
    y = _real(y, "y", 1)
    if y.shape != (N,):
        raise ValueError(f"y must have shape (N,) = ({N},) to match W, got {y.shape}")
    b = _real(bound, "bound", -1)
    if b.ndim == 0:
        b = np.full(N, float(b))
    if b.shape != (N,):
        raise ValueError(f"bound must be a scalar or have shape (N,) = ({N},), got shape {b.shape}")
    if np.any(b <= 0):
        k = int(np.flatnonzero(b <= 0)[0])
        raise ValueError(f"bound must be > 0 in every row, got {float(b[k])!r} at row {k}")
    if not isinstance(prior, Box):
        raise TypeError(f"prior must be an ident.Box, got {type(prior).__name__}")
    lo = np.array(prior.lower, dtype=float)
    hi = np.array(prior.upper, dtype=float)
    if lo.shape != (p,):
        raise ValueError(f"prior must have p = {p} components to match W's columns, got {lo.size}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("prior must have finite bounds")
    return W, y, b, lo, hi, tuple(prior.names)


def check_groups(groups, N: int) -> np.ndarray:
    """``groups`` as an (N,) int array (one group when None)."""
    if groups is None:
        return np.zeros(N, dtype=int)
    g = np.asarray(groups)
    if g.shape != (N,) or g.dtype.kind not in "iu":
        raise ValueError(f"groups must be an (N,) = ({N},) integer array, got shape {g.shape} dtype {g.dtype}")
    return g.astype(int)


def clip_to_prior(lower, upper, lo, hi):
    """Intersect a box with the prior; an empty intersection is returned as ``None``."""
    lower = np.maximum(np.asarray(lower, dtype=float), lo)
    upper = np.minimum(np.asarray(upper, dtype=float), hi)
    if np.any(lower > upper):
        return None
    return lower, upper


def set_box(method: str, c, rad, lo, hi, names, W, y, b, prior, set_info: dict, **info):
    """The final box of a set estimator: the set's hull ``c +- rad`` intersected with the prior, its set in
    ``info["set"]``; an empty intersection (only through rounding: the set meets the prior by construction) is an
    inconsistency naming ``method``."""
    from h4bench.ident import Box

    clipped = clip_to_prior(c - rad, c + rad, lo, hi)
    if clipped is None:
        raise inconsistent(f"the {method} does not meet the prior", W, y, b, prior)
    return Box(clipped[0], clipped[1], names, info={"method": method, **info, "set": set_info})


def inconsistent(message: str, W, y, b, prior):
    """An ``ident.InconsistentDataError`` for data proven (or found) inconsistent with the prior.

    ``min_bound`` is ``ident.min_consistent_bound`` of the data (zero rows appended when N < p, which does not
    change it); ``scale_lower`` is 1 (the emptiness is the only proof, not its size).
    """
    from h4bench.ident import InconsistentDataError, min_consistent_bound

    N, p = W.shape
    if N < p:
        W = np.vstack([W, np.zeros((p - N, p))])
        y = np.concatenate([y, np.zeros(p - N)])
    mb = float(min_consistent_bound(W, y, prior))
    return InconsistentDataError(f"{message}; the smallest consistent scalar bound is about {mb:.6g}",
                                 min_bound=mb, bound=float(np.max(b)), scale_lower=1.0)
