"""Guaranteed estimation with outliers: the q-relaxed feasible set (OMNE, Lahanier, Walter & Gomeni 1987;
q-relaxed intersection, Jaulin 2009), its hull, and which rows are outliers.

A few rows may break the bound (a torque spike, an encoder glitch). With the strips
``T_k = {theta : |y_k - W_k theta| <= b_k}`` and the prior box Q, the **q-relaxed feasible set** is

    S_q = {theta in Q : theta lies outside at most q strips},

the set of parameter vectors consistent with all but at most q rows. It is a union of polytopes (one per
set of at most q discarded rows), generally non-convex. Two rigorous outer enclosures of its hull:

* **groups** (fast, any size; :func:`relaxed_hull` with ``method="groups"``): split the rows into G >= q + 1
  disjoint groups. A theta with at most q bad rows spoils at most q groups, so it lies in the feasible set
  ``S_g`` of at least ``G - q`` groups. Hence, with ``l_g`` a rigorous lower bound of ``theta_i`` over
  ``S_g`` (``+inf`` for a group proven empty), ``theta_i >= `` the ``(G - q)``-th smallest ``l_g``; likewise
  the upper end is the ``(G - q)``-th largest ``u_g``. For ``G = q + 1`` this is the union of the group hulls;
  a larger G trades wider group hulls for a higher order statistic. Every ``l_g``, ``u_g`` is an ordinary
  rigorous hull (:func:`ident.estimate`); boxes from several partitions are intersected (each is outer).
* **exact** (small problems): the 2p mixed-integer LPs ``min/max theta_i`` over
  ``{(theta, z) : theta in X, z in {0,1}^N, sum z <= q, W_k theta - Mu_k z_k <= y_k + b_k,
  W_k theta + Ml_k z_k >= y_k - b_k}``, with ``Mu_k >= max_X (W_k theta) - (y_k + b_k)`` and
  ``Ml_k >= (y_k - b_k) - min_X (W_k theta)`` bounded by interval arithmetic (outward rounded), so that
  ``z_k = 1`` relaxes row k exactly over X and the projection of the feasible set on theta is exactly
  ``S_q & X`` (X a box already known to contain S_q, see the reductions below). Each MILP is solved by a
  **best-first branch and bound of our own, whose every bound is rigorous**: a node fixes some ``z_k`` to 1
  (rows declared outliers, E) or 0 (rows declared clean, K); its LP relaxation (free ``z_k`` in [0, 1], plus
  an elastic variable ``s`` that widens every strip by ``s w_k`` at a penalty ``Lambda s`` in the objective,
  so the LP is always feasible and an empty node gets a large bound) is solved by HiGHS (dual simplex, warm
  started from the previous node) and bounded below by the Neumaier-Shcherbina safe bound
  (:func:`ident.estimators.hull.safe_lower_bound` on the exact float data, valid for any dual vector). The open node of
  smallest bound is expanded next; a node is closed when its LP point violates at most ``q - |E|`` free rows
  (a point of ``S_q`` up to the LP tolerance: its value is the incumbent) or when its bound reaches the
  incumbent (within ``tau``, 1e-7 of the box width); otherwise it branches on its most violated free row
  (outlier or clean). The leaves and open nodes cover ``S_q & X`` (every theta of it lies in the branch that
  matches its own set of bad rows), so **the endpoint is the minimum of their safe bounds**: rigorous
  whatever HiGHS's tolerances, and tight to them. The search is anytime: at ``max_nodes`` or ``time_limit``
  the open nodes contribute their parents' safe bounds (still rigorous, looser; ``info['certified']`` says
  which endpoints were closed). Optionally (``highs_milp=True``) HiGHS's own MILP solver runs first on the
  same formulation for an incumbent and an independent value (measured 20-40x slower than the best-first
  search alone at 200-300 rows, p = 6-14). The cost grows combinatorially with the budget left over the
  true number of outliers (each spare unit lets any active row of a vertex be dropped).

What is rigorous, and where. The row bounds ``y -+ b`` are rounded outward; the ranges of ``W_k theta``
over a box come from :func:`ident.numerics.interval.point_matvec`; every LP bound is a safe dual bound; "certain"
outliers are decided by interval evaluation. Heuristic (float) decisions only steer the search (which row
to branch on, when a node's point counts as a member of ``S_q``, which rows are "suspected"), never a bound:
a wrong incumbent only makes the search explore further or stop at a bound that is still valid.

Reductions (both rigorous, used by every method): once a box X ⊇ hull(S_q) is known, a row whose strip
misses ``W_k X`` (interval test) is an outlier for every theta in S_q (**certain** outlier); one whose strip
contains ``W_k X`` is satisfied by all of X (**redundant**). With C certain rows, ``S_q = {theta in X :
at most q - |C| bad rows among the undecided ones}``: the search runs on the undecided rows only, with the
budget ``q - |C|``, and for ``q = |C|`` it is an ordinary hull (:func:`ident.estimate`). More than q certain
rows prove ``S_q`` empty (:class:`OutlierBudgetError`).
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass

import highspy
import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.errors import InconsistentDataError, OutlierBudgetError
from h4bench.ident.estimators.checks import check_bound, check_prior, check_W_y
from h4bench.ident.estimators.estimate import estimate, min_consistent_bound
from h4bench.ident.estimators.hull import strip_bounds
from h4bench.ident.numerics.interval import point_matvec, up
from h4bench.ident.numerics.lp import LPError, LPModel, arm_time_limit, check, column_scale, power2_scale
from h4bench.ident.numerics.safe_bound import safe_lower_bound

__all__ = ["OutlierBudgetError", "OutlierRows", "detect_outliers", "relaxed_hull"]

METHODS = ("auto", "exact", "groups")
_OPTIMAL = highspy.HighsModelStatus.kOptimal



@dataclass(frozen=True)
class OutlierRows:
    """Rows (indices into W) that break the bound under the q assumption.

    certain : rows whose strip cannot meet the box (interval test, outward rounded): an outlier for every
    theta in the box, hence for every theta of ``S_q``. suspected : rows violated at the box's midpoint
    (a float test; a heuristic pointer, not a proof); certain rows are suspected too.
    """

    certain: np.ndarray
    suspected: np.ndarray


# ------------------------------------------------------------------------------------------------ checks
def _check_q(q, m: int) -> int:
    if isinstance(q, bool) or not isinstance(q, (int, np.integer)):
        raise TypeError(f"q must be an integer (the number of rows allowed to break the bound), got {type(q).__name__}")
    q = int(q)
    if not 0 <= q < m:
        raise ValueError(f"q must be an integer with 0 <= q < m = {m} (the number of rows), got {q}")
    return q


def _check_groups(groups, q: int, m: int) -> tuple[int, ...]:
    if groups is None:  # the default (q + 1, 2 q + 1), without partitions larger than the rows (m > q always)
        return tuple(sorted({g for g in (q + 1, 2 * q + 1) if g <= m}))
    if isinstance(groups, (int, np.integer)) and not isinstance(groups, bool):
        groups = (int(groups),)
    try:
        gs = tuple(int(g) for g in groups if not isinstance(g, bool) and int(g) == g)
    except (TypeError, ValueError):
        raise TypeError(f"groups must be an integer or a sequence of integers, got {groups!r}") from None
    if len(gs) != len(tuple(groups)) or not gs:
        raise TypeError(f"groups must be an integer or a non-empty sequence of integers, got {groups!r}")
    bad = [g for g in gs if not q + 1 <= g <= m]
    if bad:
        raise ValueError(f"groups must each be between q + 1 = {q + 1} and m = {m} (rows), got {bad}")
    return tuple(sorted(set(gs)))


def _row_ranges(W, lo, hi):
    """Rigorous ``[min, max]`` of ``W_k theta`` over the box ``[lo, hi]`` for every row k."""
    return point_matvec(W, lo, hi)


def detect_outliers(W, y, bound, box) -> OutlierRows:
    """Rows that contradict the bound for every theta in ``box`` (certain) or at its midpoint (suspected).

    W : (m, p); y : (m,); bound : scalar or (m,) > 0; box : :class:`~ident.Box` or (lower, upper), e.g. the
    box of :func:`relaxed_hull`. If ``box`` encloses ``S_q``, every certain row is an outlier of every
    parameter vector consistent with all but q rows (rigorous: outward-rounded strips and interval ranges).
    """
    W, y = check_W_y(W, y)
    b, _ = check_bound(bound, W.shape[0])
    lo, hi, _ = check_prior(box, W.shape[1])
    return _detect(W, *strip_bounds(y, b), lo, hi)


def _detect(W, bl, bu, lo, hi, point=None) -> OutlierRows:
    rlo, rhi = _row_ranges(W, lo, hi)
    certain = np.flatnonzero((rlo > bu) | (rhi < bl))
    c = 0.5 * lo + 0.5 * hi if point is None else point
    v = W @ c
    suspected = np.flatnonzero((v > bu) | (v < bl))
    return OutlierRows(certain=certain, suspected=np.union1d(suspected, certain))


# ------------------------------------------------------------------------------------------- plain hulls
def _plain_hull(W, y, b, lo, hi):
    """Rigorous hull of ``{theta in [lo, hi] : |y - W theta| <= b}`` as (lower, upper), or None if proven empty.

    Fewer rows than parameters: padded with the redundant rows ``|0 - 0 theta| <= 1`` so that
    :func:`ident.estimate` (which wants m >= p) applies; the set is unchanged.
    """
    m, p = W.shape
    if m == 0:
        return lo.copy(), hi.copy()
    if m < p:
        W = np.vstack([W, np.zeros((p - m, p))])
        y = np.concatenate([y, np.zeros(p - m)])
        b = np.concatenate([b, np.ones(p - m)])
    try:
        box = estimate(W, y, b, (lo, hi))
    except InconsistentDataError:
        return None
    return np.array(box.lower), np.array(box.upper)


def _labels(m: int, G: int) -> np.ndarray:
    """The partition: row k -> group k mod G (every group spans the whole experiment, all joints)."""
    return np.arange(m) % G


def _groups_box(W, y, b, bl, bu, lo, hi, q: int, G: int):
    """Counting bound over G disjoint interleaved groups (module docstring), and the rows it proves outliers.

    Returns ``(box, certain, part, info)``: ``box`` the (lower, upper) pair, or None when fewer than ``G - q``
    groups are non-empty (S_q is then proven empty); ``certain`` the indices of rows proven outliers by
    counting; ``part`` a dict with the group ``labels``, ``nonempty`` flags and ``ref``, the coordinate-wise
    median of the non-empty group hulls' midpoints (a robust reference point for suspicion, a float heuristic).

    Certain rows by counting: if row k is good for some theta of S_q, then theta has at most q bad rows, none of
    them k, so it lies in the feasible set of at least ``G - q`` groups, each of which then also meets row k's
    strip. Group g can do so only if it is not proven empty and, for a group other than k's own (whose set
    already contains the strip condition), if its rigorous box ``X_g`` has ``W_k X_g`` meeting the strip
    (interval test). A row for which fewer than ``G - q`` groups can is an outlier of every theta of S_q.
    """
    m, p = W.shape
    lab = _labels(m, G)
    ls = np.full((G, p), np.inf)
    us = np.full((G, p), -np.inf)
    nonempty = np.zeros(G, dtype=bool)
    for g in range(G):
        rows = np.flatnonzero(lab == g)
        res = _plain_hull(W[rows], y[rows], b[rows], lo, hi)
        if res is not None:
            ls[g], us[g] = res
            nonempty[g] = True
    k = G - q  # groups clean for every theta of S_q
    lower = np.sort(ls, axis=0)[k - 1]
    upper = -np.sort(-us, axis=0)[k - 1]
    info = {"G": G, "empty_groups": int(G - nonempty.sum()), "rows_per_group": m // G}
    if not np.all(np.isfinite(lower)):
        return None, np.zeros(0, dtype=np.int64), None, info
    ref = np.median(0.5 * ls[nonempty] + 0.5 * us[nonempty], axis=0)
    possible = np.zeros(m, dtype=np.int64)
    for g in np.flatnonzero(nonempty):
        rlo, rhi = _row_ranges(W, ls[g], us[g])
        meets = ~((rlo > bu) | (rhi < bl))
        own = lab == g
        possible += np.where(own, True, meets)
    certain = np.flatnonzero(possible < k)
    info["certain_by_counting"] = int(certain.size)
    part = {"labels": lab, "nonempty": nonempty, "ref": ref}
    return (np.maximum(lower, lo), np.minimum(upper, hi)), certain, part, info


def _certain_by_lp(W, y, b, lab, nonempty, q: int, candidates, lo, hi) -> np.ndarray:
    """The counting test of :func:`_groups_box` with exact LPs instead of boxes, for a few candidate rows.

    Row k is proven an outlier of every theta of S_q if fewer than ``G - q`` groups g can contain a theta
    that also satisfies row k: for k's own group that needs the group's set non-empty; for another group, the
    set of its rows plus row k (within the box [lo, hi] that encloses S_q) must not be proven empty by
    :func:`ident.estimate` (a safe Chebyshev bound). Stops testing a row as soon as enough groups remain.
    """
    G = int(lab.max()) + 1
    need = G - q
    out = []
    for k in candidates:
        possible = int(nonempty[lab[k]])
        for g in np.flatnonzero(nonempty):
            if possible >= need:
                break
            if g == lab[k]:
                continue
            rows = np.append(np.flatnonzero(lab == g), k)
            if _plain_hull(W[rows], y[rows], b[rows], lo, hi) is not None:
                possible += 1
        if possible < need:
            out.append(int(k))
    return np.asarray(out, dtype=np.int64)


# ------------------------------------------------------------------------------------- exact (MILP + B&B)
class _BigM:
    """The big-M formulation over a box X: columns (theta (p), z (n), s (1)), rows upper (n), lower (n),
    budget (1). Exact float data for the safe bounds; a scaled copy for HiGHS."""

    def __init__(self, W, bl, bu, lo, hi, budget, lp_tol):
        n, p = W.shape
        self.W, self.bl, self.bu, self.lo, self.hi = W, bl, bu, lo, hi
        self.n, self.p, self.budget = n, p, int(budget)
        rlo, rhi = _row_ranges(W, lo, hi)
        self.Mu = np.maximum(up(rhi - bu), 0.0)
        self.Ml = np.maximum(up(bl - rlo), 0.0)
        self.w = np.maximum(0.5 * bu - 0.5 * bl, np.finfo(float).tiny)  # elastic weights (any positive)
        need = np.maximum(self.Mu, self.Ml) / self.w
        self.s_max = float(up(up(np.max(need, initial=0.0)) * 2.0 + 1.0))
        self.xl = np.concatenate([lo, np.zeros(n), [0.0]])
        self.xu = np.concatenate([hi, np.ones(n), [self.s_max]])
        r = power2_scale(self.w)  # rows to units of their half-width first, then columns (units-invariant)
        self.d = np.concatenate([column_scale(W, r), np.ones(n + 1)])
        self.r = np.concatenate([r] * 2 + [np.ones(1)])
        self.lp_tol = lp_tol

    def rows(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Dense rows ``idx`` (of 2n + 1) of the exact constraint matrix with their bounds."""
        n, p = self.n, self.p
        A = np.zeros((idx.size, p + n + 1))
        bl = np.full(idx.size, -np.inf)
        bu = np.full(idx.size, np.inf)
        for a, k in enumerate(idx):
            if k < n:  # W theta - Mu z - w s <= bu
                A[a, :p] = self.W[k]
                A[a, p + k] = -self.Mu[k]
                A[a, -1] = -self.w[k]
                bu[a] = self.bu[k]
            elif k < 2 * n:  # W theta + Ml z + w s >= bl
                j = k - n
                A[a, :p] = self.W[j]
                A[a, p + j] = self.Ml[j]
                A[a, -1] = self.w[j]
                bl[a] = self.bl[j]
            else:  # sum z <= budget
                A[a, p: p + n] = 1.0
                bu[a] = float(self.budget)
        return A, bl, bu

    def highs(self, integer: bool) -> LPModel:
        """The model on the LP core (columns scaled by ``d``, rows by ``r``, no shift): the MILP (``integer``,
        z binary, no elastic slack) or the LP relaxation of the branch and bound (dual simplex: node changes
        are bound changes)."""
        n, p = self.n, self.p
        if integer:
            h = LPModel(self.xl, self.xu, center=np.zeros(p + n + 1), col_scale=self.d, tolerance=None,
                        presolve="choose", mip_rel_gap=1e-9, mip_abs_gap=0.0, primal_feasibility_tolerance=self.lp_tol,
                        mip_feasibility_tolerance=self.lp_tol)
        else:
            h = LPModel(self.xl, self.xu, center=np.zeros(p + n + 1), col_scale=self.d, tolerance=self.lp_tol,
                        simplex_strategy=1)
        # sparse rows: each upper/lower row has the p theta entries, its z and s; then the budget row
        k = np.arange(n)
        index = np.concatenate([np.hstack([np.tile(np.arange(p), (n, 1)), (p + k)[:, None], np.full((n, 1), p + n)])
                                .ravel()] * 2 + [p + k])
        side_values = [np.hstack([self.W, (-self.Mu)[:, None], (-self.w)[:, None]]),
                       np.hstack([self.W, self.Ml[:, None], self.w[:, None]])]
        values = np.concatenate([v.ravel() for v in side_values] + [np.ones(n)])
        starts = np.append(np.arange(2 * n) * (p + 2), 2 * n * (p + 2))
        lo_b = np.concatenate([np.full(n, -np.inf), self.bl, [-np.inf]])
        hi_b = np.concatenate([self.bu, np.full(n, np.inf), [float(self.budget)]])
        h.add_sparse_rows(starts, index, values, lo_b, hi_b, np.concatenate([self.w, self.w, [1.0]]))
        if integer:
            check(h.highs.changeColsIntegrality(n, np.arange(p, p + n, dtype=np.int32),
                                                np.full(n, highspy.HighsVarType.kInteger)), "changeColsIntegrality")
            check(h.highs.changeColBounds(p + n, 0.0, 0.0), "changeColBounds")  # no elastic slack in the MILP
        return h

    def safe_bound(self, cost: np.ndarray, duals: np.ndarray, xl, xu) -> float:
        """Safe lower bound of ``min cost^T x`` over the LP with column bounds ``xl, xu`` (original units), for
        the duals of the unscaled rows (:meth:`LPModel.solve`)."""
        y = np.asarray(duals)
        nz = np.flatnonzero(y != 0.0)
        A, bl, bu = self.rows(nz)
        return safe_lower_bound(A, bl, bu, xl, xu, cost, y[nz])


