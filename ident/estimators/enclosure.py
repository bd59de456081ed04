"""The one decide-empty / inflate / retry / fall-back step of the hull estimators.

The hull LPs (:func:`ident.estimators.hull.interval_hull`) decide the hull of a polytope ``S`` whose rows are
strips ``|y - W theta| <= s b`` scaled by a factor ``s`` (1 for the given bounds). Their verdict "infeasible"
is HiGHS's, within its tolerance; crossing safe endpoints (a lower above an upper) prove ``S`` empty. Either
way a consistency LP (the smallest factor ``s*`` the bounds need: ``S`` is empty iff ``s* > 1``) decides:

* a safe lower bound of ``s*`` above 1 proves ``S`` empty: the caller's error is raised (so are crossing
  endpoints when the consistency LP could not be solved);
* otherwise ``S`` may be empty only within the LP tolerance: the hull is recomputed for the slightly larger,
  non-empty set with the bounds scaled by ``max(s_upper, 1) (1 + 1e-9)`` (still an outer box of ``S``), from
  the verified point; if that fails too, the box is the prior (a fallback, reported).

When the hull LPs succeed, the mean of their 2p solutions is checked rigorously (a point of ``S`` proves it
non-empty); failing that, the consistency LP decides as above.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from h4bench.ident.estimators.hull import COUNTERS, HullResult

__all__ = ["INFLATION", "Verdict", "decide_and_enclose"]

INFLATION = 1.0 + 1e-9  #: relative margin of the inflated bounds above the verified factor


@dataclass
class Verdict:
    """A consistency LP's answer about the factor ``s*`` the bounds need (``S`` empty iff ``s* > 1``).

    lower : safe lower bound of ``s*`` (0 when nothing is proven); upper : rigorous upper bound of ``s*``,
    attained at ``theta`` (p,); solved : whether HiGHS solved the LP (else ``upper`` is the value at a centre).
    """

    lower: float
    upper: float
    theta: np.ndarray
    solved: bool


def decide_and_enclose(
    hull: Callable[[float, np.ndarray], HullResult],
    decide: Callable[[], Verdict],
    residual: Callable[[np.ndarray], float],
    inconsistent: Callable[[float, float], Exception],
    fallback: Callable[[str], None],
    center: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
) -> tuple[HullResult, Verdict | None, float | None]:
    """Run the hull, decide emptiness when its verdict needs it, and enclose (module docstring).

    Parameters
    ----------
    hull : ``hull(factor, center)`` the hull LPs for the bounds scaled by ``factor``, from ``center`` (p,).
    decide : the consistency LP (called at most once).
    residual : ``residual(theta)`` a rigorous upper bound of the factor ``theta`` (p,) needs.
    inconsistent : ``inconsistent(scale_lower, s_upper)`` the error that says ``S`` is proven empty.
    fallback : ``fallback(message)`` reports a fallback to the prior (a warning).
    center : (p,) the first hull's origin; lo, hi : (p,) the prior box.

    Returns
    -------
    (result, verdict, factor) : the hull (its endpoints an outer box of ``S``), the consistency verdict if the
    LP was run (else None, and the mean point proved ``S`` non-empty), the factor of the inflated bounds
    (None if not inflated). Raises what ``inconsistent`` returns when ``S`` is proven empty.
    """
    res = hull(1.0, center)
    crossed = res.status == "ok" and bool(np.any(res.lower > res.upper))  # rigorous: S is empty
    if res.status == "infeasible" or crossed:
        verdict = decide()
        if verdict.lower > 1.0 or (crossed and not verdict.solved):
            raise inconsistent(max(verdict.lower, 1.0), verdict.upper)
        factor = max(verdict.upper, 1.0) * INFLATION  # not proven empty: enclose the slightly larger set
        first, res = res, hull(factor, verdict.theta)
        for key in COUNTERS:  # the LP work of both hulls is counted
            res.info[key] = res.info.get(key, 0) + first.info.get(key, 0)
        if res.status != "ok" or np.any(res.lower > res.upper):
            fallback("the hull LPs failed on a set known to be non-empty; the box is the prior")
            res.lower, res.upper = lo.copy(), hi.copy()
        return res, verdict, factor
    x_mean = np.clip(res.points.mean(axis=1), lo, hi)
    if residual(x_mean) <= 1.0:
        return res, None, None
    verdict = decide()
    if verdict.lower > 1.0:
        raise inconsistent(verdict.lower, verdict.upper)
    return res, verdict, None
