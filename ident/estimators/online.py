"""Online guaranteed estimation: the exact hull updated as rows stream in.

The feasible set after N rows, ``S_N = {theta in Q : |y_k - W_k theta| <= b_k, k <= N}``, only shrinks as rows
arrive. :class:`OnlineHull` keeps, for each of the 2p endpoints ``min / max theta_i``, one small HiGHS model
holding the rows that endpoint needed so far (its working set) and that model's optimal basis. On
:meth:`OnlineHull.update`:

1. the 2p current optimal points are checked against the new rows (one small matrix product);
2. an endpoint whose point satisfies every new row **stays optimal** (its point is still feasible for the
   smaller set and no point of the smaller set can do better), and its safe bound stays valid (a bound for a
   larger set);
3. the other endpoints get their violated new rows added to their own model and are re-solved from their
   previous optimal basis (dual simplex: few iterations); their new points are checked against all rows seen
   so far (constraint generation, as :func:`ident.estimators.hull.interval_hull`), the worst violated rows are added and
   the LPs re-solved until no row is violated by more than ``violation_tol`` times its half-width.

Every endpoint returned is a Neumaier-Shcherbina safe bound of its model's LP (rows outward rounded, duals
mapped back to the original data), hence a rigorous bound for ``S_N`` whatever the LP tolerances; the box is
also intersected with the previous one (both enclose ``S_N``), so it never grows. After the last update the box
equals the batch hull of the same rows to the LP tolerance (same convergence test). One model per endpoint
(rather than one shared model with switched bases) keeps each re-solve a plain warm start of the model that
was optimal for that objective; the working sets are a few hundred rows, so memory stays small.

When a model becomes infeasible, or the safe bounds of two endpoints cross (``lower_i > upper_i``, itself a
proof that the rows seen are inconsistent), the verdict is the batch estimator's: a Chebyshev LP over all rows
seen decides (:func:`ident.estimators.chebyshev.chebyshev`); if the emptiness is proven,
:class:`~ident.InconsistentDataError` is raised and **the rejected block is dropped**: the object is left exactly as before the update (rows seen,
box, working sets; the HiGHS models that had taken rows of the block are rebuilt from their working sets), so
later consistent blocks can still be added. If it is not proven (the set is thinner than the LP tolerance),
the box of the batch :func:`ident.estimate` on all rows seen is returned (it encloses a slightly inflated set)
and ``info['fallback'] = 'batch'``.

Scaling (as :func:`ident.estimators.hull.interval_hull`): each model sees ``(theta - c_j) / d`` with ``c_j`` the
midpoint of the box when the model is made (the shift keeps the row bounds of the size of the strips,
however narrow), rows scaled by the power of two nearest the inverse of their half-width, and the column
scale ``d`` of the first block after that row scaling; each model's cost is ``+-1`` on its scaled column (the
duals are mapped back with ``d_i``). A model is rebuilt around the current box's midpoint when the box has
shrunk below 1e-5 of the model's distance to it (narrow strips: its row bounds would be beyond the LP's
precision), and once more when HiGHS cannot solve or rejects it; if that fails too, its endpoint keeps its
previous (valid) bound.
"""

from __future__ import annotations

import time

import numpy as np

from h4bench.ident.errors import InconsistentDataError
from h4bench.ident.estimators.checks import check_finite, check_prior, real_array
from h4bench.ident.estimators.estimate import estimate
from h4bench.ident.estimators.hull import strip_bounds
from h4bench.ident.numerics.lp import LPError, LPModel, column_scale, power2_scale
from h4bench.ident.numerics.safe_bound import shifted_safe_bound
from h4bench.ident.box import Box

__all__ = ["OnlineHull"]



