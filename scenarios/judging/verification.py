"""Verifying the methods' boxes against the exact hull and the truth (a room of :mod:`scenarios.judging`).

:func:`judge` turns the outcomes into the per-method entries of ``result.json``: ``kind``, ``rigorous``,
``level``, ``origin``, ``status``, ``lower``, ``upper``, ``width``, ``enclosed`` / ``all_enclosed`` (when a truth
is known, else null), ``width_vs_hull`` (its width over the hull's, per parameter), ``unsound`` and
``narrower_than_hull`` (guaranteed methods), ``seconds``.

The narrower-than-hull check (:class:`HullReference`). The hull box H = [h_lo, h_hi] is the smallest box
enclosing the feasible set S (its endpoints rigorous outer bounds). Its 2p LP solutions (the points attaining
the endpoints, computed in floating point) are proven in S by :func:`ident.estimators.proof.proven_points`
(outward-rounded residuals, ``max_k |y_k - W_k x| / b_k <= 1``, and x in the prior; a point that fails is pulled
towards a verified point of S along the segment, or dropped): the same proof as ``h4bench check-estimator``. The proven points are in S, so per
coordinate j the inner endpoints ``in_lo_j = min x_j``, ``in_hi_j = max x_j`` over them lie in the exact hull, and
the hull's tolerance is ``tol_lo_j = in_lo_j - h_lo_j``, ``tol_hi_j = h_hi_j - in_hi_j`` (how far the exact hull
may lie inside H). A guaranteed box B is **unsound** when in some coordinate ``B_lo_j > h_lo_j + tol_lo_j`` or
``B_hi_j < h_hi_j - tol_hi_j``: it then excludes a point proven to lie in S (so it is not an outer enclosure, a
proof). Where no point is proven (S empty within the LP tolerance, or thinner than the rounding: the
``enclosure-critical`` campaign), the tolerance falls back to :data:`HULL_RTOL` relative to the hull's
endpoints, ``tol_j = HULL_RTOL * max(|h_lo_j|, |h_hi_j|)`` (``hull_tolerance`` in the entry: its ``source``,
"proven points" or "relative HULL_RTOL", and the tolerances per coordinate, ``lower`` and ``upper``):
a box narrower than that is flagged, but without a proof. A method that says "proven empty" while a point of S
is proven is unsound in every coordinate. A statistical box claims no enclosure: it is never unsound.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from h4bench import ident
from h4bench.ident.estimators.proof import proven_points

__all__ = ["HULL_RTOL", "HullReference", "hull_reference", "judge"]

#: relative tolerance (of the hull's endpoint magnitudes) of the narrower-than-hull check where no hull point is
#: proven feasible. Nothing can be proven there, so this is a stated heuristic: 100 times the hull LPs' feasibility
#: tolerance (1e-9 on the rows scaled by their bound; the unproven LP points violate them by up to a few 1e-10),
#: so that the looseness of the LP optimum alone never flags a sound box. On ``enclosure-critical`` the hull's
#: widths are about 1e-13 of the endpoints, far below it: the check is silent there and the truth check decides.
HULL_RTOL = 1e-7


@dataclass
class HullReference:
    """The exact hull as the reference of the narrower-than-hull check (module docstring).

    lower, upper : (p,) the hull box; inner_lower, inner_upper : (p,) the proven inner endpoints (NaN where no
    point is proven); tol_lower, tol_upper : (p,) the tolerances; proven : number of proven points;
    source : "proven points" or "relative HULL_RTOL" (the fallback).
    """

    lower: np.ndarray
    upper: np.ndarray
    inner_lower: np.ndarray
    inner_upper: np.ndarray
    tol_lower: np.ndarray
    tol_upper: np.ndarray
    proven: int
    source: str
    seconds: float = 0.0
    points: np.ndarray | None = field(default=None, repr=False)

    def narrower(self, lower, upper) -> np.ndarray:
        """(p,) bool: coordinates where [lower, upper] is narrower than the hull beyond its tolerance."""
        return (np.asarray(lower) > self.lower + self.tol_lower) | (np.asarray(upper) < self.upper - self.tol_upper)

    def tolerance(self) -> dict:
        """The check's tolerance per coordinate, as written in a guaranteed method's entry (``hull_tolerance``)."""
        return {"source": self.source, "lower": self.tol_lower.tolist(), "upper": self.tol_upper.tolist(),
                **({"rtol": HULL_RTOL} if self.source != "proven points" else {})}

    def describe(self) -> dict:
        return {"lower": self.lower.tolist(), "upper": self.upper.tolist(), "source": self.source,
                "proven_points": self.proven, "rtol": HULL_RTOL,
                "tolerance_lower": self.tol_lower.tolist(), "tolerance_upper": self.tol_upper.tolist(),
                "seconds": self.seconds}


def hull_reference(W, y, bound, prior, hull: ident.Box) -> HullReference:
    """The reference of the check from the hull box and its LP points (``hull.info["points"]``, (p, 2p)).

    W (N, p), y (N,), bound scalar or (N,), prior a Box; see the module docstring for the proof and the fallback.
    """
    t0 = time.perf_counter()
    W = np.asarray(W, dtype=float)
    y = np.asarray(y, dtype=float)
    b = np.broadcast_to(np.asarray(bound, dtype=float), y.shape)
    lo, hi = np.asarray(prior.lower, float), np.asarray(prior.upper, float)
    h_lo, h_hi = np.asarray(hull.lower, float), np.asarray(hull.upper, float)
    proven = proven_points(W, y, b, lo, hi, hull.info.get("points"))
    rel = HULL_RTOL * np.maximum(np.abs(h_lo), np.abs(h_hi))
    if proven.shape[1]:
        in_lo, in_hi = proven.min(axis=1), proven.max(axis=1)
        tol_lo, tol_hi = np.maximum(in_lo - h_lo, 0.0), np.maximum(h_hi - in_hi, 0.0)
        source = "proven points"
    else:
        in_lo = in_hi = np.full(len(h_lo), np.nan)
        tol_lo = tol_hi = rel
        source = "relative HULL_RTOL"
    return HullReference(h_lo, h_hi, in_lo, in_hi, tol_lo, tol_hi, int(proven.shape[1]), source,
                         time.perf_counter() - t0, proven)


def _info(box: ident.Box) -> dict:
    return {k: v for k, v in box.info.items() if isinstance(v, (int, float, str, bool, list)) and k != "points"}


def judge(outcomes: dict, reference: HullReference | None, truth=None, names=None) -> dict:
    """The result entries of the methods (module docstring), by name.

    outcomes : from :func:`run_methods`; reference : :func:`hull_reference` of the hull (None when the hull did
    not give a box: no width_vs_hull, no check); truth : (p,) true parameters or None (real data).
    """
    truth = None if truth is None else np.asarray(truth, dtype=float)
    out = {}
    for name, o in outcomes.items():
        est = o.estimator
        e = {"kind": est.kind if est else None, "rigorous": est.rigorous if est else None,
             "level": est.level if est else None, "origin": est.origin if est else None,
             "status": o.status, "seconds": o.seconds}
        guaranteed = est is not None and est.kind == "guaranteed"
        if o.status == "ok":
            box = o.box
            e.update(lower=box.lower.tolist(), upper=box.upper.tolist(), width=box.width.tolist())
            if truth is not None:
                enc = box.contains(truth)
                e.update(enclosed=enc.tolist(), all_enclosed=bool(enc.all()))
            else:
                e.update(enclosed=None, all_enclosed=None)
            if reference is not None:
                hw = reference.upper - reference.lower
                with np.errstate(divide="ignore", invalid="ignore"):
                    ratio = np.where(hw > 0, box.width / np.where(hw > 0, hw, 1.0), np.where(box.width > 0, np.inf, 1.0))
                e["width_vs_hull"] = [float(v) if np.isfinite(v) else None for v in ratio]
                if guaranteed:
                    bad = reference.narrower(box.lower, box.upper)
                    nm = list(names or box.names)
                    e["narrower_than_hull"] = [nm[j] for j in np.flatnonzero(bad)]
                    e["unsound"] = bool(bad.any())
                    e["hull_tolerance"] = reference.tolerance()
            e["info"] = _info(box)
        else:
            e["message"] = o.message
            if truth is not None:
                e.update(enclosed=None, all_enclosed=False)
            if guaranteed and o.status == "inconsistent" and reference is not None and reference.proven:
                e["unsound"] = True  # claims "empty" while a point of S is proven
                e["narrower_than_hull"] = list(names or [])
                e["hull_tolerance"] = reference.tolerance()
        if guaranteed and "unsound" not in e:  # no box (failed), or no reference: not judged (null), never "sound"
            e["unsound"] = None if reference is None or o.status == "failed" else False
            e.setdefault("narrower_than_hull", [])
        out[name] = e
    return out
