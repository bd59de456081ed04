"""Input checks shared by the estimators: the data ``W`` (m, p), ``y`` (m,), the error bound and the prior box.

Each raises a ``TypeError`` (wrong kind of value) or ``ValueError`` (wrong value) naming the argument, what was
expected and what came. :func:`check_problem` is the one validator of the estimator protocol's inputs: the registry
(:func:`~ident.estimators.registry.call`) applies it to every estimator, built-in or plugin, and the estimator modules
apply it when called directly.

The rule on the number of rows: any ``N >= 1``, also ``N < p``. The prior box is bounded, so the feasible set
``{theta in prior : |y - W theta| <= bound}`` is a bounded polytope whatever N is and its hull is defined (the
parameters the rows do not reach keep their prior interval). An estimator that needs more rows than parameters
(a least-squares fit, a variance estimate) says so itself with a ``ValueError``.
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.box import Box, default_names

__all__ = ["check_W_y", "check_bound", "check_finite", "check_prior", "check_problem", "real_array"]


def real_array(x, name: str) -> np.ndarray:
    """``x`` as a float array (contiguous); TypeError naming ``name`` for non-numeric or ragged input."""
    try:
        arr = np.asarray(x)
    except Exception as exc:  # ragged lists and the like
        raise TypeError(f"{name} must be a real numeric array, got {type(x).__name__} ({exc})") from None
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    arr = np.asarray(arr, dtype=float)
    return np.ascontiguousarray(arr) if arr.ndim else arr


def check_finite(arr: np.ndarray, name: str) -> None:
    """ValueError naming ``name``, the NaN and inf counts and the first bad index, if ``arr`` is not finite."""
    if np.isfinite(arr.sum()):  # one pass, no temporary; a NaN or inf anywhere makes the sum non-finite
        return
    bad = ~np.isfinite(arr)
    if not bad.any():
        return  # the sum overflowed, the entries are fine
    n_nan = int(np.isnan(arr).sum())
    n_inf = int(bad.sum()) - n_nan
    first = tuple(int(i) for i in np.unravel_index(int(np.flatnonzero(bad.ravel())[0]), arr.shape))
    raise ValueError(f"{name} must be finite, got {n_nan} NaN and {n_inf} inf entries (first at index {first})")


def check_W_y(W, y) -> tuple[np.ndarray, np.ndarray]:
    """W (m, p) with m >= 1 and p >= 1 (m < p allowed: module docstring) and y (m,), finite real arrays, as float
    arrays."""
    W = real_array(W, "W")
    if W.ndim != 2 or W.shape[1] < 1 or W.shape[0] < 1:
        raise ValueError(f"W must have shape (m, p) with m >= 1 and p >= 1, got {W.shape}")
    check_finite(W, "W")
    y = real_array(y, "y")
    if y.shape != (W.shape[0],):
        raise ValueError(f"y must have shape (m,) = ({W.shape[0]},) to match W, got {y.shape}")
    check_finite(y, "y")
    return W, y


def check_bound(bound, m: int) -> tuple[np.ndarray, bool]:
    """bound (a scalar or (m,), finite, > 0) -> ((m,) array, whether it was a scalar)."""
    b = real_array(bound, "bound")
    if b.ndim == 0:
        if not (np.isfinite(b) and b > 0):
            raise ValueError(f"bound must be finite and > 0 (a scalar or one value per row), got {float(b)!r}")
        return np.full(m, float(b)), True
    if b.shape != (m,):
        raise ValueError(f"bound must be a scalar or have shape (m,) = ({m},), got shape {b.shape}")
    bad = ~(np.isfinite(b) & (b > 0))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(f"bound must be finite and > 0 in every row, got {float(b[k])!r} at row {k} ({int(bad.sum())} bad rows)")
    return b, False


def check_prior(prior, p: int) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """prior (a Box or a (lower, upper) pair of (p,) finite arrays, lower <= upper) -> (lower, upper, names);
    names default to :func:`ident.box.default_names`."""
    if isinstance(prior, Box):
        lo, hi, names = np.array(prior.lower, dtype=float), np.array(prior.upper, dtype=float), prior.names
    elif isinstance(prior, (tuple, list)) and len(prior) == 2:
        lo = real_array(prior[0], "prior lower")
        hi = real_array(prior[1], "prior upper")
        names = default_names(p)
    else:
        raise TypeError(f"prior must be a Box or a (lower, upper) pair of arrays of length {p}, got {type(prior).__name__}")
    if lo.shape != (p,) or hi.shape != (p,):
        raise ValueError(f"prior lower and upper must have shape ({p},) to match W's columns, got {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("prior must be finite: an interval hull needs a bounded prior box (got NaN or inf bounds)")
    if np.any(lo > hi):
        bad = [names[i] for i in np.flatnonzero(lo > hi)]
        raise ValueError(f"prior lower must be <= upper, violated for {bad}")
    return lo, hi, tuple(names)


def check_problem(W, y, bound, prior):
    """The estimator protocol's inputs checked and converted (module docstring).

    W (N, p) and y (N,) finite reals with N >= 1, bound a scalar or (N,) finite and > 0, prior a Box or a
    ``(lower, upper)`` pair of (p,) finite arrays. Returns ``(W, y, b, lo, hi, names)``: float arrays, b (N,),
    the prior's bounds (p,) and names. Raises TypeError / ValueError naming the argument.
    """
    W, y = check_W_y(W, y)
    b, _ = check_bound(bound, W.shape[0])
    lo, hi, names = check_prior(prior, W.shape[1])
    return W, y, b, lo, hi, names