class OnlineHull:
    """Exact interval hull of the bounded-error feasible set, updated row block by row block.

    prior : :class:`~ident.Box` or (lower, upper) finite arrays; p : number of parameters (checked against the
    prior; taken from it when omitted); lp_tol : HiGHS tolerances; violation_tol : a row counts as violated
    when off by more than this fraction of its half-width (tightness only); add_rows : rows added per
    endpoint per round of constraint generation.

    Use ``box = hull.update(W_rows, y_rows, bound_rows)`` for each block; ``hull.box`` is the current box.
    """

    def __init__(self, prior, p: int | None = None, *, lp_tol: float = 1e-9, violation_tol: float = 1e-10,
                 add_rows: int = 10) -> None:
        if p is None:
            if isinstance(prior, Box):
                p = len(prior)
            elif isinstance(prior, (tuple, list)) and len(prior) == 2:
                p = int(np.size(prior[0]))
            else:
                raise TypeError(f"prior must be a Box or a (lower, upper) pair, got {type(prior).__name__}")
        if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
            raise ValueError(f"p must be an integer >= 1 (number of parameters), got {p!r}")
        self.p = int(p)
        self._lo, self._hi, self.names = check_prior(prior, self.p)
        for name, val in (("lp_tol", lp_tol), ("violation_tol", violation_tol)):
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not (np.isfinite(val) and val > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {val!r}")
        if isinstance(add_rows, bool) or not isinstance(add_rows, (int, np.integer)) or add_rows < 1:
            raise ValueError(f"add_rows must be an integer >= 1, got {add_rows!r}")
        self.lp_tol, self.violation_tol, self.add_rows = float(lp_tol), float(violation_tol), int(add_rows)
        self.max_rounds = 200  # rounds of constraint generation per update (each adds rows; a safety stop)
        p = self.p
        cap = 1024
        self._W = np.empty((cap, p))
        self._y = np.empty(cap)
        self._b = np.empty(cap)
        self._bl = np.empty(cap)
        self._bu = np.empty(cap)
        self._n = 0
        self._d: np.ndarray | None = None  # column scale, fixed at the first rows
        self._models: list[LPModel | None] = [None] * (2 * p)
        self._x0 = np.zeros((p, 2 * p))  # each model's origin (its shift), set when the model is made
        self._ws: list[list[int]] = [[] for _ in range(2 * p)]  # working-set rows, in model order
        self._in_ws = [np.zeros(cap, dtype=bool) for _ in range(2 * p)]
        # current optimal points (columns): min theta_i at the prior's lower corner in i, centre elsewhere
        centre = 0.5 * self._lo + 0.5 * self._hi
        self._x = np.repeat(centre[:, None], 2 * p, axis=1)
        for i in range(p):
            self._x[i, i] = self._lo[i]
            self._x[i, p + i] = self._hi[i]
        self._lower = self._lo.copy()
        self._upper = self._hi.copy()
        self._duals: list[np.ndarray | None] = [None] * (2 * p)
        self.stats = {"updates": 0, "resolved_endpoints": 0, "lp_solves": 0, "lp_iterations": 0, "lp_limit_hits": 0,
                      "lp_retries": 0, "lp_fallbacks": 0}

    # ------------------------------------------------------------------------------------------ state
    @property
    def rows_seen(self) -> int:
        return self._n

    @property
    def box(self) -> Box:
        return Box(self._lower.copy(), self._upper.copy(), self.names, info={"rows": self._n, **self.stats})

    def _grow(self, extra: int) -> None:
        need = self._n + extra
        cap = self._W.shape[0]
        if need <= cap:
            return
        new = max(need, 2 * cap)
        for name in ("_W", "_y", "_b", "_bl", "_bu"):
            old = getattr(self, name)
            arr = np.empty((new,) + old.shape[1:])
            arr[: self._n] = old[: self._n]
            setattr(self, name, arr)
        self._in_ws = [np.concatenate([m, np.zeros(new - cap, dtype=bool)]) for m in self._in_ws]

    def _cost(self, j: int) -> np.ndarray:
        c = np.zeros(self.p)
        c[j % self.p] = 1.0 if j < self.p else -1.0
        return c

    def _model(self, j: int) -> LPModel:
        """Model j, made (around the current box's midpoint, with its working-set rows) when missing."""
        if self._models[j] is None:
            x0 = np.clip(0.5 * self._lower + 0.5 * self._upper, self._lo, self._hi)
            # dual simplex: new rows keep the basis dual feasible
            h = LPModel(self._lo, self._hi, center=x0, col_scale=self._d, tolerance=self.lp_tol, simplex_strategy=1)
            # HiGHS sees the cost +-1 on the scaled column (not +-d_i, which is tiny when the strips are narrow
            # and would fall below HiGHS's dual tolerance); the model maps the duals back
            h.set_cost(self._cost(j))
            self._x0[:, j] = x0
            self._models[j] = h
            if self._ws[j]:
                self._add_model_rows(j, np.asarray(self._ws[j], dtype=np.int64))
        return self._models[j]

    def _add_model_rows(self, j: int, rows: np.ndarray) -> None:
        half = 0.5 * self._bu[rows] - 0.5 * self._bl[rows]  # each row in units of its half-width
        self._models[j].add_rows(self._W[rows], self._bl[rows], self._bu[rows], half)

    def _add(self, j: int, rows: np.ndarray) -> None:
        rows = rows[~self._in_ws[j][rows]]
        if rows.size == 0:
            return
        self._model(j)
        self._add_model_rows(j, rows)
        self._in_ws[j][rows] = True
        self._ws[j].extend(rows.tolist())

    # ------------------------------------------------------------------------------------------ update
    def update(self, W_rows, y_rows, bound_rows) -> Box:
        """Add rows ``|y_k - W_k theta| <= bound_k`` and return the updated rigorous box.

        W_rows : (k, p); y_rows : (k,); bound_rows : scalar or (k,) positive. Returns a :class:`~ident.Box`
        with ``info``: ``rows`` (seen so far), ``resolved`` (endpoints re-solved by this update), ``seconds``.
        Raises :class:`~ident.InconsistentDataError` when the rows seen so far are proven inconsistent.
        """
        t0 = time.perf_counter()
        W = real_array(W_rows, "W_rows")
        if W.ndim == 1 and W.size == self.p:
            W = W[None, :]
        if W.ndim != 2 or W.shape[1] != self.p:
            raise ValueError(f"W_rows must have shape (k, {self.p}), got {W.shape}")
        k = W.shape[0]
        y = np.atleast_1d(real_array(y_rows, "y_rows"))
        if y.shape != (k,):
            raise ValueError(f"y_rows must have shape ({k},) to match W_rows, got {y.shape}")
        b = real_array(bound_rows, "bound_rows")
        b = np.full(k, float(b)) if b.ndim == 0 else b
        if b.shape != (k,):
            raise ValueError(f"bound_rows must be a scalar or have shape ({k},), got {b.shape}")
        check_finite(W, "W_rows")
        check_finite(y, "y_rows")
        if not np.all(np.isfinite(b) & (b > 0)):
            raise ValueError("bound_rows must be finite and > 0 in every row")
        if k == 0:
            return self.box
        snapshot = self._snapshot()
        try:
            return self._update(W, y, b, t0)
        except InconsistentDataError:
            self._restore(snapshot)  # the rejected block leaves no trace
            raise

    def _snapshot(self) -> dict:
        return {"n": self._n, "lower": self._lower.copy(), "upper": self._upper.copy(), "x": self._x.copy(),
                "duals": list(self._duals), "ws": [len(w) for w in self._ws], "d": self._d,
                "stats": dict(self.stats)}

    def _restore(self, snap: dict) -> None:
        n = snap["n"]
        self._n, self._d = n, snap["d"]
        self._lower, self._upper, self._x = snap["lower"], snap["upper"], snap["x"]
        self._duals = snap["duals"]
        self.stats = snap["stats"]
        for j, length in enumerate(snap["ws"]):
            if len(self._ws[j]) != length:
                self._in_ws[j][self._ws[j][length:]] = False
                del self._ws[j][length:]
                self._models[j] = None  # rebuilt from its working set when next needed
                self._duals[j] = None
        for m in self._in_ws:
            m[n:] = False

    def _update(self, W, y, b, t0) -> Box:
        k = W.shape[0]
        self._grow(k)
        s, e = self._n, self._n + k
        self._W[s:e], self._y[s:e], self._b[s:e] = W, y, b
        self._bl[s:e], self._bu[s:e] = strip_bounds(y, b)
        self._n = e
        if self._d is None:
            self._d = column_scale(W, power2_scale(b))  # columns of the row-scaled block (units-invariant)
        # 1. which endpoints does a new row cut off?
        new = np.arange(s, e)
        viol = self._violation(new, self._x)
        todo = {int(j): new[viol[:, j] > self.violation_tol] for j in np.flatnonzero((viol > self.violation_tol).any(axis=0))}
        resolved = sorted(todo)
        self.stats["updates"] += 1
        self.stats["resolved_endpoints"] += len(resolved)
        fallback = None
        # 2. re-solve them, with constraint generation against all rows seen
        first = True
        failed: set[int] = set()  # endpoints HiGHS could not solve: they keep their previous (valid) bound
        for _ in range(self.max_rounds):
            if not todo:
                break
            for j, rows in todo.items():
                if not first and rows.size > self.add_rows:  # new rows go in at once; older ones the worst first
                    rows = rows[np.argsort(-self._violation(rows, self._x[:, [j]])[:, 0], kind="stable")[: self.add_rows]]
                status = self._add_and_solve(j, rows)
                if status == "infeasible":
                    fallback = self._infeasible()
                    break
                if status in ("failed", "limit"):  # not solved again in this update: its bound stays valid
                    failed.add(j)
            if fallback is not None:
                break
            first = False
            todo = {j: r for j, r in todo.items() if j not in failed}
            if not todo:
                break
            cols = np.array(sorted(todo))
            v = self._violation(np.arange(self._n), self._x[:, cols])
            todo = {}
            for c, j in enumerate(cols):
                bad = np.flatnonzero((v[:, c] > self.violation_tol) & ~self._in_ws[j][: self._n])
                if bad.size:
                    todo[int(j)] = bad
        if fallback is None:
            box_lo, box_hi = self._lower.copy(), self._upper.copy()  # encloses the set before this block
            for j in resolved:
                self._bound(j, box_lo, box_hi)
            if np.any(self._lower > self._upper):  # crossing safe bounds: the rows seen are inconsistent
                fallback = self._infeasible()
        if fallback is not None:
            lower, upper = fallback
            self._lower = np.maximum(self._lower, lower)
            self._upper = np.minimum(self._upper, upper)
        box = self.box
        box.info.update({"resolved": resolved, "seconds": time.perf_counter() - t0, "lp_failures": sorted(failed)})
        if fallback is not None:
            box.info["fallback"] = "batch"
        return box

    def _violation(self, rows: np.ndarray, x_cols: np.ndarray) -> np.ndarray:
        """``|W_k x - mid_k| / half_k - 1`` (> 0: violated) for rows k and each column x (float heuristic).

        Where the value is positive it is reduced by a bound of its own rounding error (``|W_k| |x| + |mid|``
        times 2^-50, relative to the half-width), so that narrow strips are not reported violated by rounding."""
        mid = 0.5 * self._bl[rows] + 0.5 * self._bu[rows]
        half = 0.5 * self._bu[rows] - 0.5 * self._bl[rows]
        Wr = self._W[rows]
        v = np.abs(Wr @ x_cols - mid[:, None]) / half[:, None] - 1.0
        hit = np.flatnonzero((v > self.violation_tol).any(axis=1))
        if hit.size:
            err = (np.abs(Wr[hit]) @ np.abs(x_cols) + np.abs(mid[hit, None])) * 2.0**-50 / half[hit, None]
            v[hit] -= err
        return v

    def _add_and_solve(self, j: int, rows: np.ndarray) -> str:
        """Add rows to model j and re-solve; a model HiGHS rejects or cannot solve is rebuilt once around the
        current box's midpoint. Returns 'ok', 'infeasible', 'failed' or 'limit' (:meth:`_solve`; not rebuilt)."""
        if self._models[j] is not None:
            # the box has shrunk to 1e-5 of this model's distance to it: re-centre the model (its
            # row bounds would otherwise be huge in units of the strips, beyond the LP's precision)
            width = self._upper - self._lower
            off = np.abs(self._x0[:, j] - (0.5 * self._lower + 0.5 * self._upper))
            if np.any(off > 1e5 * width + 1e-300):
                self._models[j] = None
                self._duals[j] = None
        for attempt in range(2):
            try:
                self._add(j, rows)
                status = self._solve(j)
            except LPError:
                status = "failed"
            if status != "failed" or attempt:
                return status
            self._models[j] = None  # rebuilt (with all its working-set rows) by the next _add/_model
            self._duals[j] = None
            rows = rows[:0]
        return status

    def _solve(self, j: int) -> str:
        """Solve model j: 'ok', 'infeasible', 'failed' (HiGHS could not: the endpoint keeps its bound) or 'limit'
        (stopped at the per-solve budget: the duals HiGHS held give the endpoint a coarser safe bound)."""
        h = self._model(j)
        self._duals[j] = None  # until this solve gives duals for the model's current rows
        before = h.counters()
        try:
            sol = h.solve()
        except LPError:
            sol = None  # the previous (valid) bound of this endpoint stays
        for key, value in h.counters().items():
            self.stats[key] += value - before[key]
        if sol is None:
            return "failed"
        if sol.status == "infeasible":
            return "infeasible"
        if sol.status == "limit":
            self._duals[j] = sol.duals if sol.dual_valid else None  # any duals give a valid bound
            return "limit"
        self._x[:, j] = np.clip(sol.x, self._lo, self._hi)
        self._duals[j] = sol.duals  # of the unscaled rows for the cost +-e_i
        return "ok"

    def _bound(self, j: int, box_lo: np.ndarray, box_hi: np.ndarray) -> None:
        """Tighten endpoint j by the safe bound of its model's last duals (any duals give a valid bound), over
        the box ``[box_lo, box_hi]`` that encloses the set before this block (hence after it)."""
        rd = self._duals[j]
        if rd is None or np.any(box_lo > box_hi):
            return
        ws = np.asarray(self._ws[j], dtype=np.int64)
        yd = rd  # duals of the unscaled rows for the cost +-e_i: y_k = d_i r_k y'_k (LPModel.solve)
        nz = yd != 0.0
        rows = ws[nz]
        mu = shifted_safe_bound(self._W[rows], self._bl[rows], self._bu[rows], box_lo, box_hi, self._cost(j), yd[nz],
                                self._x0[:, j])
        i = j % self.p
        if j < self.p:
            self._lower[i] = max(self._lower[i], mu)
        else:
            self._upper[i] = min(self._upper[i], -mu)

    def _infeasible(self):
        """The rows seen look inconsistent: the batch estimator's verdict on all of them (raises
        :class:`~ident.InconsistentDataError` when proven; else the batch box of a slightly inflated set)."""
        n = self._n
        W, y, b = self._W[:n], self._y[:n], self._b[:n]
        box = estimate(W, y, b, (self._lo, self._hi))
        return np.array(box.lower), np.array(box.upper)
