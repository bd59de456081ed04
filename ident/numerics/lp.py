"""The one place where HiGHS models are made: silent from the start, every call's status checked.

* **No solver output on stdout.** HiGHS writes its banner ("Running HiGHS x.y.z ...") from C to file
  descriptor 1 inside the constructor of the *first* ``highspy.Highs()`` of a process (measured with highspy
  1.16: once per process, at construction, before any option can be set; later constructions print
  nothing, and ``output_flag = False`` silences every solve). :func:`new_highs` therefore constructs the
  first model of the process with file descriptor 1 pointed at ``os.devnull`` (Python's and C's stdout
  buffers flushed before and after), under a lock, so that two threads never interleave the redirection;
  a thread that writes to file descriptor 1 during that single construction (microseconds) loses that
  write. Every later model is constructed without any redirection.
* **Every status is checked.** ``addVars``/``addRows``/``changeColsCost``/``setOptionValue`` return a
  ``HighsStatus``; an error (e.g. ``addRows`` rejects a whole block when an entry is ``>= 1e15`` in
  magnitude, leaving the model without those rows) raises :class:`LPError`. Callers turn it into a rigorous
  fallback (a coarser safe bound or the prior), never into a tighter box.
* **One LP core.** :class:`LPModel` is the one HiGHS model of every linear program of the project (the
  hull's 2p LPs and the Chebyshev fit, the Oettli-Prager LP, the online models, the big-M MILP and the
  branch-and-bound LP, the prediction envelope, the half-width LPs of the experiment design): rows added in
  dense or sparse blocks (constraint generation appends), column bounds, costs, warm-started re-solves, every
  status checked, the scaling done once (a shift to a centre, rows by powers of two nearest their size, columns
  by powers of two) and the duals returned for the original rows and cost. The safe bounds of
  :mod:`ident.numerics.safe_bound` turn any duals into a rigorous bound over a box (Neumaier & Shcherbina,
  Math. Program. 99, 2004), so neither the scaling nor the LP tolerances can affect rigour.
* **A budget per solve, never stuck.** Every HiGHS run of :meth:`LPModel.solve` has a simplex iteration limit
  and a wall-time limit of its own (:meth:`LPModel.budgets`: defaults from the model's size, overridable). A run
  stopped by a limit (or ending in any other non-final status) is retried once from a cold start with the dual
  simplex, under the same budget; if that one stops too, the solve returns the status ``'limit'`` with the
  duals HiGHS holds (those of the dual simplex, dual feasible once in its phase 2; any duals give a valid safe
  bound), and the caller falls back to a coarser safe bound. HiGHS's ``time_limit`` counts the run time of the
  whole ``Highs`` object (once reached, every later run stops at once: measured with highspy 1.16), so it is
  re-armed before each run to the object's run time so far plus the budget (:func:`arm_time_limit`). The model
  counts ``solves`` (HiGHS runs), ``iterations``, ``limit_hits`` (runs stopped by a limit), ``retries`` (cold
  re-runs) and ``fallbacks`` (solves that returned ``'limit'``).
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from dataclasses import dataclass

import highspy
import numpy as np

from h4bench.ident.errors import LPError, LPFallbackWarning
from h4bench.portable import matmul as pmatmul
from h4bench.portable import nearest_power_of_two

__all__ = [
    "BASIC",
    "LARGE_ENTRY",
    "LPError",
    "LPFallbackWarning",
    "LPModel",
    "LPSolution",
    "add_dense_rows",
    "arm_time_limit",
    "check",
    "column_scale",
    "new_highs",
    "power2_scale",
]

BASIC = highspy.HighsBasisStatus.kBasic  #: the basis status of a basic variable (a row's: its slack is basic)
LARGE_ENTRY = 1e15  # HiGHS's default large_matrix_value: addRows rejects a block holding an entry this large
_ERROR = highspy.HighsStatus.kError
_lock = threading.Lock()
_first_done = False




def check(status, what: str) -> None:
    """Raise :class:`LPError` if a HiGHS call returned ``kError`` (warnings are accepted)."""
    if status == _ERROR:
        raise LPError(f"HiGHS rejected {what} (status {status})")


def arm_time_limit(h: highspy.Highs, seconds: float) -> None:
    """Let the next ``h.run()`` take at most ``seconds`` of wall time (inf: no limit).

    HiGHS compares its ``time_limit`` option with the run time of the whole ``Highs`` object, summed over its
    runs (``getRunTime``), so a limit set once stops every run after the first ones that used it up; this sets
    it to the run time so far plus ``seconds``.
    """
    check(h.setOptionValue("time_limit", float(h.getRunTime()) + float(seconds)), f"option time_limit (+{seconds} s)")


def _flush_c_stdout() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library handle on this platform: nothing buffered to flush
        pass


def _construct_silently() -> highspy.Highs:
    """``highspy.Highs()`` with file descriptor 1 sent to ``os.devnull`` around the constructor."""
    if sys.stdout is not None:
        try:
            sys.stdout.flush()
        except (OSError, ValueError):
            pass
    _flush_c_stdout()
    try:
        saved = os.dup(1)
    except OSError:  # no file descriptor 1: nothing can reach stdout
        return highspy.Highs()
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        try:
            h = highspy.Highs()
        finally:
            _flush_c_stdout()
            os.dup2(saved, 1)
    finally:
        os.close(saved)
        os.close(devnull)
    return h


def new_highs(tolerance: float | None = None, **options) -> highspy.Highs:
    """A silent ``highspy.Highs`` (no banner, ``output_flag`` off) with the given options set and checked.

    tolerance : primal and dual feasibility tolerance (None: HiGHS's defaults); options : further HiGHS
    options by name (e.g. ``presolve="off"``, ``simplex_strategy=4``).
    """
    global _first_done
    with _lock:
        if not _first_done:
            h = _construct_silently()
            _first_done = True
        else:
            h = highspy.Highs()
    h.silent()
    check(h.setOptionValue("output_flag", False), "option output_flag")
    if tolerance is not None:
        options = {"primal_feasibility_tolerance": float(tolerance), "dual_feasibility_tolerance": float(tolerance),
                   **options}
    for name, value in options.items():
        check(h.setOptionValue(name, value), f"option {name}={value!r}")
    return h


def add_dense_rows(h: highspy.Highs, A: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    """Append the dense rows ``lo <= A x <= hi`` to ``h``; :class:`LPError` if HiGHS rejects them.

    A : (m, n); lo, hi : (m,) (may hold -inf / +inf). Rows with an entry of magnitude ``>= LARGE_ENTRY`` or a
    non-finite entry are rejected here first (HiGHS would drop the whole block).
    """
    A = np.ascontiguousarray(A, dtype=float)
    m, n = A.shape
    if m == 0:
        return
    amax = np.max(np.abs(A)) if A.size else 0.0
    if not np.isfinite(amax) or amax >= LARGE_ENTRY:
        raise LPError(f"rows with a matrix entry of magnitude {amax:.3g} (HiGHS accepts < {LARGE_ENTRY:.0e})")
    starts = np.arange(m, dtype=np.int32) * n
    index = np.tile(np.arange(n, dtype=np.int32), m)
    check(h.addRows(m, np.asarray(lo, float), np.asarray(hi, float), m * n, starts, index, A.ravel()), f"addRows ({m} rows)")


# ------------------------------------------------------------------------------------------ the LP core
_OPTIMAL = highspy.HighsModelStatus.kOptimal
_INFEASIBLE = highspy.HighsModelStatus.kInfeasible
_LIMITS = (highspy.HighsModelStatus.kIterationLimit, highspy.HighsModelStatus.kTimeLimit)
_DUAL_SIMPLEX = 1  # HiGHS's simplex_strategy of the serial dual simplex (its default)
_MAX_ITERATIONS = 2**31 - 1  # HiGHS's largest simplex_iteration_limit (its default: no limit)

#: Defaults of the per-solve budgets (:meth:`LPModel.budgets`), for each HiGHS run of a solve: at least
#: ``ITERATIONS_FLOOR`` simplex iterations, ``ITERATIONS_PER_LINE`` per row and column; at least
#: ``SECONDS_FLOOR`` seconds, ``SECONDS_PER_ENTRY`` per entry of the ``m x n`` matrix. Measured on the signed
#: Oettli-Prager hull of a 6-joint arm's certified equation (a 28 s synthetic TX40 log as in
#: tests/ident/test_serial_certified.py: 4188 rows x 61 base parameters, 3 refinements, working sets up to
#: 2 605 rows; 2 cores under a load average of 10-28): warm runs at most 767 iterations and 1.1 s, cold
#: dual-simplex runs (each solve's first run stopped on purpose) median 259 and at most 988 iterations, at most
#: 1.2 s. The defaults are 20x those; a stuck warm start (primal simplex) ran past 80 000 iterations.
ITERATIONS_FLOOR = 20_000
ITERATIONS_PER_LINE = 10
SECONDS_FLOOR = 20.0
SECONDS_PER_ENTRY = 4e-6
_CHUNK = 8192  # rows per block when scanning a matrix: temporaries stay small


def power2_scale(v: np.ndarray) -> np.ndarray:
    """Powers of two ``2^-round(log2 v)`` (1 where v is 0): multiplying by them is exact barring underflow."""
    v = np.asarray(v, dtype=float)
    if v.size > 1 and v.ndim == 1 and v[0] > 0 and np.all(v == v[0]):  # one value (a scalar bound): one log
        return np.full(v.shape, float(np.ldexp(1.0, -int(nearest_power_of_two(v[0])))))
    out = np.ones_like(v)
    pos = v > 0
    out[pos] = np.ldexp(1.0, -nearest_power_of_two(v[pos]))
    return out


def column_scale(A: np.ndarray, row_scale: np.ndarray | None = None) -> np.ndarray:
    """Power-of-two column scales bringing each column of ``diag(row_scale) A`` to a root-mean-square of about 1.

    A : (m, n); row_scale : (m,) the row factors HiGHS sees (default 1). Computed on the row-scaled matrix, so
    that the scaled model does not depend on the units of the rows nor of the columns, up to powers of two.
    One blocked pass over A. Returns (n,).
    """
    common = 1.0
    if row_scale is not None and row_scale.size and np.all(row_scale == row_scale[0]):
        common, row_scale = float(row_scale[0]), None  # one factor for all rows (a power of two): exact
    ss = np.zeros(A.shape[1])
    for s in range(0, A.shape[0], _CHUNK):
        blk = A[s : s + _CHUNK]
        if row_scale is not None:
            blk = blk * row_scale[s : s + _CHUNK, None]
        ss += np.einsum("ij,ij->j", blk, blk)
    return power2_scale(np.sqrt(ss / max(A.shape[0], 1)) * common)


@dataclass
class LPSolution:
    """One solve of :class:`LPModel`: ``status`` 'optimal', 'infeasible' or 'limit' (both runs of the solve
    stopped at the per-solve budget, :meth:`LPModel.solve`); on 'optimal', ``x`` (n,) the solution in the
    model's original coordinates (float, unverified), ``z`` (n,) the same as a shift from the centre; on
    'optimal' and 'limit', ``duals`` (m,) the row duals of the ORIGINAL (unscaled) rows for the ORIGINAL cost
    (zeros when HiGHS gives none, then ``dual_valid`` is False), usable as the dual guess of
    :class:`~ident.numerics.safe_bound.SafeBound` (at a limit: those HiGHS holds, not optimal, still a valid guess); ``iterations`` the simplex iterations of
    this solve (both runs)."""

    status: str
    x: np.ndarray | None = None
    z: np.ndarray | None = None
    duals: np.ndarray | None = None
    iterations: int = 0
    dual_valid: bool = True


class LPModel:
    """One HiGHS model of ``min c^T x  s.t.  lo <= A x <= hi, xl <= x <= xu``, scaled and shifted once.

    HiGHS sees ``z = (x - center) / d`` (``d`` powers of two, :func:`column_scale` of the row-scaled rows or
    given) and each row multiplied by a power of two ``r`` (:func:`power2_scale` of its ``row_scale``, e.g. its
    bound or half-width). Rows are added in blocks (constraint generation friendly: :meth:`add_rows` appends);
    costs change between warm-started solves (:meth:`solve`); every HiGHS status is checked (:class:`LPError`
    on any failure, never a silent value) and the row duals are returned unscaled, for the original rows and
    cost, so that :class:`~ident.numerics.safe_bound.SafeBound` on the original data turns them into a rigorous
    bound whatever the scaling (Neumaier & Shcherbina, Math. Program. 99, 2004).

    xl, xu : (n,) finite column bounds; center : (n,) the origin of HiGHS's coordinates (default the
    midpoint of the box); col_scale : (n,) powers of two (default 1, see :meth:`scale_columns`);
    tolerance : primal/dual feasibility tolerance; iteration_limit, time_limit : the per-solve budgets of each
    HiGHS run (simplex iterations, seconds of wall time; None: the defaults of :meth:`budgets`, from the model's
    size; ``math.inf``: none); warm_iteration_limit : a lower iteration limit for a solve's first run when it
    starts from a valid basis (None: the same budget): a warm start that stalls is cut there and the solve runs
    again cold, under the full budget; dual_after_rows : a solve whose only change since the last one is added rows
    runs the dual simplex (the previous basis stays dual feasible when rows are added, while the primal simplex
    restarts from an infeasible point); options : further HiGHS options (default ``presolve='off'``).
    Counters: ``solves`` (HiGHS runs), ``iterations``, ``limit_hits``, ``retries``, ``fallbacks`` (module
    docstring).
    """

    def __init__(self, xl, xu, *, center=None, col_scale=None, tolerance: float | None = 1e-9,
                 iteration_limit: float | None = None, time_limit: float | None = None,
                 warm_iteration_limit: float | None = None, dual_after_rows: bool = False, **options) -> None:
        self.xl = np.asarray(xl, dtype=float)
        self.xu = np.asarray(xu, dtype=float)
        n = self.xl.size
        if self.xl.shape != (n,) or self.xu.shape != (n,):
            raise ValueError(f"xl and xu must be (n,) arrays of one length, got {self.xl.shape} and {self.xu.shape}")
        self.n = n
        self.center = 0.5 * self.xl + 0.5 * self.xu if center is None else np.asarray(center, dtype=float)
        self.d = np.ones(n) if col_scale is None else np.asarray(col_scale, dtype=float)
        self.r = np.zeros(0)  # the row factors, in insertion order
        for name, value in (("iteration_limit", iteration_limit), ("time_limit", time_limit),
                            ("warm_iteration_limit", warm_iteration_limit)):
            if value is not None and (isinstance(value, bool) or not value > 0):
                raise ValueError(f"{name} must be None or a number > 0, got {value!r}")
        self.iteration_limit, self.time_limit = iteration_limit, time_limit
        self.warm_iteration_limit = warm_iteration_limit
        self._has_basis = False  # whether HiGHS holds a basis to start from (a run's, or one set)
        self.dual_after_rows = bool(dual_after_rows)
        self.iterations = self.solves = self.limit_hits = self.retries = self.fallbacks = 0
        self._norm: float | None = None
        self._rows_added = self._cost_changed = False  # since the last solve
        self._cols = np.arange(n, dtype=np.int32)
        self.highs = new_highs(tolerance, **{"presolve": "off", **options})
        self._strategy = self._option("simplex_strategy")
        check(self.highs.addVars(n, (self.xl - self.center) / self.d, (self.xu - self.center) / self.d), "addVars")

    def _option(self, name: str):
        value = self.highs.getOptionValue(name)
        return value[1] if isinstance(value, tuple) else value  # (status, value) in some highspy versions

    def budgets(self) -> tuple[int, float]:
        """The per-run budgets of the next solve: (simplex iteration limit, wall-time limit [s]).

        Defaults (module constants): ``max(ITERATIONS_FLOOR, ITERATIONS_PER_LINE (m + n))`` iterations and
        ``max(SECONDS_FLOOR, SECONDS_PER_ENTRY m n)`` seconds for the model's current m rows and n columns:
        far above what a cold solve of such a model takes, far below a stuck one. The values given to the
        constructor (or set on the attributes ``iteration_limit``, ``time_limit``) replace them.
        """
        m, n = self.m, self.n
        its = self.iteration_limit
        if its is None:
            its = max(ITERATIONS_FLOOR, ITERATIONS_PER_LINE * (m + n))
        secs = self.time_limit
        if secs is None:
            secs = max(SECONDS_FLOOR, SECONDS_PER_ENTRY * m * n)
        return int(min(its, _MAX_ITERATIONS)), float(secs)

    @property
    def m(self) -> int:
        """The number of rows added so far."""
        return int(self.r.size)

    def add_rows(self, A, lo, hi, row_scale=None) -> None:
        """Append the rows ``lo <= A x <= hi`` (original coordinates; A (k, n), lo, hi (k,), may be infinite).

        row_scale : (k,) each row's size (its bound or half-width; default 1): HiGHS sees the row times the
        power of two nearest ``1 / row_scale``. The bounds are shifted to the centre (``lo - A center``).
        """
        A = np.asarray(A, dtype=float)
        a0 = pmatmul(A, self.center)  # no BLAS: HiGHS sees the same bits on any CPU
        self.add_shifted_rows(A, np.asarray(lo, float) - a0, np.asarray(hi, float) - a0, row_scale)

    def add_shifted_rows(self, A, lo_shift, hi_shift, row_scale=None) -> None:
        """Append rows ``lo_shift <= A (x - center) <= hi_shift`` (bounds already relative to the centre)."""
        A = np.asarray(A, dtype=float)
        r = np.ones(A.shape[0]) if row_scale is None else power2_scale(row_scale)
        add_dense_rows(self.highs, A * self.d * r[:, None], lo_shift * r, hi_shift * r)
        self.r = np.concatenate([self.r, r])
        self._rows_added = self._rows_added or r.size > 0

    def add_sparse_rows(self, starts, index, values, lo, hi, row_scale=None) -> None:
        """Append sparse rows ``lo <= A x <= hi`` in compressed row form (original coordinates): row i holds
        the entries ``values[starts[i]:starts[i + 1]]`` in the columns ``index[...]`` (every row non-empty).

        starts : (k,) int; index, values : (nnz,); lo, hi : (k,) (may be infinite); row_scale as in
        :meth:`add_rows`. The bounds are shifted to the centre and each entry scaled by its row's power of
        two and its column's scale. :class:`LPError` when an entry is not finite or ``>= LARGE_ENTRY``.
        """
        starts = np.asarray(starts, dtype=np.int64)
        index = np.asarray(index, dtype=np.int32)
        values = np.asarray(values, dtype=float)
        k = starts.size
        if k == 0:
            return
        counts = np.diff(np.append(starts, values.size))
        if np.any(counts <= 0):
            raise LPError("add_sparse_rows needs every row non-empty")
        amax = float(np.max(np.abs(values)))
        if not np.isfinite(amax) or amax >= LARGE_ENTRY:
            raise LPError(f"rows with a matrix entry of magnitude {amax:.3g} (HiGHS accepts < {LARGE_ENTRY:.0e})")
        r = np.ones(k) if row_scale is None else power2_scale(row_scale)
        a0 = np.add.reduceat(values * self.center[index], starts)
        lo_s = (np.asarray(lo, float) - a0) * r
        hi_s = (np.asarray(hi, float) - a0) * r
        scaled = values * self.d[index] * np.repeat(r, counts)
        check(self.highs.addRows(k, lo_s, hi_s, values.size, starts.astype(np.int32), index, scaled),
              f"addRows ({k} rows)")
        self.r = np.concatenate([self.r, r])
        self._rows_added = True

    def set_bounds(self, xl, xu) -> None:
        """Change every column's bounds (original coordinates), e.g. a branch-and-bound node."""
        self.xl, self.xu = np.asarray(xl, dtype=float), np.asarray(xu, dtype=float)
        check(self.highs.changeColsBounds(self.n, self._cols, (self.xl - self.center) / self.d,
                                          (self.xu - self.center) / self.d), "changeColsBounds")
        self._cost_changed = True  # the basis may lose primal feasibility: not a rows-only change

    def basis(self):
        """HiGHS's current basis (to warm-start a later model of the same shape, :meth:`set_basis`)."""
        return self.highs.getBasis()

    def set_basis(self, basis) -> None:
        """Start the next solve from ``basis`` (a :meth:`basis` of a model of the same shape)."""
        check(self.highs.setBasis(basis), "setBasis")
        self._has_basis = True

    def basis_status(self) -> tuple[list, list]:
        """HiGHS's current basis as ``(col_status, row_status)`` lists (for :meth:`set_basis_status`)."""
        b = self.highs.getBasis()
        return list(b.col_status), list(b.row_status)

    def set_basis_status(self, col_status, row_status) -> bool:
        """Start the next solve from the basis ``(col_status, row_status)`` of :meth:`basis_status`, taken from a
        model with the same columns and the same first ``len(row_status)`` rows (e.g. the same rows over another
        box): the rows after those are made basic (their slacks), so the basis stays square and non-singular
        if it was. Returns whether HiGHS accepted it (if not, the next solve starts from the current basis: a
        start only, the solution does not depend on it beyond the LP tolerances)."""
        if len(col_status) != self.n or len(row_status) > self.m:
            return False
        b = highspy.HighsBasis()
        b.col_status = list(col_status)
        b.row_status = list(row_status) + [highspy.HighsBasisStatus.kBasic] * (self.m - len(row_status))
        b.valid = True
        ok = self.highs.setBasis(b) != _ERROR
        self._has_basis = self._has_basis or ok
        self._cost_changed = True  # not a rows-only change
        return ok

    def set_cost(self, cost, *, normalize: bool = True) -> None:
        """Set the objective ``min cost^T x`` (cost (n,) finite, not zero) without solving; HiGHS sees
        ``cost d / max |cost d|`` (``cost d`` itself with ``normalize=False``)."""
        cd = np.asarray(cost, dtype=float) * self.d
        norm = float(np.max(np.abs(cd))) if cd.size else 0.0
        if norm == 0.0 or not np.isfinite(norm):
            raise LPError(f"cost must be finite and not zero, got max |cost d| = {norm!r}")
        if not normalize:
            norm = 1.0
        check(self.highs.changeColsCost(self.n, self._cols, cd / norm), "changeColsCost")
        self._norm = norm
        self._cost_changed = True

    def _run(self, strategy: int | None = None, warm: bool = False):
        """One ``run`` of HiGHS under the per-solve budgets (:meth:`budgets`, the time limit re-armed; a ``warm``
        run, from a valid basis, at most ``warm_iteration_limit`` iterations), with the simplex strategy
        ``strategy`` for this run only (None: the model's). Returns (model status, simplex iterations); LPError if
        ``run`` itself fails."""
        h = self.highs
        its, secs = self.budgets()
        if warm and self.warm_iteration_limit is not None and self._has_basis:
            its = int(min(its, self.warm_iteration_limit))
        check(h.setOptionValue("simplex_iteration_limit", its), f"option simplex_iteration_limit={its}")
        arm_time_limit(h, secs)
        switch = strategy is not None and strategy != self._strategy
        if switch:
            check(h.setOptionValue("simplex_strategy", strategy), f"option simplex_strategy={strategy}")
        try:
            run_status = h.run()
        finally:
            if switch:
                check(h.setOptionValue("simplex_strategy", self._strategy), f"option simplex_strategy={self._strategy}")
        self.solves += 1
        self._has_basis = True
        check(run_status, "run")
        it = int(h.getInfo().simplex_iteration_count)
        self.iterations += it
        ms = h.getModelStatus()
        self.limit_hits += ms in _LIMITS
        return ms, it

    def solve(self, cost=None) -> LPSolution:
        """Solve ``min cost^T x`` warm-started from the previous basis, under the per-solve budgets.

        cost : (n,) finite, not zero (None: the previous solve's cost, e.g. after rows were added). HiGHS sees
        ``(cost d) / max |cost d|`` (the unit vector itself when cost is one); the returned duals are those of
        the original rows and cost: ``y_k = r_k y'_k max |cost d|``. A run that ends neither optimal nor
        infeasible (a limit, or e.g. "Unknown" from a warm start on a degenerate basis) is run once more from a
        cold start with the dual simplex; if that stops at a limit too, the solution has the status 'limit'
        and the duals HiGHS holds (the next solve then starts cold). :class:`LPError` for any other failure
        (another model status, an error of ``run``, a solution without values).
        """
        h = self.highs
        if cost is not None:
            self.set_cost(cost)
        elif self._norm is None:
            raise LPError("no cost set: pass one to the first solve")
        norm = self._norm
        rows_only = self.dual_after_rows and self._rows_added and not self._cost_changed
        self._rows_added = self._cost_changed = False
        ms, it = self._run(_DUAL_SIMPLEX if rows_only else None, warm=True)
        if ms not in (_OPTIMAL, _INFEASIBLE):
            self.retries += 1
            h.clearSolver()
            self._has_basis = False
            ms, it2 = self._run(_DUAL_SIMPLEX)
            it += it2
        if ms == _INFEASIBLE:
            return LPSolution("infeasible", iterations=it)
        sol = h.getSolution()
        if ms in _LIMITS:
            self.fallbacks += 1
            rd, valid = self._row_duals(sol)
            h.clearSolver()  # the next solve starts cold, not from the basis where this one stopped
            self._has_basis = False
            return LPSolution("limit", duals=rd * self.r * norm, iterations=it, dual_valid=valid)
        if ms != _OPTIMAL or not sol.value_valid or len(sol.col_value) != self.n:
            raise LPError(f"HiGHS did not solve the LP: {h.modelStatusToString(ms)}")
        rd, valid = self._row_duals(sol)
        z = np.asarray(sol.col_value) * self.d
        return LPSolution("optimal", x=self.center + z, z=z, duals=rd * self.r * norm, iterations=it,
                          dual_valid=valid)

    def _row_duals(self, sol) -> tuple[np.ndarray, bool]:
        """HiGHS's row duals of the scaled rows (zeros when it gives none) and whether it gave them."""
        if not sol.dual_valid:
            return np.zeros(self.m), False
        rd = np.asarray(sol.row_dual, dtype=float)
        if rd.size != self.m:
            raise LPError(f"HiGHS returned {rd.size} row duals for {self.m} rows")
        return rd, True

    def counters(self) -> dict:
        """``{'lp_solves', 'lp_iterations', 'lp_limit_hits', 'lp_retries', 'lp_fallbacks'}`` (ints) so far."""
        return {"lp_solves": self.solves, "lp_iterations": self.iterations, "lp_limit_hits": self.limit_hits,
                "lp_retries": self.retries, "lp_fallbacks": self.fallbacks}
