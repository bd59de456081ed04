"""Guaranteed estimation with an uncertain regressor: ``W`` known only as an interval matrix.

**The feasible set (Oettli & Prager 1964).** With ``[W] = [Wc - D, Wc + D]`` (``D >= 0``) and bounds ``b``,

    S = {theta in Q : exists W in [W] with |y - W theta| <= b}.

For ``theta >= 0`` (physical inertias, masses and frictions; the prior must have ``lower >= 0``), the values
``W_k theta`` taken by row k over ``[W]`` form exactly the interval ``[(Wc - D)_k theta, (Wc + D)_k theta]``
(each entry is chosen independently and multiplies a non-negative ``theta_j``), and the row's condition is that
this interval meets ``[y_k - b_k, y_k + b_k]``:

    S = {theta in Q : (Wc - D) theta <= y + b  and  (Wc + D) theta >= y - b},

a polytope given by 2N linear inequalities. Its exact hull is the 2p LPs of :func:`ident.estimators.hull.interval_hull`
on the stacked rows ``A = [W_lo; W_hi]`` with ``W_lo = down(Wc - D)``, ``W_hi = up(Wc + D)`` (outward rounded,
so ``[W_lo, W_hi]`` contains ``[W]`` and the set can only grow). Each stacked row has one finite side; the other
side is set to the range of that row over the prior box, computed by interval arithmetic and rounded outward
(``L_k <= min_Q W_lo,k theta``, ``U_k >= max_Q W_hi,k theta``). **Proof that this changes nothing:** every
theta in Q satisfies ``W_lo,k theta >= L_k`` and ``W_hi,k theta <= U_k``, so adding these inequalities to the
system leaves the set ``S ∩ Q`` unchanged, and all row bounds are finite as ``interval_hull`` needs. A row
with ``L_k > y_k + b_k`` (or ``U_k < y_k - b_k``) proves S empty. Endpoints are the usual safe dual bounds;
emptiness is decided by a one-sided Chebyshev LP (``min s : W_lo theta - s b <= y, W_hi theta + s b >= y``):
a safe lower bound of ``s* > 1`` proves S empty, a verified point with ``s <= 1`` proves it non-empty.

The interval regressor of a robot (e.g. the H4's, :mod:`ident.robots.h4_interval`: encoder error, filters and
friction signs) is built outside this module: here ``[W]`` is any interval matrix, for any robot.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.errors import InconsistentDataError
from h4bench.ident.estimators.enclosure import Verdict, decide_and_enclose
from h4bench.ident.estimators.checks import check_bound, check_finite, check_prior, real_array
from h4bench.ident.estimators.estimate import least_squares_center
from h4bench.ident.estimators.hull import PRIMAL_SIMPLEX, HullWarm, hull_report, interval_hull, strip_bounds
from h4bench.ident.numerics.interval import down, point_matmul, point_matvec, up
from h4bench.portable import matmul as pmatmul
from h4bench.ident.numerics.lp import LPError, LPFallbackWarning, LPModel, column_scale, power2_scale
from h4bench.ident.numerics.safe_bound import shifted_safe_bound

__all__ = ["uncertain_hull", "uncertain_hull_rows"]


# ----------------------------------------------------------------------------------------------- checks
def _check_interval_matrix(Wc, D, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    Wc = real_array(Wc, "Wc")
    if Wc.ndim != 2 or Wc.shape[1] < 1 or Wc.shape[0] < 1:
        raise ValueError(f"Wc must have shape (m, p) with m, p >= 1, got {Wc.shape}")
    check_finite(Wc, "Wc")
    D = real_array(D, "D")
    if D.ndim == 0:
        D = np.full(Wc.shape, float(D))
    if D.shape != Wc.shape:
        raise ValueError(f"D must be a scalar or have the shape of Wc {Wc.shape}, got {D.shape}")
    check_finite(D, "D")
    if np.any(D < 0):
        k = tuple(int(i) for i in np.unravel_index(int(np.argmin(D)), D.shape))
        raise ValueError(f"D must be >= 0 (a radius), got {float(D[k])!r} at index {k}")
    y = real_array(y, "y")
    if y.shape != (Wc.shape[0],):
        raise ValueError(f"y must have shape (m,) = ({Wc.shape[0]},) to match Wc, got {y.shape}")
    check_finite(y, "y")
    return Wc, D, y


# -------------------------------------------------------------------------------------------- the hull
def _op_scale(W_lo, W_hi, y, b, lo, hi, lp_tol=1e-9, center=None):
    """``min s`` s.t. ``W_lo theta - s b <= y``, ``W_hi theta + s b >= y``, theta in [lo, hi], s in [0, s_max].

    Returns (s_lower (safe dual bound), s_upper (verified at the returned theta), theta, solved). ``S`` is empty iff
    ``s* > 1``. All rows at once (HiGHS, shifted to ``center`` and scaled rows first by ``1 / b``, then
    columns, powers of two); the bound is rigorous for the exact float data. If HiGHS cannot solve the LP,
    ``s_lower = 0`` (nothing proven), ``s_upper`` is the verified value at ``center`` and ``solved`` is False; if
    it stops at its per-solve budget, the same but ``s_lower`` the safe bound of the duals HiGHS held there.
    """
    m, p = W_lo.shape
    theta0 = 0.5 * lo + 0.5 * hi if center is None else np.clip(center, lo, hi)
    s0 = _op_upper(W_lo, W_hi, y, b, theta0)
    s_max = float(up(2.0 * s0) + 1.0)
    A = np.vstack([np.hstack([W_lo, -b[:, None]]), np.hstack([W_hi, b[:, None]])])
    bl = np.concatenate([np.full(m, -np.inf), y])
    bu = np.concatenate([y, np.full(m, np.inf)])
    x0 = np.append(theta0, 0.0)
    a0 = pmatmul(A[:, :p], theta0)
    d = np.append(column_scale(A[:, :p], np.tile(power2_scale(b), 2)), 1.0)
    xl, xu = np.append(lo, 0.0), np.append(hi, s_max)
    cost = np.zeros(p + 1)
    cost[p] = 1.0
    try:
        model = LPModel(xl, xu, center=x0, col_scale=d, tolerance=lp_tol, **PRIMAL_SIMPLEX)
        model.add_shifted_rows(A, bl - a0, bu - a0, np.tile(b, 2))
        sol = model.solve(cost)
        if sol.status == "infeasible":
            raise LPError("HiGHS failed on the Oettli-Prager scale LP: infeasible (it always has a solution)")
    except LPError as exc:
        warnings.warn(f"uncertain_hull: {exc}; consistency not decided by the LP", LPFallbackWarning, stacklevel=3)
        return 0.0, s0, theta0, False
    yd = sol.duals  # of the unscaled rows (at a limit: those HiGHS held, still a valid guess)
    nz = yd != 0.0
    s_lo = shifted_safe_bound(A[nz], bl[nz], bu[nz], xl, xu, cost, yd[nz], x0) if sol.dual_valid else 0.0
    if sol.status == "limit":
        warnings.warn(f"uncertain_hull: the Oettli-Prager scale LP stopped at its per-solve budget; its safe lower "
                      f"bound {max(s_lo, 0.0):.6g} is coarser", LPFallbackWarning, stacklevel=3)
        return max(s_lo, 0.0), s0, theta0, False
    theta = np.clip(sol.x[:p], lo, hi)
    return max(s_lo, 0.0), _op_upper(W_lo, W_hi, y, b, theta), theta, True


def _op_upper(W_lo, W_hi, y, b, theta) -> float:
    """Rigorous upper bound of the smallest s with ``W_lo theta - s b <= y <= W_hi theta + s b`` row by row."""
    llo, lhi = point_matmul(W_lo, theta)
    hlo, hhi = point_matmul(W_hi, theta)
    need = np.maximum(up(lhi - y), up(y - hlo))
    return float(max(np.max(up(np.maximum(need, 0.0) / b)), 0.0))


def uncertain_hull(Wc, D, y, bound, prior, *, lp_tol: float = 1e-9) -> Box:
    """Guaranteed box enclosing the Oettli-Prager set (:func:`uncertain_hull_rows` without its warm start)."""
    return uncertain_hull_rows(Wc, D, y, bound, prior, lp_tol=lp_tol)[0]


def uncertain_hull_rows(Wc, D, y, bound, prior, *, lp_tol: float = 1e-9, warm: HullWarm | None = None,
                        split=None, lp_options: dict | None = None,
                        lp_budget: dict | None = None) -> tuple[Box, HullWarm | None]:
    """Guaranteed box enclosing ``S = {theta in Q : exists W in [Wc - D, Wc + D], |y - W theta| <= bound}``.

    Wc : (m, p) centre regressor; D : (m, p) or scalar radius >= 0 (units of W); y : (m,); bound : scalar or
    (m,) > 0; prior : :class:`~ident.Box` or (lower, upper) with ``lower >= 0`` (the polytope form of the
    module docstring needs theta >= 0). The exact hull of S by 2p LPs on the 2m stacked rows, rigorous
    endpoints. Returns a Box with ``info``: ``method='interval'``, ``rows``, ``nonempty_proven``,
    ``seconds``, the hull's LP statistics and budget counters (:func:`~ident.estimators.hull.hull_report`:
    ``lp_limit_hits``, ``lp_retries``, ``lp_fallbacks``, ``lp_fallback_parameters``; a fallback also raises an
    :class:`~ident.LPFallbackWarning` naming the endpoints), ``bound_inflated_by`` when HiGHS found S empty
    within its tolerance without a proof (then the box encloses a slightly larger set). Raises :class:`~ident.InconsistentDataError`
    when S is proven empty (``min_bound`` the smallest consistent scalar bound, rounded up; ``scale_lower``
    a proven lower bound of the factor the given bounds need); ``ValueError``/``TypeError`` on bad input.

    warm : the warm start of the hull LPs (:class:`~ident.estimators.hull.HullWarm`, rows of the 2m stacked rows
    ``[W_lo; W_hi]``), e.g. of the same system over a larger prior; it steers the LPs only, the box is rigorous
    whatever it is. Returns ``(box, warm)``: the hull's own warm start (None when its LPs did not run through).
    split : a :class:`~ident.estimators.hull_split.HullSplit`: the minima and the maxima as two hulls (in two
    processes if it has them; ``warm`` is then its :class:`~ident.estimators.hull_split.SplitWarm`).
    lp_options, lp_budget : HiGHS options and per-run budgets of the hull's LP models
    (:func:`~ident.estimators.hull.interval_hull`).
    """
    t0 = time.perf_counter()
    Wc, D, y = _check_interval_matrix(Wc, D, y)
    m, p = Wc.shape
    b, scalar = check_bound(bound, m)
    lo, hi, names = check_prior(prior, p)
    if np.any(lo < 0):
        bad = [names[j] for j in np.flatnonzero(lo < 0)]
        raise ValueError(f"prior lower must be >= 0 for the interval regressor (Oettli-Prager polytope form "
                         f"needs theta >= 0), violated for {bad}")
    W_lo, W_hi = down(Wc - D), up(Wc + D)
    given = float(b[0]) if scalar else float(np.max(b))

    def inconsistent(s_lo, s_up):
        min_bound = float(up(s_up * given)) if scalar else float("nan")
        msg = (f"the data contradict the bound{'' if scalar else 's'} even with the interval regressor: no "
               f"parameter vector in the prior and no W in [Wc - D, Wc + D] satisfy |y - W theta| <= bound; the "
               f"bound{'' if scalar else 's'} must be scaled by at least {s_lo:.6g}")
        return InconsistentDataError(msg, min_bound=min_bound, bound=given, scale_lower=s_lo)

    def stacked(bb):
        bl, bu = strip_bounds(y, bb)
        L, _ = point_matvec(W_lo, lo, hi)
        _, U = point_matvec(W_hi, lo, hi)
        A = np.vstack([W_lo, W_hi])
        BL = np.concatenate([L, bl])
        BU = np.concatenate([bu, U])
        return A, BL, BU

    info: dict = {"method": "interval", "rows": m}
    center = least_squares_center(pmatmul(Wc.T, Wc), Wc, y, lo, hi, None if scalar else b)

    def decide() -> Verdict:
        s_lo, s_up, theta, solved = _op_scale(W_lo, W_hi, y, b, lo, hi, lp_tol, center)
        return Verdict(s_lo, s_up, theta, solved)

    A, BL, BU = stacked(b)
    if np.any(BL > BU):  # a row whose range over the prior misses its strip: S is empty (rigorous)
        v = decide()
        raise inconsistent(max(v.lower, 1.0), v.upper)
    # scale=b: a stacked row is violated when theta is off its range [BL, BU] by more than violation_tol * b
    # (its own bound, not the width of the range), and HiGHS sees each row in units of its bound
    rows_b = np.concatenate([b, b])

    def hull(factor, start):
        rows = (A, BL, BU) if factor == 1.0 else stacked(b * factor)
        if split is not None:
            return split.hull(*rows, lo, hi, scale=rows_b * factor, center=start, lp_tol=lp_tol, warm=warm,
                              lp_options=lp_options, lp_budget=lp_budget)
        return interval_hull(*rows, lo, hi, scale=rows_b * factor, center=start, lp_tol=lp_tol, warm=warm,
                             lp_options=lp_options, lp_budget=lp_budget)

    def fallback(what):
        warnings.warn(f"uncertain_hull: {what}", LPFallbackWarning, stacklevel=4)

    res, verdict, factor = decide_and_enclose(hull, decide, lambda t: _op_upper(W_lo, W_hi, y, b, t), inconsistent,
                                              fallback, center, lo, hi)
    if factor is not None:
        info["bound_inflated_by"] = factor
    info["nonempty_proven"] = True if verdict is None or factor is not None else verdict.upper <= 1.0
    if res.info["lp_failures"]:
        warnings.warn(f"uncertain_hull: HiGHS could not solve {len(res.info['lp_failures'])} of the hull LPs "
                      f"({res.info.get('lp_error', 'no optimal basis')}); their endpoints are coarser safe bounds "
                      "or the prior's", LPFallbackWarning, stacklevel=2)
    report, message = hull_report(res.info, names)
    if message is not None:
        warnings.warn(f"uncertain_hull: {message}", LPFallbackWarning, stacklevel=2)
    info.update(report)
    lower, upper = np.clip(res.lower, lo, hi), np.clip(res.upper, lo, hi)
    info["seconds"] = time.perf_counter() - t0
    return Box(lower=lower, upper=upper, names=names, info=info), res.warm
