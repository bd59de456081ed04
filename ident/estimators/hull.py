"""Exact interval hull of the feasible parameter set by linear programming, with rigorous endpoints.

The feasible set of the bounded-error problem is the polytope
``S = {theta in Q : y_k - b_k <= W_k theta <= y_k + b_k, k = 1..N}`` (Q the prior box). Its interval hull
is given by the ``2p`` linear programs ``min / max theta_i over S``. This module solves them with HiGHS

* **warm-started**: one ``highspy.Highs`` model is kept; only the objective changes between the 2p solves
  (``changeColsCost``), so each solve starts from the previous optimal basis;
* with **constraint generation**: the LPs are solved on a working set of rows (a few hundred, chosen spread
  out and near-active), every solution is checked against all N rows, the most violated rows are added and
  the violated LPs re-solved, until no row is violated by more than ``violation_tol * b_k``. This keeps the
  LPs small, so ``N = 10^6`` rows cost a few passes over ``W``. A check visits only the rows a solution can
  violate: ``|W_k z| <= ||W_k diag(d)|| ||z / d||`` (Cauchy-Schwarz in the LP's scaled coordinates) rules out
  every row whose strip leaves more room around the centre, so the rows near the set's boundary are gathered
  once and each solution costs a product with them only;
* with **safe bounds** (Neumaier & Shcherbina, Math. Program. 99, 2004): for ``min c^T x`` subject to
  ``bl <= A x <= bu``, ``xl <= x <= xu`` and *any* ``y``, with ``r = A^T y - c`` enclosed rigorously,
  ``mu = sum_i min(y_i bl_i, y_i bu_i) + sum_j min(-r_j xl_j, -r_j xu_j)`` (summed with downward rounding)
  is a guaranteed lower bound of the optimum. With ``y`` the HiGHS row duals of the working-set rows (zero
  elsewhere) it is a lower bound of the working-set LP, hence of the full LP (fewer rows, larger set).
  The endpoints are therefore rigorous whatever the LP tolerances; the tolerances only decide tightness.

The row bounds ``y -+ b`` are rounded outward (:func:`strip_bounds`), so the LP's set contains ``S``.
HiGHS sees a model shifted to a centre ``theta0`` (least squares) and scaled by powers of two: **rows first**,
each by the power of two nearest ``1 / b_k`` (its own bound), **then columns**, each to unit root-mean-square
of the row-scaled matrix. Changing the units of y (rows, with W and b) or of a parameter (a column) changes
that model only by powers of two, so the box is the same in any units (to the LPs' tightness and the
rounding of the converted data; ``tests/ident/test_units.py`` states the tolerance), and the shift keeps
row bounds of the size of the strips however narrow they are (bounds of 1e-13 relative). HiGHS would
otherwise drop entries below 1e-9 and reject blocks with entries of 1e15 (every HiGHS status is checked,
:mod:`ident.numerics.lp`). The safe bounds are evaluated on the original data with the duals mapped back
(``y_k = d_i r_k y'_k``), around ``theta0`` (:func:`shifted_safe_bound`), so neither the scaling nor the
shift can affect rigour. An LP HiGHS cannot solve keeps its endpoint at a coarser safe bound or the prior.

:func:`ident.estimators.chebyshev.chebyshev` solves ``min s  s.t. |y_k - W_k theta| <= s w_k, theta in Q`` the
same way.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from h4bench.portable import largest, smallest
from h4bench.ident.numerics.interval import down, up
from h4bench.portable import matmul as pmatmul
from h4bench.ident.estimators.hull_warm import HullWarm, tight_rows, usable
from h4bench.ident.numerics.lp import LPError, LPModel, column_scale, power2_scale
from h4bench.ident.numerics.safe_bound import SafeBound, SafeBounds, safe_lower_bound, shifted_safe_bound

__all__ = [
    "COUNTERS",
    "HULL_INFO_KEYS",
    "HullResult",
    "HullWarm",
    "SafeBound",
    "hull_report",
    "interval_hull",
    "power2_scale",
    "safe_lower_bound",
    "shifted_safe_bound",
    "strip_bounds",
]

#: a problem with at most this many rows is solved on all of them from the start (no constraint generation:
#: on such small problems it saves nothing, and at bounds of 1e-12 relative HiGHS failed some working-set LPs)
ALL_ROWS_UP_TO = 150
#: default of interval_hull's ``pool_entries``: problems of at most this many matrix entries (16 MB) keep every row
#: in the pool of rows checked after each solve (0: the ``pool_rows`` nearest only)
POOL_ENTRIES = 2_000_000
_CHUNK = 8192  # rows per block when scanning W: temporaries stay small (no page-fault cost, little memory)


def strip_bounds(y: np.ndarray, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row bounds ``(bl, bu)`` with ``bl <= y - bound`` and ``bu >= y + bound`` exactly (outward rounding)."""
    return down(y - bound), up(y + bound)


