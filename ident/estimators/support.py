"""Rigorous support function of the feasible polytope, by warm-started LPs on a working set of rows.

The feasible set is ``S = {theta in B : y_k - b_k <= W_k theta <= y_k + b_k, k = 1..N}`` with ``B`` a finite box
that contains it (the prior, or a hull of S). :class:`SupportLP` answers ``min c^T theta`` over S for many costs
``c`` (the edges of a projection, the torques of a prediction) with one HiGHS model
(:class:`ident.numerics.lp.LPModel`, warm-started from the previous basis):

* **working set** (constraint generation): the model holds the rows nearest the boundary at a centre plus
  spread rows; after each solve the solution is checked against all N rows (one blocked pass) and the worst
  violated rows are added and the LP re-solved, until no row is off its strip by more than
  ``violation_tol * b_k``. The LPs stay a few hundred rows however large N is;
* **safe bounds**: the returned value is the Neumaier-Shcherbina bound (Neumaier & Shcherbina, Math.
  Program. 99, 2004; :class:`ident.numerics.safe_bound.SafeBound`) of the working-set LP, with its row duals, evaluated
  on the original data around the centre and over ``B``. A working set has fewer rows than S, so its LP's
  minimum is at most the minimum over S: the bound is rigorous whatever the tolerances and however many rows
  are still missing; the tolerances only decide its tightness. An LP HiGHS cannot solve, or that stops at its
  per-solve budget (:class:`ident.numerics.lp.LPModel`), gives the best of the interval bound of ``c^T theta``
  over ``B`` and the safe bounds of the duals at hand (HiGHS's at the limit, an earlier solve's on fewer rows).

The row bounds ``y -+ b`` are rounded outward (:func:`ident.estimators.hull.strip_bounds`); HiGHS sees the model
shifted to the centre and scaled by powers of two (rows by their bound, then columns), as in the hull.
"""

from __future__ import annotations

import time

import numpy as np

from h4bench.portable import largest
from h4bench.ident.estimators.hull import PRIMAL_SIMPLEX, strip_bounds
from h4bench.ident.numerics.interval import mul, sum_down
from h4bench.ident.numerics.lp import LPError, LPModel, column_scale, power2_scale
from h4bench.ident.numerics.safe_bound import SafeBound

__all__ = ["SupportLP"]

_CHUNK = 8192


def _box_lower(c, lower, upper) -> float:
    """Rigorous lower bound of ``c^T theta`` over the box ``[lower, upper]`` (interval evaluation)."""
    lo, _ = mul(c, c, lower, upper)
    return float(sum_down(lo))