def _exact_endpoints(W, bl, bu, lo, hi, budget, *, max_nodes, time_limit, highs_milp, milp_time_limit, lp_tol):
    """Certified ``min/max theta_i`` over ``S_budget & [lo, hi]`` (module docstring). Returns (lower, upper, info).

    Best-first branch and bound: the open node of smallest safe bound is expanded first, so the search stops
    as soon as that bound reaches the best point found (the incumbent), and no node whose bound exceeds the
    optimum is ever expanded. On stopping, every theta of the set lies in a closed leaf or an open node (a
    child's region is inside its parent's, so a parent's bound is valid for it), and the minimum of their safe
    bounds is a rigorous lower bound of the endpoint.
    """
    t0 = time.perf_counter()
    deadline = t0 + time_limit
    n, p = W.shape
    model = _BigM(W, bl, bu, lo, hi, budget, lp_tol)
    mip = None
    if highs_milp:
        mip_model = model.highs(integer=True)
        mip = mip_model.highs  # HiGHS's MILP statuses (a time limit with an incumbent) are read directly
    lp = model.highs(integer=False)
    ncol = p + n + 1
    lower, upper = lo.copy(), hi.copy()
    info = {"milp_objective": [], "milp_status": [], "nodes": [], "certified": [], "endpoint_gap": []}
    width = np.maximum(hi - lo, 1e-300)
    for j in range(2 * p):
        i = j % p
        sign = 1.0 if j < p else -1.0
        cost = np.zeros(ncol)
        cost[i] = sign
        cut = np.inf  # best objective of a point found in S_budget (float; steers the search only)
        hint: set = set()
        if mip is not None:  # HiGHS's own MILP solver: incumbent, hint and an independent value
            mip_model.set_cost(cost, normalize=False)
            arm_time_limit(mip, milp_time_limit)  # each endpoint's MILP its own time (HiGHS's counts all runs)
            run_error = mip.run() == highspy.HighsStatus.kError  # no incumbent then: the search finds its own
            ms = mip.getModelStatus()
            sol = mip.getSolution()
            if not run_error and sol.value_valid and ms in (_OPTIMAL, highspy.HighsModelStatus.kTimeLimit):
                x = np.asarray(sol.col_value) * model.d
                cut = float(cost[:p] @ x[:p])
                hint = set(np.flatnonzero(x[p: p + n] > 0.5).tolist())
            info["milp_objective"].append(sign * cut if np.isfinite(cut) else None)
            info["milp_status"].append(mip.modelStatusToString(ms))
        lp_cost = cost.copy()
        lp_cost[-1] = 1e4 * width[i]  # elastic penalty: any value keeps the bound valid; large makes it exact
        lp.set_cost(lp_cost, normalize=False)
        tau = 1e-7 * width[i] + 1e-300
        heap = [(-np.inf, 0, 0, (), ())]  # (parent's safe bound, -depth, tie, E, K)
        closed = np.inf  # min safe bound over closed leaves
        nodes = tie = 0
        certified = True
        while heap:
            lbp = heap[0][0]
            if lbp >= cut - tau:
                break  # every open node is bounded by the incumbent (to tau)
            if nodes >= max_nodes or time.perf_counter() > deadline:
                certified = False
                break
            lbp, depth, _, E, K = heapq.heappop(heap)
            nodes += 1
            xl, xu = model.xl.copy(), model.xu.copy()
            xl[p + np.array(E, dtype=np.int64)] = 1.0
            xu[p + np.array(K, dtype=np.int64)] = 0.0
            lp.set_bounds(xl, xu)
            try:
                s = lp.solve()
            except LPError:
                s = None
            if s is None or s.status != "optimal" or not s.dual_valid:
                # not solved: the parent's bound stays valid for this region, and so does the safe bound of the
                # duals HiGHS held when it stopped at its per-solve budget (any duals are a valid guess)
                limit = s is not None and s.status == "limit" and s.dual_valid
                closed = min(closed, max(lbp, model.safe_bound(lp_cost, s.duals, xl, xu)) if limit else lbp)
                continue
            lb = max(lbp, model.safe_bound(lp_cost, s.duals, xl, xu))
            if lb >= cut - tau:
                closed = min(closed, lb)
                continue
            theta, slack = s.x[:p], s.x[-1]
            v = W @ theta
            viol = np.maximum(v - bu, bl - v) / model.w
            free = np.ones(n, dtype=bool)
            free[list(E)] = False
            free[list(K)] = False
            bad = np.flatnonzero(free & (viol > 1e-9))
            if slack <= 1e-9 and bad.size <= budget - len(E):
                closed = min(closed, lb)  # the LP point is (to the LP tolerance) in S_budget: node solved
                cut = min(cut, float(cost[:p] @ theta))
                continue
            if bad.size == 0:
                closed = min(closed, lb)  # the clean rows K alone are (nearly) inconsistent: no row to branch on
                continue
            r = int(bad[np.argmax(viol[bad])])
            tie += 1
            heapq.heappush(heap, (lb, depth - 1, tie, E, K + (r,)))
            if len(E) < budget:
                tie += 1
                heapq.heappush(heap, (lb, depth - 1 - (r in hint), tie, E + (r,), K))
        bound = min(closed, heap[0][0]) if heap else closed
        info["nodes"].append(nodes)
        info["certified"].append(certified)
        info["endpoint_gap"].append(float(cut - bound) if np.isfinite(cut) and np.isfinite(bound) else None)
        if j < p:
            lower[i] = max(lower[i], bound)
        else:
            upper[i] = min(upper[i], -bound)
    info["seconds"] = time.perf_counter() - t0
    return lower, upper, info


