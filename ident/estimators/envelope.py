"""Prediction envelope: the guaranteed range of new rows' output over the feasible parameter polytope.

For the feasible set ``S = {theta in Q : |y - W theta| <= b}`` (Q a finite box, the prior or a hull of S) and
new regressor rows ``W_new``, the range of ``W_new,k theta`` over S is two linear programs per row,
``min / max W_new,k theta  s.t.  theta in S``. Over the box Q alone the range is exact by interval evaluation
but ignores the correlations of S, so it is much wider. Each LP (one HiGHS model on a working set of rows,
:class:`ident.estimators.support.SupportLP`, warm-started from the previous optimum, rows scaled by their bound,
columns to unit root-mean-square, violated rows added until none is left) only steers: the endpoint returned
is the Neumaier-Shcherbina safe bound (Neumaier & Shcherbina, Math. Program. 99, 2004;
:class:`ident.numerics.safe_bound.SafeBound`) of the working-set LP with its row duals, on the original data: rigorous
for any duals, and a bound of the full LP too (fewer rows, a larger set); an LP that HiGHS does not solve keeps
the box's bound. Each endpoint is also intersected with
the interval evaluation over Q (both are outer bounds). Nothing here depends on the robot.
"""

from __future__ import annotations

import time

import numpy as np

from h4bench.ident.estimators.support import SupportLP
from h4bench.ident.numerics.interval import point_matvec

__all__ = ["envelope_lp", "prediction_envelope"]


def _prior_arrays(prior, p: int) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(prior, "lower") and hasattr(prior, "upper"):
        lower, upper = prior.lower, prior.upper
    else:
        try:
            lower, upper = prior
        except (TypeError, ValueError):
            raise TypeError(f"prior must be a Box or a (lower, upper) pair, got {type(prior).__name__}") from None
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    if lower.shape != (p,) or upper.shape != (p,):
        raise ValueError(f"prior lower and upper must have shape ({p},), got {lower.shape} and {upper.shape}")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))) or np.any(lower > upper):
        raise ValueError("prior must be a finite box with lower <= upper")
    return lower, upper


def envelope_lp(W, y, bound, lower, upper, W_new, *, center=None, lp_tol: float = 1e-9):
    """Rigorous ``[min, max]`` of ``W_new_k theta`` over ``S = {theta in [lower, upper] : |y - W theta| <= bound}``.

    W : (m, p); y : (m,) (units of y); bound : scalar or (m,) > 0 (units of y); lower, upper : (p,) finite box
    containing S; W_new : (k, p); center : (p,) a point near S (the LPs' origin; default least squares).
    Returns ``(lo (k,), hi (k,), info)`` (units of y) with info ``{'lps'`` (two per non-zero row),
    ``'lp_solves'`` (HiGHS runs, re-solves of the working set included), ``'lp_failures', 'working_rows', 'seconds'}``.
    Raises ValueError on shapes that do not agree or a bound that is not finite and positive.
    """
    t0 = time.perf_counter()
    W, y, W_new = (np.asarray(a, dtype=float) for a in (W, y, W_new))
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    m, p = W.shape
    if y.shape != (m,) or W_new.ndim != 2 or W_new.shape[1] != p or lower.shape != (p,) or upper.shape != (p,):
        raise ValueError(f"W (m, p), y (m,), W_new (k, p), lower and upper (p,) must agree, got W {W.shape}, "
                         f"y {y.shape}, W_new {W_new.shape}, lower {lower.shape}, upper {upper.shape}")
    b = np.broadcast_to(np.asarray(bound, dtype=float), (m,))
    if not np.all(np.isfinite(b)) or np.any(b <= 0):
        raise ValueError("bound must be finite and > 0")
    box_lo, box_hi = point_matvec(W_new, lower, upper)
    lo_out, hi_out = np.array(box_lo, dtype=float), np.array(box_hi, dtype=float)
    engine = SupportLP(W, y, b, lower, upper, center=center, lp_tol=lp_tol)
    todo = [k for k in range(W_new.shape[0]) if np.any(W_new[k])]  # a zero row's range is {0}: the box's
    for k in todo:  # all minima in the rows' order, then all maxima in reverse: consecutive optima are close
        lo_out[k] = max(lo_out[k], engine.minimize(W_new[k])[0])
    for k in reversed(todo):
        hi_out[k] = min(hi_out[k], engine.maximize(W_new[k])[0])
    lps = 2 * len(todo)
    info = {"lps": lps, "lp_solves": engine.solves, "lp_failures": engine.failures,
            "working_rows": int(engine.idx.size), "seconds": time.perf_counter() - t0}
    return lo_out, hi_out, info


def prediction_envelope(W, y, bound, prior, W_new, *, rows=None, center=None, lp_tol: float = 1e-9):
    """The guaranteed range of ``W_new @ theta`` over ``S = {theta in prior : |y - W theta| <= bound}``.

    Parameters
    ----------
    W : (m, p) regressor of the data; y : (m,) measurements (units of y, e.g. [N m]).
    bound : scalar or (m,) positive error bound(s) (units of y).
    prior : :class:`ident.Box` or ``(lower, upper)``: a finite box containing S (the prior or a hull of S).
    W_new : (k, p) regressor rows whose output is predicted.
    rows : optional indices into W_new: only these rows are evaluated (default all).
    center : (p,) a point near S, the LPs' origin (default least squares); lp_tol : HiGHS's tolerance.

    Returns
    -------
    (lower, upper) : (k,) or (len(rows),) rigorous outer bounds of ``W_new_k theta`` over S (units of y),
    two warm-started LPs per row with safe dual bounds (module docstring).
    """
    W = np.asarray(W, dtype=float)
    if W.ndim != 2:
        raise ValueError(f"W must have shape (m, p), got {W.shape}")
    lower, upper = _prior_arrays(prior, W.shape[1])
    W_new = np.asarray(W_new, dtype=float)
    if rows is not None:
        if W_new.ndim != 2:
            raise ValueError(f"W_new must have shape (k, p), got {W_new.shape}")
        W_new = W_new[np.asarray(rows, dtype=np.int64)]
    lo, hi, _ = envelope_lp(W, y, bound, lower, upper, W_new, center=center, lp_tol=lp_tol)
    return lo, hi