class SupportLP:
    """``min / max c^T theta`` over ``S = {theta in [lower, upper] : |y - W theta| <= bound}``, rigorously.

    Parameters
    ----------
    W : (N, p) regressor; y : (N,) measurements (units of y); bound : scalar or (N,) > 0 (units of y).
    lower, upper : (p,) a finite box containing S (the prior or a hull of S).
    center : (p,) a point near the middle of S, the LPs' origin (default least squares, clipped to the box).
    initial_rows : rows of the first working set (the nearest the boundary at the centre, plus 2p spread rows).
    add_rows : violated rows added per round; violation_tol : a row is violated when off its strip by more than
    ``violation_tol * b_k``; lp_tol : HiGHS's feasibility tolerance; max_rounds : re-solves per cost.

    Attributes ``solves``, ``failures`` (LPs without usable duals), ``seconds`` (time in :meth:`minimize`),
    ``infeasible`` (HiGHS found the working set infeasible: S is then probably empty, and every bound returned
    is the box's interval bound; emptiness is proven by :func:`ident.min_consistent_bound`, not here).
    """

    def __init__(self, W, y, bound, lower, upper, *, center=None, initial_rows: int = 200, add_rows: int = 20,
                 violation_tol: float = 1e-9, lp_tol: float = 1e-9, max_rounds: int = 50) -> None:
        W, y = np.asarray(W, dtype=float), np.asarray(y, dtype=float)
        if W.ndim != 2 or y.shape != (W.shape[0],):
            raise ValueError(f"W must be (N, p) and y (N,), got W {W.shape} and y {y.shape}")
        n, p = W.shape
        b = np.broadcast_to(np.asarray(bound, dtype=float), (n,))
        if not np.all(np.isfinite(b)) or np.any(b <= 0):
            raise ValueError("bound must be finite and > 0")
        lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        if lower.shape != (p,) or upper.shape != (p,) or not (np.all(np.isfinite(lower))
                                                              and np.all(np.isfinite(upper))):
            raise ValueError(f"lower and upper must be finite ({p},) arrays, got {lower.shape} and {upper.shape}")
        if np.any(lower > upper):
            raise ValueError("lower must be <= upper")
        self.W, self.b, self.lower, self.upper = W, np.ascontiguousarray(b), lower, upper
        self.bl, self.bu = strip_bounds(y, self.b)
        if center is None:  # weighted least squares (rows scaled by their bound), or the box's midpoint
            center = np.linalg.lstsq(W * (1.0 / self.b)[:, None], y / self.b, rcond=None)[0] if n \
                else 0.5 * (lower + upper)
        c0 = np.asarray(center, dtype=float)
        self.center = np.clip(np.where(np.isfinite(c0), c0, 0.5 * (lower + upper)), lower, upper)
        self.m0 = (0.5 * self.bl + 0.5 * self.bu) - W @ self.center  # strip centres, shifted (float: steers only)
        self.half = 0.5 * self.bu - 0.5 * self.bl
        self.add_rows, self.violation_tol, self.max_rounds = int(add_rows), float(violation_tol), int(max_rounds)
        self.solves = self.failures = 0
        self.seconds = 0.0
        self.infeasible = False
        self.model = LPModel(lower, upper, center=self.center, col_scale=column_scale(W, power2_scale(self.b)),
                             tolerance=lp_tol, **PRIMAL_SIMPLEX)
        self.mask = np.zeros(n, dtype=bool)
        self.idx = np.zeros(0, dtype=np.int64)
        if n:
            dist = (np.abs(self.m0) - self.half) / (np.sqrt(np.einsum("ij,ij->i", W, W)) + 1e-300)
            k = min(n, int(initial_rows))
            first = largest(dist, k)
            spread = np.unique(np.linspace(0, n - 1, min(n, 2 * p)).round().astype(np.int64))
            self._add(np.union1d(first, spread))

    def _add(self, rows) -> None:
        rows = np.asarray(rows, dtype=np.int64)
        self.model.add_shifted_rows(self.W[rows], self.m0[rows] - self.half[rows], self.m0[rows] + self.half[rows],
                                    self.b[rows])
        self.mask[rows] = True
        self.idx = np.concatenate([self.idx, rows])

    def _violated(self, z) -> np.ndarray:
        """Rows not in the model whose strip ``z`` (shifted) leaves by more than the tolerance, worst first."""
        n = self.W.shape[0]
        viol = np.empty(n)
        for s in range(0, n, _CHUNK):
            e = min(n, s + _CHUNK)
            viol[s:e] = (np.abs(self.W[s:e] @ z - self.m0[s:e]) - self.half[s:e]) / self.b[s:e]
        viol[self.mask] = -np.inf
        bad = np.flatnonzero(viol > self.violation_tol)
        if bad.size > self.add_rows:
            bad = bad[largest(viol[bad], self.add_rows)]
        return bad

    def minimize(self, c) -> tuple[float, np.ndarray | None]:
        """A rigorous lower bound of ``min c^T theta`` over S and the LP's minimiser (float, feasible to the
        tolerances; None when HiGHS gave no solution). c : (p,) finite, not zero."""
        t0 = time.perf_counter()
        c = np.asarray(c, dtype=float)
        fallback = _box_lower(c, self.lower, self.upper)
        if not np.any(c * self.model.d) or self.infeasible:
            self.seconds += time.perf_counter() - t0
            return fallback, None
        sol, rows, guesses = None, self.idx, []  # guesses: (rows, duals) of the optimal solves on fewer rows
        try:
            for r in range(self.max_rounds):
                sol, rows = self.model.solve(c if r == 0 else None), self.idx
                self.solves += 1
                if sol.status == "infeasible":
                    self.infeasible = True
                    self.seconds += time.perf_counter() - t0
                    return fallback, None
                if sol.status == "limit":  # stopped at the per-solve budget: a coarser safe bound
                    break
                new = self._violated(sol.z)
                if new.size == 0:
                    break
                guesses = [(rows, sol.duals)] if sol.dual_valid else guesses
                self._add(new)
        except LPError:
            sol = None
        ok = sol is not None and sol.status == "optimal" and sol.dual_valid
        if ok:
            guesses = [(rows, sol.duals)]  # the optimum's duals: the tight guess
        elif sol is not None and sol.dual_valid:
            guesses.append((rows, sol.duals))  # a limit's duals beside the earlier solve's: the better one counts
        if not ok:
            self.failures += 1
        mu = max([fallback] + [self._safe(c, r, yd) for r, yd in guesses])
        self.seconds += time.perf_counter() - t0
        return mu, sol.x if ok else None

    def _safe(self, c, rows, duals) -> float:
        """The safe lower bound of ``min c^T theta`` for the dual guess ``duals`` of the model's rows ``rows``."""
        nz = duals != 0.0
        r = rows[nz]
        return SafeBound(self.W[r], self.bl[r], self.bu[r], c, duals[nz], self.center).over(self.lower, self.upper)

    def maximize(self, c) -> tuple[float, np.ndarray | None]:
        """A rigorous upper bound of ``max c^T theta`` over S and the LP's maximiser (see :meth:`minimize`)."""
        mu, x = self.minimize(-np.asarray(c, dtype=float))
        return -mu, x

    def ranges(self, C) -> tuple[np.ndarray, np.ndarray]:
        """Rigorous ``[min, max]`` of ``C_k theta`` over S for each row of C (k, p): ``(lo (k,), hi (k,))``."""
        C = np.asarray(C, dtype=float)
        lo, hi = np.empty(C.shape[0]), np.empty(C.shape[0])
        for k in range(C.shape[0]):
            lo[k] = self.minimize(C[k])[0]
            hi[k] = self.maximize(C[k])[0]
        return lo, hi