def _matvec(W: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``W @ x`` block by block (float)."""
    out = np.empty(W.shape[0])
    for s in range(0, W.shape[0], _CHUNK):  # einsum, not BLAS: the LPs' data are the same bits on any CPU
        out[s : s + _CHUNK] = pmatmul(W[s : s + _CHUNK], x)
    return out


def _spread_rows(n_rows: int, m: int) -> np.ndarray:
    if n_rows <= m:
        return np.arange(n_rows)
    return np.unique(np.linspace(0, n_rows - 1, m).round().astype(np.int64))


#: HiGHS options of the hull's models: primal simplex, since after an objective change the previous optimal
#: basis stays primal feasible (measured: about 15 % fewer iterations than HiGHS's default on the 2p hull LPs)
PRIMAL_SIMPLEX = {"presolve": "off", "simplex_strategy": 4}
#: a re-solve after rows were added (same cost) runs the dual simplex (:class:`~ident.numerics.lp.LPModel`)
DUAL_AFTER_ROWS = False
#: the counters of :meth:`~ident.numerics.lp.LPModel.counters` in a hull's ``info``
COUNTERS = ("lp_solves", "lp_iterations", "lp_limit_hits", "lp_retries", "lp_fallbacks")


@dataclass
class HullResult:
    """Raw result of :func:`interval_hull` (``lower``/``upper`` are rigorous; ``status`` 'ok' or 'infeasible')."""

    lower: np.ndarray
    upper: np.ndarray
    status: str
    info: dict = field(default_factory=dict)
    points: np.ndarray | None = None  # (p, 2p) the LP solutions (float, unverified), columns min_i then max_i
    warm: HullWarm | None = None  # the working set and each LP's last optimal basis (interval_hull's warm start)


def _violated_rows(W, dx_cols, m0, thr, skip):
    """Rows k (not in ``skip``) with ``|W_k dx - m0_k| > thr_k`` for some column dx of ``dx_cols``.

    Returns ``(rows, dev)`` with ``dev[r, j] = |W_rows[r] dx_j - m0|``; one blocked pass over ``W``
    (computed transposed, ``dx^T W^T``, so that the reduction over the k solutions runs along contiguous rows).

    Which rows join the working set is a choice, so it is the same on any CPU and BLAS thread count: the pass runs
    through BLAS (fast), and every row that BLAS's rounding could have decided otherwise (within ``g (|dx|^T |W_k| +
    |m0_k|)`` of its threshold, ``g`` twice the ``gamma_(p + 2)`` of any summation order, with or without fused
    multiply-adds) is decided again, with its deviations, by :func:`_dots` (element-wise operations in a fixed
    order: each row's bits whatever the other rows)."""
    n, k = W.shape[0], dx_cols.shape[1]
    xt = np.ascontiguousarray(dx_cols.T)
    axt = np.abs(xt)
    g = 4.0 * (W.shape[1] + 2) * 2.0**-53
    rows, devs = [], []
    buf = np.empty(k * min(n, _CHUNK))
    bnd = np.empty(k * min(n, _CHUNK))
    for s in range(0, n, _CHUNK):
        e = min(n, s + _CHUNK)
        a = buf[: k * (e - s)].reshape(k, e - s)  # contiguous, so matmul writes through BLAS
        np.matmul(xt, W[s:e].T, out=a)
        a -= m0[s:e]
        np.abs(a, out=a)
        c = bnd[: k * (e - s)].reshape(k, e - s)
        np.matmul(axt, np.abs(W[s:e]).T, out=c)
        c += np.abs(m0[s:e])
        c *= g
        c += a
        near = np.flatnonzero((c.max(axis=0) > thr[s:e]) & ~skip[s:e]) + s
        if near.size:
            exact = np.abs(_dots(xt, W[near]) - m0[near])
            hit = exact.max(axis=0) > thr[near]
            if np.any(hit):
                rows.append(near[hit])
                devs.append(exact[:, hit].T.copy())
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros((0, k))
    return np.concatenate(rows), np.vstack(devs)


def _dots(xt, Wr):
    """(k, r) ``xt Wr^T`` summed column by column in the order of j (element-wise operations: every entry the same
    bits on any CPU, whatever the number of rows r)."""
    acc = xt[:, :1] * Wr[:, 0]
    for j in range(1, xt.shape[1]):
        acc += xt[:, j:j + 1] * Wr[:, j]
    return acc


def _row_norms(W, d):
    """(N,) ``||W_k diag(d)||_2``: each row's Euclidean norm in the LP's scaled coordinates (one pass)."""
    return np.sqrt(np.einsum("ij,ij,j->i", W, W, d * d))  # no (N, p) temporary


def _near_rows(rho, pool_rows):
    """The ``pool_rows`` rows of smallest critical radius ``rho`` (all rows when there are fewer), sorted by it."""
    n_rows = rho.size
    return smallest(rho, min(pool_rows, n_rows))  # sorted by rho, ties by index: the same on any CPU


def _worst(v, candidates, violation_tol, add_rows):
    """Up to ``add_rows`` candidates whose scaled violation ``v`` exceeds ``violation_tol``, the worst first."""
    bad = v > violation_tol
    if not bad.any():
        return candidates[:0]
    idx, v = candidates[bad], v[bad]
    if idx.size > add_rows:
        idx = idx[largest(v, add_rows)]
    return idx


def _safe_endpoints(W, bl, bu, costs, duals, theta0, prior_lo, prior_hi, extra=()):
    """The 2p safe bounds (LP j < p: lower of theta_j; LP p + j: upper) over the prior, then once more over the
    box they give (it encloses the set, so the bound stays valid and the residual costs only that box).

    duals : 2p ``(rows, y)``, LP j's dual guess; extra : further ``(j, rows, y)`` guesses of LP j (e.g. the
    duals where a solve stopped at its budget, or of an earlier solve on fewer rows): each guess gives a valid
    bound (Neumaier & Shcherbina), and each endpoint is the best of its LP's guesses and the prior.
    All at once (:class:`~ident.numerics.safe_bound.SafeBounds`: the rows of every guess gathered once)."""
    p = prior_lo.size
    guesses = [(j, r, yd) for j, (r, yd) in enumerate(duals)] + list(extra)
    lps = np.array([j for j, _, _ in guesses], dtype=np.int64)
    rows = np.unique(np.concatenate([r for _, r, _ in guesses]))
    Y = np.zeros((rows.size, lps.size))
    for k, (_, r, yd) in enumerate(guesses):
        Y[np.searchsorted(rows, r), k] = yd
    bounds = SafeBounds(W[rows], bl[rows], bu[rows], costs[lps], Y, theta0)
    lower, upper = prior_lo.copy(), prior_hi.copy()
    for refine in (False, True):
        if refine and np.any(lower > upper):
            break  # the set is proven empty: no box to refine over
        mu = bounds.over(lower.copy(), upper.copy()) if refine else bounds.over(prior_lo, prior_hi)
        best = np.full(2 * p, -np.inf)
        np.maximum.at(best, lps, mu)
        lower = np.maximum(lower, best[:p])
        upper = np.minimum(upper, -best[p:])
    return lower, upper


class _WorkingSet:
    """The rows of one hull model under constraint generation: the strips in the model's shifted coordinates
    (centres ``m0``, half-widths ``half``), the rows added so far (``idx``, in the model's order).

    A row can be violated by a point ``z`` only if ``||z / d||`` exceeds its critical radius
    ``rho_k = (half_k + tol unit_k - |m0_k|) / ||W_k diag(d)||`` (Cauchy-Schwarz in the LP's scaled coordinates:
    ``|W_k z| <= ||W_k diag(d)|| ||z / d||``). The ``pool_rows`` rows of smallest ``rho`` are gathered once,
    sorted by ``rho``: the rows a solution may violate are a prefix of them, checked exactly; a solution farther
    out than the pool's last ``rho`` is checked on the whole pool (steering only), and the final check of all
    solutions then makes one pass over ``W`` (float: the checks steer the LPs, the safe bounds make the
    endpoints rigorous)."""

    _MARGIN = 1.0 + 1e-9  # on the Cauchy-Schwarz bound, for the rounding of the norms

    def __init__(self, W, m0, half, unit, size, d, near, rho_near, model: LPModel) -> None:
        self.W, self.m0, self.half, self.unit, self.size, self.d = W, m0, half, unit, size, d
        self.inv_unit = 1.0 / np.maximum(unit, np.finfo(float).tiny)
        self.mask = np.zeros(W.shape[0], dtype=bool)
        self.idx = np.zeros(0, dtype=np.int64)
        self.model = model
        self.near, self.rho = near, rho_near
        self.all_near = near.size == W.shape[0]  # the pool is every row: every check is complete
        self.nW, self.nm0, self.nhalf, self.ninv = W[near], m0[near], half[near], self.inv_unit[near]
        self.nmask = np.zeros(near.size, dtype=bool)  # pool rows already in the model
        self.pos = np.full(W.shape[0], -1, dtype=np.int64)
        self.pos[near] = np.arange(near.size)

    def add(self, rows) -> None:
        self.model.add_shifted_rows(self.W[rows], self.m0[rows] - self.half[rows], self.m0[rows] + self.half[rows],
                                    self.size[rows])
        self.mask[rows] = True
        at = self.pos[rows]
        self.nmask[at[at >= 0]] = True
        self.idx = np.concatenate([self.idx, rows])

    def _prefix(self, dz_cols) -> tuple[int, bool]:
        """How many pool rows the shifted points ``dz_cols`` (p, k) may violate, and whether no other row can."""
        u = dz_cols / self.d[:, None]
        radius = float(np.sqrt(np.max(np.einsum("ij,ij->j", u, u)))) * self._MARGIN
        cnt = int(np.searchsorted(self.rho, radius, side="right"))
        return cnt, self.all_near or cnt < self.rho.size

    def solve(self, cost, max_rounds, violation_tol, add_rows):
        """Solve ``min cost^T theta`` on the working set, adding the worst violated pool rows and re-solving until
        none is violated. Returns ``(solution, rows, earlier)`` with ``rows`` the model's rows at that solve (the
        duals' rows); solution None when HiGHS does not solve the LP, status 'limit' when it stopped at the
        per-solve budget (:class:`LPError` when HiGHS rejects rows); ``earlier`` the ``(rows, duals)`` of this
        call's last optimal solve before a re-solve (a valid dual guess of fewer rows), or None."""
        sol, rows, earlier = None, self.idx, None
        for k in range(max_rounds):
            try:  # a re-solve after added rows keeps the cost (LPModel's dual_after_rows may then apply)
                sol, rows = self.model.solve(cost if k == 0 else None), self.idx
            except LPError:
                return None, rows, earlier
            if sol.status != "optimal":
                return sol, rows, earlier
            cnt, complete = self._prefix(sol.z[:, None])
            if cnt == 0:
                return sol, rows, earlier
            # einsum (the same rows chosen on any CPU); in place: v = (|W z - m0| - half) / unit, the scaled violation
            v = pmatmul(self.nW[:cnt], sol.z)
            v -= self.nm0[:cnt]
            np.abs(v, out=v)
            v -= self.nhalf[:cnt]
            v *= self.ninv[:cnt]
            v[self.nmask[:cnt]] = -np.inf  # rows already in the model
            new = _worst(v, self.near[:cnt], violation_tol, add_rows if complete else 3 * add_rows)
            if new.size == 0:
                return sol, rows, earlier
            earlier = (rows, sol.duals) if sol.dual_valid else earlier
            self.add(new)
        return sol, rows, earlier

    def full_check(self, dx_cols, violation_tol, add_rows) -> list:
        """Check the shifted solutions ``dx_cols`` (p, k) against all N rows (a prefix of the pool when that is
        complete, else one blocked pass over ``W``); add the worst violated rows of each to the model. Returns,
        per column, the rows added."""
        cnt, complete = self._prefix(dx_cols)
        if complete:
            dev = np.abs(pmatmul(self.nW[:cnt], dx_cols) - self.nm0[:cnt, None])
            rows = self.near[:cnt]
            hit = (dev.max(axis=1) > self.nhalf[:cnt] + violation_tol * self.unit[rows]) & ~self.nmask[:cnt]
            rows, dev = rows[hit], dev[hit]
        else:
            rows, dev = _violated_rows(self.W, dx_cols, self.m0, self.half + violation_tol * self.unit, self.mask)
        if not rows.size:
            return [rows] * dx_cols.shape[1]
        v = (dev - self.half[rows, None]) * self.inv_unit[rows, None]
        new = [_worst(v[:, col], rows, violation_tol, add_rows) for col in range(dx_cols.shape[1])]
        if any(n.size for n in new):
            self.add(np.unique(np.concatenate(new)))
        return new


#: the keys of a hull's ``info`` that the estimators built on it copy into their Box's ``info``
HULL_INFO_KEYS = COUNTERS + ("working_rows", "rounds", "lp_failures", "converged")


def hull_report(info: dict, names) -> tuple[dict, str | None]:
    """What an estimator reports of a hull's ``info`` (:func:`interval_hull`): the :data:`HULL_INFO_KEYS` and
    ``lp_fallback_parameters`` (the names, of ``names`` (p,), of the parameters with an endpoint whose LP stopped
    at its per-solve budget: that endpoint is a coarser safe bound), and the warning to raise about them (None
    when no LP fell back)."""
    p = len(names)
    out = {k: info[k] for k in HULL_INFO_KEYS}
    ends = info.get("lp_fallback_endpoints", [])
    out["lp_fallback_parameters"] = sorted({names[j % p] for j in ends})
    if not ends:
        return out, None
    which = ", ".join(f"{'lower' if j < p else 'upper'} {names[j % p]}" for j in ends)
    return out, (f"the LPs of {len(ends)} endpoint(s) stopped at their per-solve budget after a cold retry "
                 f"({which}); those endpoints are coarser safe bounds (from the duals at the limit or of an "
                 "earlier solve) or the prior's")


def _fallback_guesses(j, sol, rows, earlier) -> list:
    """The dual guesses ``(j, rows, y)`` of LP j whose solve did not finish: the duals HiGHS held where it
    stopped (``sol`` of status 'limit', when valid) and those of the last optimal solve before it on fewer rows
    (``earlier``). Each gives a valid, coarser safe bound (Neumaier & Shcherbina); none: the prior's."""
    out = []
    if sol is not None and sol.dual_valid:
        nz = sol.duals != 0.0
        out.append((j, rows[nz], sol.duals[nz]))
    if earlier is not None:
        r, yd = earlier
        nz = yd != 0.0
        out.append((j, r[nz], yd[nz]))
    return out


def interval_hull(
    W: np.ndarray,
    bl: np.ndarray,
    bu: np.ndarray,
    prior_lo: np.ndarray,
    prior_hi: np.ndarray,
    *,
    scale: np.ndarray | None = None,
    row_scale: np.ndarray | None = None,
    center: np.ndarray | None = None,
    initial_rows: int = 60,
    pool_rows: int = 4000,
    pool_entries: int | None = None,
    add_rows: int = 20,
    violation_tol: float = 1e-10,
    lp_tol: float = 1e-9,
    max_rounds: int = 100,
    lp_budget: dict | None = None,
    lp_options: dict | None = None,
    warm: HullWarm | None = None,
    lps=None,
) -> HullResult:
    """Rigorous outer enclosure (tight to the LP tolerances) of the hull of ``{x in Q : bl <= W x <= bu}``.

    W : (N, p) float; bl, bu : (N,) row bounds (already outward rounded, see :func:`strip_bounds`);
    prior_lo, prior_hi : (p,) finite prior box Q; scale : (N,) positive unit of the violation test (a row is
    violated when off its strip by more than ``violation_tol * scale``; default the half-width
    ``(bu - bl) / 2``); row_scale : (N,) the rows' own size for the LP's equilibration (default ``scale``;
    e.g. the bound b when the strip is one-sided); center : (p,) a point near the middle of the set (e.g.
    least squares), the origin of the LP's coordinates.

    Scaling (units-invariant, module docstring and :class:`~ident.numerics.lp.LPModel`): rows by the power of
    two nearest ``1 / row_scale_k``, then columns to unit root-mean-square, shifted to ``center``.

    Constraint generation: rows are ranked by the distance of ``center`` to their strip boundary (in the LP's
    scaled coordinates); the nearest ``initial_rows`` and ``2p`` spread rows form the first working set. With
    ``warm`` (:attr:`HullResult.warm` of a hull of the same rows over a larger box, e.g. the previous round of a
    refinement) the first working set is its rows tight in some LP's basis, in its order
    (:func:`~ident.estimators.hull_warm.tight_rows`), and each LP's first solve starts from its own basis there
    (the rows added since basic): the optima move little when the box shrinks. Rows and bases steer the LPs
    only; the endpoints stay safe dual bounds. The pool of rows checked after each solve holds the
    ``max(pool_rows, pool_entries / p)`` nearest rows (every row of a problem of at most ``pool_entries``
    matrix entries, default :data:`POOL_ENTRIES`: each solve is then checked against all rows, and the final
    check finds nothing to re-solve).
    The 2p LPs are solved one after the other (all minima, then all maxima in reverse order, so that
    consecutive optima are close and warm starts cheap); after each solve the rows it may violate (the
    Cauchy-Schwarz test of the module docstring, exact for the rest) are checked and up to ``add_rows`` most
    violated rows are added and the LP re-solved, until none is violated. Then every solution is checked
    against all N rows at once the same way; violated LPs get their worst rows added and are re-solved, until
    no row is off by more than ``violation_tol * scale``. The safe bounds of the 2p LPs are evaluated together
    (:func:`_safe_endpoints`).

    Inputs are assumed validated (finite, ``bl <= bu``, ``prior_lo <= prior_hi``). Returns a
    :class:`HullResult`; ``status == 'infeasible'`` when HiGHS found a working set infeasible (the caller
    proves emptiness with :func:`chebyshev`). Every endpoint is a safe dual bound (module docstring),
    evaluated around ``center`` and then once more over the box just found, clipped to the prior.

    lp_options : HiGHS options of the LP models over :data:`PRIMAL_SIMPLEX` (e.g. ``{"simplex_strategy": 1}``,
    the dual simplex: faster on the signed hull's warm-started rounds, :mod:`ident.estimators.uncertain_signed`).

    Budgets and fallbacks: every solve runs under the per-solve budgets of
    :class:`~ident.numerics.lp.LPModel` (``lp_budget``: its ``iteration_limit``, ``time_limit``; default from
    the model's size). An LP whose solve stops at the budget (after the cold retry) is not solved again; its
    endpoint is the best safe bound of the duals HiGHS held at the limit, those of its last optimal solve on
    fewer rows (an earlier re-solve or round) and the prior: never narrower than the exact hull, and listed in
    ``info['lp_fallback_endpoints']`` (LP j < p: the lower endpoint of parameter j; p + j: its upper). An LP
    that HiGHS cannot solve at all (:class:`LPError`) keeps its endpoint the same way and is listed in
    ``info['lp_failures']`` (a model it rejects also sets ``info['lp_error']``, the message). ``info`` also
    carries the model's counters ``lp_solves``, ``lp_iterations``, ``lp_limit_hits``, ``lp_retries``,
    ``lp_fallbacks`` (:meth:`~ident.numerics.lp.LPModel.counters`). ``warm`` holds the final working set and
    each LP's last optimal basis (:class:`HullWarm`). ``lps``: solve these of the 2p LPs only (LP j < p: the
    lower endpoint of parameter j, p + j its upper); the others keep the prior's endpoint
    (:mod:`ident.estimators.hull_split` runs the minima and the maxima as two such halves).
    """
    t0 = time.perf_counter()
    n_rows, p = W.shape
    prior_lo = np.asarray(prior_lo, float)
    prior_hi = np.asarray(prior_hi, float)
    half = 0.5 * bu - 0.5 * bl
    mid = 0.5 * bl + 0.5 * bu
    unit = half if scale is None else np.asarray(scale, float)
    size = unit if row_scale is None else np.asarray(row_scale, float)

    theta0 = 0.5 * (prior_lo + prior_hi) if center is None else np.asarray(center, float)
    theta0 = np.clip(np.where(np.isfinite(theta0), theta0, 0.5 * (prior_lo + prior_hi)), prior_lo, prior_hi)
    m0 = mid - _matvec(W, theta0)  # strip centres in the shifted coordinates (float: steers the LPs only)
    d = column_scale(W, power2_scale(size))
    rho = (half + violation_tol * unit - np.abs(m0)) / (_row_norms(W, d) + 1e-300)  # critical radii
    initial_rows, add_rows = max(initial_rows, 4 * p), max(add_rows, p)  # many parameters: more rows at once
    pool_entries = POOL_ENTRIES if pool_entries is None else int(pool_entries)
    near = _near_rows(rho, max(pool_rows, initial_rows, pool_entries // max(p, 1)))
    first = np.arange(n_rows) if n_rows <= ALL_ROWS_UP_TO else np.union1d(near[:initial_rows],
                                                                         _spread_rows(n_rows, 2 * p))
    n_lp = 2 * p
    bases: list = [None] * n_lp
    if usable(warm, n_rows, n_lp, ALL_ROWS_UP_TO):
        first, bases = tight_rows(warm)
    costs = np.zeros((n_lp, p))
    costs[np.arange(p), np.arange(p)] = 1.0  # LP i: min theta_i
    costs[p + np.arange(p), np.arange(p)] = -1.0  # LP p + i: min -theta_i = -max theta_i
    x_sol = np.repeat(theta0[:, None], n_lp, axis=1)
    dx_sol = np.zeros((p, n_lp))
    duals: list = [(first[:0], np.zeros(0))] * n_lp  # LP j's last optimal duals (valid for LP j in any round)
    extra: list = []  # further dual guesses (j, rows, y) of LPs that fell back
    failures: list[int] = []
    fell_back: list[int] = []
    final: list = [None] * n_lp  # LP j's basis after its last optimal solve (for a later warm start)
    lp_error, model, ws, rounds, infeasible = None, None, None, 0, False
    todo = list(range(p)) + [p + i for i in reversed(range(p))]  # minima, then maxima in reverse: close optima
    if lps is not None:  # some of the LPs only (the others' endpoints stay at the prior)
        todo = [j for j in todo if j in set(int(i) for i in lps)]
    try:
        model = LPModel(prior_lo, prior_hi, center=theta0, col_scale=d, tolerance=lp_tol,
                        dual_after_rows=DUAL_AFTER_ROWS, **{**PRIMAL_SIMPLEX, **(lp_options or {})},
                        **(lp_budget or {}))
        ws = _WorkingSet(W, m0, half, unit, size, d, near, rho[near], model)
        ws.add(first)
        while todo and rounds < max_rounds and not infeasible:
            rounds += 1
            solved = []
            for j in todo:
                if bases[j] is not None:  # this LP's basis of the warm start (used once)
                    model.set_basis_status(*bases[j])
                    bases[j] = None
                sol, rows, earlier = ws.solve(costs[j], max_rounds, violation_tol, add_rows)
                if sol is None or sol.status == "limit":  # not solved: coarser safe guesses (module docstring)
                    (failures if sol is None else fell_back).append(int(j))
                    extra.extend(_fallback_guesses(j, sol, rows, earlier))
                    continue
                if sol.status == "infeasible":
                    infeasible = True
                    break
                dx_sol[:, j], x_sol[:, j] = sol.z, sol.x
                nz = sol.duals != 0.0  # duals of the original rows for the original cost +-e_i (any y is valid)
                duals[j] = (rows[nz], sol.duals[nz])
                final[j] = model.basis_status() if rows.size == ws.idx.size else None
                solved.append(j)
            todo = []
            if not infeasible and solved:  # full check of the solutions just computed against all N rows
                check_lps = np.array(solved)
                new = ws.full_check(dx_sol[:, check_lps], violation_tol, add_rows)
                todo = [int(j) for j, rows in zip(check_lps, new) if rows.size]
    except LPError as exc:  # a model HiGHS rejects: the endpoints solved so far keep their (valid) duals
        lp_error = str(exc)
        infeasible = False
        failures.extend(j for j in range(n_lp) if duals[j][0].size == 0 and j not in failures + fell_back)

    if infeasible:
        lower, upper = prior_lo.copy(), prior_hi.copy()
    else:
        lower, upper = _safe_endpoints(W, bl, bu, costs, duals, theta0, prior_lo, prior_hi, extra)
    info = {
        **(model.counters() if model is not None else dict.fromkeys(COUNTERS, 0)),
        "working_rows": 0 if ws is None else int(ws.idx.size),
        "rounds": rounds,
        "lp_failures": sorted(set(failures)),
        "lp_fallback_endpoints": sorted(set(fell_back)),
        "converged": not todo and lp_error is None and not failures and not fell_back,
        "seconds": time.perf_counter() - t0,
    }
    if lp_error is not None:
        info["lp_error"] = lp_error
    warm_out = None if ws is None or infeasible else HullWarm(rows=ws.idx.copy(), bases=final)
    return HullResult(lower=lower, upper=upper, status="infeasible" if infeasible else "ok", info=info, points=x_sol,
                      warm=warm_out)