# ------------------------------------------------------------------------------------------- public entry
def relaxed_hull(W, y, bound, prior, q: int, *, method: str = "auto", groups=None, exact_max_rows: int = 300,
                 lp_certify: bool = True, max_nodes: int = 5000, time_limit: float = 120.0,
                 highs_milp: bool = False, milp_time_limit: float = 60.0, lp_tol: float = 1e-9) -> Box:
    """Guaranteed box enclosing the q-relaxed set ``S_q`` (theta consistent with all but at most q rows).

    W : (m, p) regressor; y : (m,) measurements; bound : scalar or (m,) positive bounds (units of y);
    prior : :class:`~ident.Box` or (lower, upper) finite; q : number of rows allowed to break the bound,
    ``0 <= q < m`` (``q = 0`` is the ordinary hull).
    method : ``"groups"`` (fast outer approximation by the counting argument over disjoint row groups),
    ``"exact"`` (groups first, then the certified branch and bound on the rows left undecided) or ``"auto"``
    (exact when at most ``exact_max_rows`` rows are undecided, else groups).
    groups : the numbers of groups G (each ``q + 1 <= G <= m``) of the partitions to intersect; default
    ``(q + 1, 2 q + 1)`` (with the budget left after removing certain outliers).
    lp_certify : also run the LP form of the counting test on the few rows violated at a robust reference
    point (the median of the group hulls' midpoints), proving outliers the interval tests miss (a few LPs per
    candidate row; default True).
    max_nodes, time_limit : node budget of each endpoint's certifying search and seconds for the whole search
    (beyond them, the endpoints stay rigorous but looser, ``info['certified']`` is False for them);
    highs_milp : also run HiGHS's own MILP solver on each of the 2p MILPs first (an incumbent for the search
    and an independent value in ``info['milp_objective']``; measured 20-40x slower than the best-first search
    alone at 200-300 rows); milp_time_limit : seconds per HiGHS MILP; lp_tol : HiGHS tolerances (tightness
    only, never rigour).

    Returns a :class:`~ident.Box` whose ``info`` has ``method``, ``q``, ``exact`` (bool: the box is the hull of
    ``S_q`` to LP tolerance, all endpoints certified), ``certain_rows`` (proven outliers, rigorous),
    ``suspected_rows`` (violated at the reference point of the last row partition, or at the box's midpoint
    when the box is exact; a pointer, not a proof), ``undecided_rows`` (count), ``rounds``, ``partitions``,
    ``seconds`` and, for the exact search, ``nodes``, ``certified``, ``endpoint_gap`` (incumbent minus certified
    bound, per endpoint: the tightness left) and, with ``highs_milp``, ``milp_objective``, ``milp_status``.
    Raises :class:`OutlierBudgetError` when S_q is proven empty (more than q rows must be outliers);
    ``ValueError``/``TypeError`` naming the argument on bad input.
    """
    t0 = time.perf_counter()
    W, y = check_W_y(W, y)
    m, p = W.shape
    b, scalar = check_bound(bound, m)
    lo, hi, names = check_prior(prior, p)
    q = _check_q(q, m)
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    _check_groups(groups, q, m)  # validate early; re-derived below for the reduced budget
    if isinstance(exact_max_rows, bool) or not isinstance(exact_max_rows, (int, np.integer)) or exact_max_rows < 0:
        raise ValueError(f"exact_max_rows must be an integer >= 0, got {exact_max_rows!r}")
    if isinstance(max_nodes, bool) or not isinstance(max_nodes, (int, np.integer)) or max_nodes < 1:
        raise ValueError(f"max_nodes must be an integer >= 1, got {max_nodes!r}")
    for name, val in (("time_limit", time_limit), ("milp_time_limit", milp_time_limit), ("lp_tol", lp_tol)):
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not (np.isfinite(val) and val > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {val!r}")
    bl, bu = strip_bounds(y, b)
    given = float(b[0]) if scalar else float(np.max(b))

    def fail(msg, certain):
        raise OutlierBudgetError(msg, q=q, certain_rows=certain, min_bound=min_consistent_bound(W, y, (lo, hi)),
                                 bound=given)

    info: dict = {"method": method, "q": q, "partitions": [], "rounds": 0}
    ref = None  # robust reference point of the last partition (suspected rows)
    X_lo, X_hi = lo.copy(), hi.copy()
    active = np.arange(m)  # rows not (yet) proven outliers
    certain = np.zeros(0, dtype=np.int64)
    budget = q
    exact = False
    # --- groups, certain outliers, repeat with the reduced budget until nothing new is certain
    while True:
        info["rounds"] += 1
        if budget == 0:
            res = _plain_hull(W[active], y[active], b[active], X_lo, X_hi)
            if res is None:
                fail(f"the data contradict the bound on more than q = {q} rows: with the {certain.size} proven "
                     f"outliers removed, the remaining {active.size} rows admit no parameter vector", certain)
            X_lo, X_hi = np.maximum(X_lo, res[0]), np.minimum(X_hi, res[1])
            exact = True
            break
        wanted = (budget + 1, 2 * budget + 1) if groups is None else _check_groups(groups, q, m)
        gs = tuple(sorted({max(g, budget + 1) for g in wanted if g <= active.size})) or (budget + 1,)
        new = np.zeros(0, dtype=np.int64)
        first = None
        for G in gs:
            box, gcertain, part, ginfo = _groups_box(W[active], y[active], b[active], bl[active], bu[active],
                                                     X_lo, X_hi, budget, G)
            info["partitions"].append({**ginfo, "budget": budget})
            if box is None:
                fail(f"the data contradict the bound on more than q = {q} rows: fewer than G - q' = "
                     f"{G - budget} of {G} row groups admit a parameter vector ({certain.size} rows already "
                     f"proven outliers, q' = {budget})", certain)
            X_lo, X_hi = np.maximum(X_lo, box[0]), np.minimum(X_hi, box[1])
            if np.any(X_lo > X_hi):
                fail(f"the data contradict the bound on more than q = {q} rows: the outer boxes of two row "
                     f"partitions do not intersect", certain)
            new = np.union1d(new, active[gcertain])
            first = part if first is None else first
        ref = first["ref"]
        new = np.union1d(new, active[_detect(W[active], bl[active], bu[active], X_lo, X_hi).certain])
        # the LP form of the counting test, on the rows violated at the robust reference point
        v = W[active] @ ref
        viol = np.maximum(v - bu[active], bl[active] - v) / b[active]
        cand = np.flatnonzero((viol > 0) & ~np.isin(active, new))
        cand = cand[np.argsort(-viol[cand], kind="stable")][: 2 * budget + 4]
        if cand.size and lp_certify:
            new = np.union1d(new, active[_certain_by_lp(W[active], y[active], b[active], first["labels"],
                                                        first["nonempty"], budget, cand, X_lo, X_hi)])
        if new.size > budget:
            certain = np.union1d(certain, new)
            fail(f"the data contradict the bound on more than q = {q} rows: {certain.size} rows are proven "
                 f"outliers for every parameter vector of the relaxed box", certain)
        if new.size == 0:
            break
        certain = np.union1d(certain, new)
        active = np.setdiff1d(active, new)
        budget -= new.size
    # --- rows still undecided over X: the exact search works on them only
    rlo, rhi = _row_ranges(W[active], X_lo, X_hi)
    undecided = active[~((rlo >= bl[active]) & (rhi <= bu[active]))]
    info["undecided_rows"] = int(undecided.size)
    if not exact and (method == "exact" or (method == "auto" and undecided.size <= exact_max_rows)):
        if undecided.size <= budget:
            exact = True  # every undecided row may be dropped: S_q & X = X
        else:
            elo, ehi, einfo = _exact_endpoints(W[undecided], bl[undecided], bu[undecided], X_lo, X_hi, budget,
                                               max_nodes=max_nodes, time_limit=time_limit, highs_milp=highs_milp,
                                               milp_time_limit=milp_time_limit, lp_tol=lp_tol)
            info.update(einfo)
            if np.any(elo > ehi):
                fail(f"the data contradict the bound on more than q = {q} rows: the certified search found no "
                     "parameter vector", certain)
            X_lo, X_hi = np.maximum(X_lo, elo), np.minimum(X_hi, ehi)
            exact = all(einfo["certified"])
    det = _detect(W, bl, bu, X_lo, X_hi, None if exact or ref is None else np.clip(ref, X_lo, X_hi))
    certain = np.union1d(certain, det.certain)  # proven by counting on the way, or by the final box
    info.update({
        "exact": bool(exact), "budget_left": int(budget),
        "certain_rows": certain.tolist(), "suspected_rows": np.union1d(det.suspected, certain).tolist(),
        "seconds": time.perf_counter() - t0,
    })
    return Box(lower=X_lo, upper=X_hi, names=names, info=info)
