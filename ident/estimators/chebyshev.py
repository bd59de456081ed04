"""The Chebyshev LP ``min s  s.t. |y_k - W_k theta| <= s w_k, theta in Q`` (:func:`chebyshev`), solved as the hull's
LPs are (:mod:`ident.estimators.hull`: HiGHS on a shifted, power-of-two scaled model, constraint generation,
safe dual bounds): with ``w = 1`` it is the smallest consistent scalar bound, with ``w = b`` it decides emptiness
of the feasible set ``S`` (``S`` is empty iff ``s* > 1``; a safe lower bound ``> 1`` proves it).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from h4bench.portable import largest
from h4bench.ident.estimators.hull import _CHUNK, PRIMAL_SIMPLEX, _matvec, _spread_rows
from h4bench.ident.numerics.interval import mid_rad, point_matmul, up
from h4bench.ident.numerics.lp import LPError, LPFallbackWarning, LPModel, column_scale, power2_scale
from h4bench.ident.numerics.safe_bound import shifted_safe_bound
from h4bench.portable import matmul as pmatmul

__all__ = ["ChebyshevResult", "chebyshev", "scaled_residual_upper"]


@dataclass
class ChebyshevResult:
    """``min s  s.t. |y - W theta| <= s w, theta in Q``: ``theta`` attains ``upper`` exactly (rigorous upper
    bound of the optimum ``s*``); ``lower`` is a safe dual lower bound of ``s*``."""

    theta: np.ndarray
    upper: float
    lower: float
    info: dict = field(default_factory=dict)


def scaled_residual_upper(W, y, w, theta):
    """Rigorous upper bound of ``max_k |y_k - W_k theta| / w_k`` for a float vector theta (p,) (a float), or for
    each column of theta (p, m) (an (m,) array)."""
    X = np.asarray(theta, dtype=float)
    yy, ww = (y, w) if X.ndim == 1 else (y[:, None], w[:, None])
    best = np.zeros(X.shape[1:])
    for s in range(0, W.shape[0], _CHUNK):
        e = min(W.shape[0], s + _CHUNK)
        alo, ahi = point_matmul(W[s:e], X)
        dev = np.maximum(up(yy[s:e] - alo), up(ahi - yy[s:e]))
        best = np.maximum(best, np.max(up(dev / ww[s:e]), axis=0))
    return float(best) if X.ndim == 1 else best


def _chebyshev_first_rows(e0, w, initial_rows: int) -> np.ndarray:
    """(N,) mask of the Chebyshev LP's first working set: spread rows plus the rows of largest scaled residual
    ``|e0| / w`` at the centre, ``initial_rows`` in all (every row when there are fewer)."""
    n_rows = e0.size
    ws_mask = np.zeros(n_rows, dtype=bool)
    ws_mask[_spread_rows(n_rows, initial_rows // 4)] = True
    if n_rows > initial_rows:
        res = np.abs(e0) / w
        res[ws_mask] = -np.inf
        k = initial_rows - int(ws_mask.sum())
        ws_mask[largest(res, k)] = True
    else:
        ws_mask[:] = True
    return ws_mask


def _chebyshev_rows(W, rhs, w, idx):
    """The Chebyshev LP's rows of samples ``idx`` over ``(theta, s)``: ``W_k theta + w_k s >= rhs_k`` for each
    k, then ``W_k theta - w_k s <= rhs_k`` for each k. Returns ``(A (2k, p + 1), lo (2k,), hi (2k,))``."""
    A = np.vstack([np.hstack([W[idx], w[idx, None]]), np.hstack([W[idx], -w[idx, None]])])
    lo = np.concatenate([rhs[idx], np.full(idx.size, -np.inf)])
    hi = np.concatenate([np.full(idx.size, np.inf), rhs[idx]])
    return A, lo, hi


def _scaled_residuals(W, e0, w, dtheta) -> np.ndarray:
    """``|e0 - W dtheta| / w`` (N,) block by block (float: steers the constraint generation only)."""
    n_rows = W.shape[0]
    out = np.empty(n_rows)
    for b in range(0, n_rows, _CHUNK):
        e = min(n_rows, b + _CHUNK)
        out[b:e] = np.abs(e0[b:e] - pmatmul(W[b:e], dtheta)) / w[b:e]
    return out


def chebyshev(
    W: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    prior_lo: np.ndarray,
    prior_hi: np.ndarray,
    *,
    center: np.ndarray | None = None,
    initial_rows: int = 400,
    add_per_round: int = 50,
    violation_tol: float = 1e-12,
    lp_tol: float = 1e-9,
    max_rounds: int = 500,
) -> ChebyshevResult:
    """Weighted Chebyshev (L-infinity) fit over the prior box, by one LP with constraint generation.

    W : (N, p); y : (N,); w : (N,) positive weights; prior box (p,) finite. Variables ``(theta, s)`` with
    ``s in [0, s_max]``, ``s_max`` a rigorous upper bound of ``s*`` (the scaled residual at ``center``,
    doubled, plus 1), so the safe bound is valid. Rows per sample: ``W_k theta + w_k s >= y_k`` and
    ``W_k theta - w_k s <= y_k``. HiGHS sees them shifted to ``center`` (default the prior's midpoint) and
    scaled as in :func:`interval_hull` (rows by ``1 / w``, then columns, powers of two); the safe bound is
    evaluated on the exact data around ``center``. The first working set is the rows of largest scaled
    residual at ``center`` plus spread rows. Raises :class:`~ident.numerics.lp.LPError` when HiGHS cannot solve
    the LP or rejects the model (no bound is then known beyond the residual at ``center``). An LP that stops
    at its per-solve budget (:class:`~ident.numerics.lp.LPModel`) gives coarser safe bounds instead: ``lower``
    the best safe bound of the duals HiGHS held there and of the last optimal solve's (fewer rows), ``upper``
    the residual at the last optimal point (or ``center``); ``info['lp_fallback']`` is then True and an
    :class:`~ident.LPFallbackWarning` is raised.
    """
    t0 = time.perf_counter()
    n_rows, p = W.shape
    prior_lo = np.asarray(prior_lo, float)
    prior_hi = np.asarray(prior_hi, float)
    theta0 = np.clip(mid_rad(prior_lo, prior_hi)[0], prior_lo, prior_hi)
    if center is not None:
        c = np.asarray(center, float)
        theta0 = np.clip(np.where(np.isfinite(c), c, theta0), prior_lo, prior_hi)
    s_max = float(up(2.0 * scaled_residual_upper(W, y, w, theta0)) + 1.0)
    e0 = y - _matvec(W, theta0)  # residuals at the centre (float: steers the LP only)

    # HiGHS works on ((theta - theta0) / d, s) and rows scaled by r ~ 1 / w (powers of two), see interval_hull
    d = np.append(column_scale(W, power2_scale(w)), 1.0)
    x0 = np.append(theta0, 0.0)
    xl, xu = np.append(prior_lo, 0.0), np.append(prior_hi, s_max)
    model = LPModel(xl, xu, center=x0, col_scale=d, tolerance=lp_tol, **PRIMAL_SIMPLEX)
    cost = np.zeros(p + 1)
    cost[p] = 1.0

    def add_model_rows(idx):
        A, lo, hi = _chebyshev_rows(W, e0, w, idx)  # bounds shifted to the centre: e0 = y - W theta0
        model.add_shifted_rows(A, lo, hi, np.concatenate([w[idx], w[idx]]))

    ws_mask = _chebyshev_first_rows(e0, w, initial_rows)
    ws_idx = np.flatnonzero(ws_mask)
    order = [ws_idx]
    add_model_rows(ws_idx)
    rounds = 0
    dtheta = np.zeros(p)
    guesses = []  # dual guesses of the model's first rows: the last optimal solve's (fewer rows are valid too)
    while True:
        rounds += 1
        sol = model.solve(cost if rounds == 1 else None)  # LPError unless optimal, infeasible or 'limit'
        if sol.status == "infeasible":
            raise LPError("HiGHS failed on the Chebyshev LP: infeasible (it always has a solution)")
        if sol.dual_valid:
            guesses = [sol.duals] if sol.status == "optimal" else guesses + [sol.duals]
        if sol.status == "limit":  # stopped at the per-solve budget: the last optimal point and the guesses
            break
        dtheta, s = sol.z[:p], sol.z[p]
        worst = _scaled_residuals(W, e0, w, dtheta)
        worst[ws_mask] = -np.inf
        bad = np.flatnonzero(worst > s + violation_tol * max(s, 1e-300))
        if bad.size == 0 or rounds >= max_rounds:
            break
        if bad.size > add_per_round:
            bad = bad[largest(worst[bad], add_per_round)]
        ws_mask[bad] = True
        order.append(bad)
        add_model_rows(bad)

    ws_all = np.concatenate(order)
    # HiGHS keeps the rows in insertion order: each block added the >= rows of the block, then its <= rows
    A, lo, hi = (np.concatenate(part) for part in zip(*(_chebyshev_rows(W, y, w, blk) for blk in order)))
    lower = 0.0  # s >= 0 (no guess: nothing proven beyond it)
    for rd in guesses:  # the duals of the unscaled rows (of the first rd.size rows when from an earlier solve)
        nz = np.flatnonzero(rd != 0.0)
        lower = max(lower, shifted_safe_bound(A[nz], lo[nz], hi[nz], xl, xu, cost, rd[nz], x0))
    theta = np.clip(theta0 + dtheta, prior_lo, prior_hi)
    upper = scaled_residual_upper(W, y, w, theta)
    fell_back = sol.status == "limit"
    if fell_back:
        warnings.warn(f"chebyshev: the LP stopped at its per-solve budget (round {rounds}); the bounds of the "
                      f"scale are coarser safe ones: [{lower:.6g}, {upper:.6g}]", LPFallbackWarning, stacklevel=2)
    info = {
        **model.counters(),
        "working_rows": int(ws_all.size),
        "rounds": rounds,
        "converged": rounds < max_rounds and not fell_back,
        "lp_fallback": fell_back,
        "seconds": time.perf_counter() - t0,
    }
    return ChebyshevResult(theta=theta, upper=upper, lower=lower, info=info)
