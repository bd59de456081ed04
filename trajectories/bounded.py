"""Bounded-error experiment design: the half-widths h_j of the feasible set's geometry, their gradients, and the
trajectory criterion built on them.

In a bounded-error context the quality of an experiment is the size of the feasible parameter set, not a
covariance (Pronzato & Walter, "Experiment design in a bounded-error context: comparison with D-optimality",
Automatica 25(3):383-391, 1989; Walter & Pronzato, "Identification of Parametric Models from Experimental
Data", Springer 1997, ch. 6). For the processed equation ``y = W theta + e``, ``|e_r| <= b`` row by row, the
feasible set is ``{theta : |y - W theta| <= b}``; with ``theta_c`` any point of it, ``theta - theta_c`` lies in
``2 b`` times the symmetric polytope ``P = {delta : |W delta| <= 1}`` (and contains ``(b - rho)`` times it about
the truth when the oracle residual is ``rho``). So each hull width obeys, before clipping by the prior::

    2 (b - rho) h_j  <=  width_j  <=  2 (b + rho) h_j,      h_j = max { delta_j : |W delta| <= 1 row-wise }

width = slack x geometry. ``h_j`` depends only on the (noise-free) regressor, hence on the trajectory, and is
what the design minimises: a smooth maximum of ``h_j / target_j`` (relative half-widths, targets = nominal
parameters by default), unlike cond(W), which is blind to the motion's amplitude.

Each ``h_j`` is one linear program (HiGHS via ``highspy``, model kept, only the objective changed between the p
solves: warm-started; no rigour is claimed, this is design). Its gradient follows from the envelope theorem.
Write LP j as ``min c^T delta`` s.t. ``-1 <= W delta <= 1`` with ``c = -e_j`` (so ``h_j = -c^T delta*``), and
let ``y`` be HiGHS's row duals, which satisfy ``c = W^T y`` at an optimum whose column bounds are inactive. The
Lagrangian ``L = c^T delta - y^T (W delta - r)`` (r the active row bounds) gives
``d(c^T delta*)/dW_ik = dL/dW_ik = -y_i delta*_k``, hence::

    dh_j / dW_ik = y_i delta*_k       (only active rows, y_i != 0, contribute)

(checked against finite differences in ``tests/trajectories/test_bounded.py``). ``h_j`` is piecewise smooth
(the active set may change); the gradient is exact wherever the LP solution is unique.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench import ident
from h4bench.ident.numerics.lp import LPError, LPModel
from h4bench.ident.processing.filtering import ProcessingSettings
from h4bench.ident.processing.processing import select_rows
from h4bench.portable import exp, log
from h4bench.trajectories.design import _IBC, _MNAC, _QD, _QDD, CoefficientProblem, grid_regressor

#: Column bound of the half-width LPs: keeps every LP bounded when W is rank-deficient (then h_j = BIG).
BIG = 1e6
#: Default sharpness of the smooth maximum ``(1/beta) log sum exp(beta log(h_j / target_j))``: within
#: ``log(p)/beta`` (here 0.33, a factor 1.4) of the true max of the log-ratios.
BETA = 8.0

@dataclass(frozen=True)
class HalfWidths:
    """Solutions of the p half-width LPs of a regressor W (m, p).

    h : (p,) ``max delta_j`` s.t. ``|W delta| <= 1`` [parameter units per N m of bound];
    delta : (p, p) the maximisers, row j for LP j; duals : (p, m) HiGHS row duals of LP j (``W^T y_j = -e_j``);
    iterations : simplex iterations over the p solves; bases : the p optimal HiGHS bases (to warm-start the
    next call on a regressor with the same rows, e.g. the optimiser's next iterate).
    """

    h: np.ndarray
    delta: np.ndarray
    duals: np.ndarray
    iterations: int
    bases: tuple = ()

    def gradient(self, weights=None) -> np.ndarray:
        """``sum_j weights_j dh_j/dW`` (m, p) by the envelope theorem (``dh_j/dW = y_j delta_j^T``);
        weights (p,) default: all ones."""
        w = np.ones(self.h.size) if weights is None else np.asarray(weights, float)
        return np.einsum("jm,j,jk->mk", self.duals, w, self.delta)  # no BLAS: the same bits on any CPU

    def gradient_of(self, j: int) -> np.ndarray:
        """``dh_j/dW`` (m, p)."""
        return np.outer(self.duals[j], self.delta[j])


def halfwidths(W, bases=None) -> HalfWidths:
    """The p half-width LPs of W (m, p) (module docstring), one warm-started HiGHS model.

    bases : optional p HiGHS bases of a previous call on a W with the same shape: LP j starts from bases[j]
    (else from the previous LP's optimal basis).

    Raises ValueError for a W that is not a finite 2-D array with at least one row, :class:`ident.LPError` when
    HiGHS does not solve an LP (every status is checked, :class:`ident.numerics.lp.LPModel`).
    """
    W = np.asarray(W, dtype=float)
    if W.ndim != 2 or W.shape[0] == 0 or W.shape[1] == 0:
        raise ValueError(f"W must have shape (m, p) with m, p >= 1, got {W.shape}")
    if not np.all(np.isfinite(W)):
        raise ValueError("W must be finite")
    m, p = W.shape
    model = LPModel(np.full(p, -BIG), np.full(p, BIG), center=np.zeros(p), tolerance=None)
    model.add_rows(W, -np.ones(m), np.ones(m))
    out_h, delta, duals, iters, out_bases = np.empty(p), np.zeros((p, p)), np.zeros((p, m)), 0, []
    use_bases = bases is not None and len(bases) == p
    for j in range(p):
        cost = np.zeros(p)
        cost[j] = -1.0
        if use_bases:
            model.set_cost(cost)
            model.set_basis(bases[j])
        sol = model.solve(None if use_bases else cost)  # ident.LPError unless optimal or infeasible
        iters += sol.iterations
        if sol.status != "optimal":
            raise LPError(f"half-width LP {j} not solved: {sol.status}")
        delta[j] = sol.x
        duals[j] = sol.duals
        out_h[j] = delta[j, j]
        out_bases.append(model.basis())
    # HiGHS's sign convention: c = W^T y + z. Flip if a build uses the opposite one (checked, not assumed).
    ref = np.einsum("jm,mk->jk", duals, W)  # (p, p), should be -I
    if np.allclose(ref, np.eye(p), atol=1e-6):
        duals = -duals
    return HalfWidths(out_h, delta, duals, iters, tuple(out_bases))


def smooth_max(h, targets, beta: float = BETA):
    """Smooth maximum ``F = (1/beta) log sum_j exp(beta log(h_j / target_j))`` of the log relative half-widths
    and its weights ``dF/dh_j`` (p,). Returns (F, weights)."""
    r = log(np.asarray(h, float) / np.asarray(targets, float))
    a = beta * r
    amax = a.max()
    e = exp(a - amax)
    s = e.sum()
    return float((amax + float(log(s))) / beta), e / s / np.asarray(h, float)


def processed_regressor(geometry, q, qd, qdd, settings: ProcessingSettings | None = None, structure="paper"):
    """The noise-free processed regressor of a reference (q, qd, qdd (n, 4) [rad, rad/s, rad/s^2]):
    ``ident.regressor`` on the reference, then the identification's parallel filter and decimation
    (``ident.processing.filtering.parallel_filter`` with ``settings.taps()``) and the same low-speed exclusion
    (``ident.processing.processing.select_rows``, the selection of ``build_equation``).

    Returns (W (m, p), joint (m,) joint index of each row). The Butterworth/difference stage of the real
    processing acts on measured positions and is not modelled (the reference's derivatives are exact).
    """
    settings = settings or ProcessingSettings()
    W = ident.regressor(geometry, q, qd, qdd, structure=structure)
    fe, rows, _ = select_rows(W, np.zeros(W.shape[0]), 1.0, qd, settings, settings.taps())
    return (W if fe is None else fe.W)[rows], rows % 4


def as_targets(targets, p: int) -> np.ndarray:
    """Validate targets (p,) > 0 (None -> the nominal parameters ``ident.NOMINAL_PARAMETERS``)."""
    t = np.asarray(ident.NOMINAL_PARAMETERS if targets is None else targets, dtype=float)
    if t.shape != (p,) or not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise ValueError(f"targets must be {p} finite values > 0 (parameter order of ident.PARAMETER_NAMES), "
                         f"got {np.asarray(targets).tolist() if targets is not None else None}")
    return t


def design_criterion(geometry, traj, settings: ProcessingSettings | None = None, targets=None) -> dict:
    """The bounded-error criterion of a :class:`trajectories.Trajectory` on its processed regressor.

    Returns ``h`` (14,) half-widths [parameter units per N m], ``relative`` = h / targets, ``max_relative``,
    ``smooth_max`` (F, log scale), ``rows`` of the processed regressor and ``seconds``. Predicted hull widths at
    a slack s [N m] are ``2 s h`` (:func:`predicted_widths`).
    """
    import time  # noqa: PLC0415

    t0 = time.perf_counter()
    W, _ = processed_regressor(geometry, traj.q, traj.qd, traj.qdd, settings)
    hw = halfwidths(W)
    t = as_targets(targets, W.shape[1])
    F, _ = smooth_max(hw.h, t)
    rel = hw.h / t
    return {"h": hw.h.tolist(), "relative": rel.tolist(), "max_relative": float(rel.max()), "smooth_max": F,
            "rows": int(W.shape[0]), "seconds": time.perf_counter() - t0}


def predicted_widths(h, slack, prior_width=None) -> np.ndarray:
    """Hull widths predicted from half-widths h (p,) at a slack ``b -+ rho`` [N m]: ``2 slack h``, clipped to
    ``prior_width`` (scalar or (p,)) when given."""
    w = 2.0 * float(slack) * np.asarray(h, float)
    return w if prior_width is None else np.minimum(w, prior_width)


class HalfwidthProblem(CoefficientProblem):
    """:class:`trajectories.design.CoefficientProblem` with the bounded-error criterion: the smooth maximum of
    ``log(h_j / target_j)`` on the design grid's regressor (SI units, true sign(qd) in the Coulomb columns).

    The design grid stands for the processed rows: the parallel filter's pass band is flat (1e-4) far above the
    motion's band, so a filtered row of a smooth regressor equals the raw row at the window's centre, and a
    Coulomb row is kept only if sign(qd) cannot change within the filter window: ``|qd| >= threshold +
    |qdd| * half_window`` (the window of ``propagate_mask``). h_j converges as the row density grows (a
    supremum over the path, not a sum), so a grid of ~12 samples per period of the highest harmonic is close
    to the 100 Hz processed figure (compared in the tests and in ``benchmarks/bench_design.py``).
    """

    def __init__(self, *args, targets, speed_threshold: float, half_window_s: float, beta: float = BETA,
                 **kwargs):
        super().__init__(*args, **kwargs)
        self.targets = np.asarray(targets, float)
        self.speed_threshold, self.half_window_s, self.beta = float(speed_threshold), float(half_window_s), beta
        self.last, self._last_keep = None, None

    def _rows(self, y):
        qd, qdd = y[:, _QD], y[:, _QDD]
        return (np.abs(qd) >= self.speed_threshold + np.abs(qdd) * self.half_window_s).reshape(-1)

    def regressor(self, y) -> np.ndarray:
        """(4n, 14) the paper's regressor on the grid (rows 4k + i), true sign in the Coulomb columns."""
        return grid_regressor(y, np.sign(y[:, _QD]))

    def objective(self, y, dy=None):
        keep = self._rows(y)
        if keep.sum() < 14:
            return None
        W = self.regressor(y)[keep]
        same_rows = self.last is not None and self._last_keep is not None and np.array_equal(self._last_keep, keep)
        try:
            hw = halfwidths(W, self.last.bases if same_rows else None)
        except LPError:
            return None
        if np.any(hw.h >= 0.5 * BIG) or np.any(hw.h <= 0):
            return None
        F, weights = smooth_max(hw.h, self.targets, self.beta)
        self.last, self._last_keep = hw, keep
        if dy is None:
            return F, None
        G = np.zeros((y.shape[0] * 4, 14))
        G[keep] = hw.gradient(weights)
        G = G.reshape(-1, 4, 14)
        idx = np.arange(4)
        grad = (np.einsum("na,naz->z", G[:, idx, idx], dy[:, _QDD]) + np.einsum("na,naz->z", G[:, :, 4], dy[:, _MNAC])
                + np.einsum("na,naz->z", G[:, :, 5], dy[:, _IBC])
                + np.einsum("na,naz->z", G[:, idx, 6 + idx], dy[:, _QD]))
        return F, grad

    def criterion(self, z) -> float:
        return float(self.evaluate(z)[0])
