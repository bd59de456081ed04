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

**Where [W] comes from (the H4 chain of :mod:`ident.processing.processing`).** The estimated states
``s_est = P(q_meas)`` (Butterworth filtfilt + central differences, a linear operator P) differ from the true
ones by ``P(e) + (P(q) - s_true)``: the encoder error ``e`` (``|e| <= pi / counts``, rounding to the nearest
count) and the filter's distortion of the true motion. After the parallel filter h (applied to both sides):

    h * W(s_true) = h * W(s_est - P e) + h * [W(s_true) - W(P q)].

* **Encoder part (rigorous for the linear columns, first-order for the others).** ``|P_k e| <= ||P_k||_1 pi /
  counts`` row by row, with the row norms of the actual processing operator (:func:`encoder_radii`: the
  code's own filter applied to unit impulses, ends included). The regressor over the state box
  ``s_est ± r`` is enclosed by :func:`interval_regressor`: one-at-a-time central differences with steps equal
  to the radii, ``|f(s + r_j) - f(s - r_j)| / 2`` per coordinate, which is exact for the columns linear in the
  states (``Imot: qdd``, ``Fv: qd``); the Mnac and Ibc columns (``J^T (J qdd + Jdot qd - G)``) are linear in
  qdd (exact), quadratic in qd (the quadratic part is bounded exactly from second differences, the cross terms
  from mixed differences) and nonlinear in q (first- plus second-order one-at-a-time terms); the mixed q-qd,
  q-qdd and q-q terms are **not** bounded rigorously but covered by a stated margin ``second_order_margin``
  (default 10 %; measured on the H4 over random and corner states, the unmargined bound was exceeded by at most
  0.05 % at radii (2e-4 rad, 0.01 rad/s, 0.5 rad/s^2), 0.6 % at (2e-3, 0.2, 20), 5 % at (1e-2, 0.5, 50)). The
  state boxes hold the encoder part only: pointwise, the filters' distortion of the true motion is far larger
  (simulated: up to 80-300 rad/s^2 on qdd, closed-loop chatter and friction steps) than after the parallel
  filter, where it is handled (next items). The interval matrix
  then goes through the parallel filter as an interval: ``h * [Wc ± D] ⊆ [h * Wc ± |h| * D]`` (rigorous, with
  the filter's own floating-point error added to D) (:func:`filter_interval`).
* **Coulomb column.** ``sign(qd)`` is kept where the sign of the true speed over the sample is certain
  (``|qd_est| > r`` at the sample and at the next one, same sign; the friction of a sampled step acts with the
  end-of-step speed), else it becomes ``[-1, 1]`` (true of MuJoCo's friction box and of static friction): those
  rows need no speed-threshold exclusion.
* **Distortion part: an assumption.** ``h * [W(s_true) - W(P q)]`` is the low-pass's error on the true motion
  (the true accelerations carry closed-loop chatter and friction steps that no low-pass follows pointwise; the
  parallel filter removes most of it). It cannot be derived from the data. It is an input, ``distortion``
  (one bound per joint row and column of the filtered regressor, plus the raw speed distortion used for the
  sign test), measured by :func:`regressor_distortion` on a calibration simulation with the truth and
  multiplied by a safety factor. The claim "the interval regressor contains the true one" is exactly as
  good as this assumption; a scenario checks it against the truth of the run itself.

This module imports neither ``sim`` nor ``mujoco``: the regressor is passed in as a function.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import highspy
import numpy as np
import scipy.signal

from ident.errors import InconsistentDataError
from ident.estimators.checks import check_bound, check_finite, check_prior, real_array
from ident.estimators.estimate import least_squares_center
from ident.processing.filtering import (
    ProcessingSettings,
    central_difference,
    default_edge_samples,
    derivatives,
    lowpass_position,
    parallel_filter,
    second_difference,
)
from ident.estimators.hull import _column_scale, _new_highs, interval_hull, power2_scale, shifted_safe_bound, strip_bounds
from ident.numerics.interval import down, nonneg_upper, point_matmul, point_matvec, up
from ident.numerics.lp import LPError, LPFallbackWarning, add_dense_rows, check
from ident.box import Box

__all__ = [
    "Distortion",
    "IntervalEquation",
    "encoder_radii",
    "filter_interval",
    "interval_equation",
    "interval_regressor",
    "regressor_distortion",
    "uncertain_hull",
]

H4_SIGN_COLUMNS = (10, 11, 12, 13)  # Fs1..Fs4 in ident.PARAMETER_NAMES order
N_JOINTS = 4


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


def _states(x, name: str, n: int | None = None) -> np.ndarray:
    a = real_array(x, name)
    if a.ndim != 2 or a.shape[1] != N_JOINTS or (n is not None and a.shape[0] != n):
        raise ValueError(f"{name} must have shape ({'n' if n is None else n}, {N_JOINTS}), got {a.shape}")
    check_finite(a, name)
    return a


def _radius(r, name: str, n: int) -> np.ndarray:
    a = real_array(r, name)
    try:
        a = np.broadcast_to(a, (n, N_JOINTS)).astype(float)
    except ValueError:
        raise ValueError(f"{name} must be a scalar, ({N_JOINTS},) or ({n}, {N_JOINTS}), got shape {a.shape}") from None
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be finite and >= 0 (a radius), got min {float(np.min(a))!r}")
    return a


# -------------------------------------------------------------------------------------------- the hull
def _op_scale(W_lo, W_hi, y, b, lo, hi, lp_tol=1e-9, center=None):
    """``min s`` s.t. ``W_lo theta - s b <= y``, ``W_hi theta + s b >= y``, theta in [lo, hi], s in [0, s_max].

    Returns (s_lower (safe dual bound), s_upper (verified at the returned theta), theta, solved). ``S`` is empty iff
    ``s* > 1``. All rows at once (HiGHS, shifted to ``center`` and scaled rows first by ``1 / b``, then
    columns, powers of two); the bound is rigorous for the exact float data. If HiGHS cannot solve the LP,
    ``s_lower = 0`` (nothing proven), ``s_upper`` is the verified value at ``center`` and ``solved`` is False.
    """
    m, p = W_lo.shape
    theta0 = 0.5 * lo + 0.5 * hi if center is None else np.clip(center, lo, hi)
    s0 = _op_upper(W_lo, W_hi, y, b, theta0)
    s_max = float(up(2.0 * s0) + 1.0)
    A = np.vstack([np.hstack([W_lo, -b[:, None]]), np.hstack([W_hi, b[:, None]])])
    bl = np.concatenate([np.full(m, -np.inf), y])
    bu = np.concatenate([y, np.full(m, np.inf)])
    x0 = np.append(theta0, 0.0)
    a0 = A[:, :p] @ theta0
    r = np.tile(power2_scale(b), 2)
    d = np.append(_column_scale(A[:, :p], r), 1.0)
    xl, xu = np.append(lo, 0.0), np.append(hi, s_max)
    cost = np.zeros(p + 1)
    cost[p] = 1.0
    try:
        h = _new_highs(lp_tol)
        check(h.addVars(p + 1, (xl - x0) / d, (xu - x0) / d), "addVars")
        add_dense_rows(h, A * d * r[:, None], (bl - a0) * r, (bu - a0) * r)
        check(h.changeColsCost(p + 1, np.arange(p + 1, dtype=np.int32), cost * d), "changeColsCost")
        run_error = h.run() == highspy.HighsStatus.kError
        sol = h.getSolution()
        if run_error or h.getModelStatus() != highspy.HighsModelStatus.kOptimal or not sol.value_valid:
            raise LPError(f"HiGHS failed on the Oettli-Prager scale LP: {h.modelStatusToString(h.getModelStatus())}")
        rd = np.asarray(sol.row_dual) if sol.dual_valid else np.zeros(2 * m)
        if rd.size != 2 * m:
            raise LPError(f"HiGHS returned {rd.size} row duals for {2 * m} rows")
    except LPError as exc:
        warnings.warn(f"uncertain_hull: {exc}; consistency not decided by the LP", LPFallbackWarning, stacklevel=3)
        return 0.0, s0, theta0, False
    x = x0 + np.asarray(sol.col_value) * d
    yd = rd * r
    nz = yd != 0.0
    s_lo = shifted_safe_bound(A[nz], bl[nz], bu[nz], xl, xu, cost, yd[nz], x0)
    theta = np.clip(x[:p], lo, hi)
    return max(s_lo, 0.0), _op_upper(W_lo, W_hi, y, b, theta), theta, True


def _op_upper(W_lo, W_hi, y, b, theta) -> float:
    """Rigorous upper bound of the smallest s with ``W_lo theta - s b <= y <= W_hi theta + s b`` row by row."""
    llo, lhi = point_matmul(W_lo, theta)
    hlo, hhi = point_matmul(W_hi, theta)
    need = np.maximum(up(lhi - y), up(y - hlo))
    return float(max(np.max(up(np.maximum(need, 0.0) / b)), 0.0))


def uncertain_hull(Wc, D, y, bound, prior, *, lp_tol: float = 1e-9) -> Box:
    """Guaranteed box enclosing ``S = {theta in Q : exists W in [Wc - D, Wc + D], |y - W theta| <= bound}``.

    Wc : (m, p) centre regressor; D : (m, p) or scalar radius >= 0 (units of W); y : (m,); bound : scalar or
    (m,) > 0; prior : :class:`~ident.Box` or (lower, upper) with ``lower >= 0`` (the polytope form of the
    module docstring needs theta >= 0). The exact hull of S by 2p LPs on the 2m stacked rows, rigorous
    endpoints. Returns a Box with ``info``: ``method='interval'``, ``rows``, ``nonempty_proven``,
    ``seconds``, the hull's LP statistics, ``bound_inflated_by`` when HiGHS found S empty within its tolerance
    without a proof (then the box encloses a slightly larger set). Raises :class:`~ident.InconsistentDataError`
    when S is proven empty (``min_bound`` the smallest consistent scalar bound, rounded up; ``scale_lower``
    a proven lower bound of the factor the given bounds need); ``ValueError``/``TypeError`` on bad input.
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
    center = least_squares_center(Wc.T @ Wc, Wc, y, lo, hi, None if scalar else b)
    A, BL, BU = stacked(b)
    if np.any(BL > BU):  # a row whose range over the prior misses its strip: S is empty (rigorous)
        s_lo, s_up, _, _ = _op_scale(W_lo, W_hi, y, b, lo, hi, lp_tol, center)
        raise inconsistent(max(s_lo, 1.0), s_up)
    # scale=b: a stacked row is violated when theta is off its range [BL, BU] by more than violation_tol * b
    # (its own bound, not the width of the range), and HiGHS sees each row in units of its bound
    rows_b = np.concatenate([b, b])
    res = interval_hull(A, BL, BU, lo, hi, scale=rows_b, center=center, lp_tol=lp_tol)
    crossed = res.status == "ok" and bool(np.any(res.lower > res.upper))  # rigorous: S is empty
    if res.status == "infeasible" or crossed:
        s_lo, s_up, theta, solved = _op_scale(W_lo, W_hi, y, b, lo, hi, lp_tol, center)
        if s_lo > 1.0 or (crossed and not solved):  # crossing safe bounds prove S empty too
            raise inconsistent(max(s_lo, 1.0), s_up)
        factor = max(s_up, 1.0) * (1.0 + 1e-9)  # not proven empty: enclose the slightly larger set
        info["bound_inflated_by"] = factor
        A, BL, BU = stacked(b * factor)
        res = interval_hull(A, BL, BU, lo, hi, scale=rows_b * factor, center=theta, lp_tol=lp_tol)
        if res.status != "ok" or np.any(res.lower > res.upper):
            warnings.warn("uncertain_hull: the hull LPs failed on a set known to be non-empty; the box is the prior",
                          LPFallbackWarning, stacklevel=2)
            res.lower, res.upper = lo.copy(), hi.copy()
        info["nonempty_proven"] = True
    else:
        x_mean = np.clip(res.points.mean(axis=1), lo, hi)
        if _op_upper(W_lo, W_hi, y, b, x_mean) <= 1.0:
            info["nonempty_proven"] = True
        else:
            s_lo, s_up, _, _ = _op_scale(W_lo, W_hi, y, b, lo, hi, lp_tol, center)
            if s_lo > 1.0:
                raise inconsistent(s_lo, s_up)
            info["nonempty_proven"] = s_up <= 1.0
    if res.info["lp_failures"]:
        warnings.warn(f"uncertain_hull: HiGHS could not solve {len(res.info['lp_failures'])} of the hull LPs "
                      f"({res.info.get('lp_error', 'no optimal basis')}); their endpoints are coarser safe bounds "
                      "or the prior's", LPFallbackWarning, stacklevel=2)
    info["lp_failures"] = res.info["lp_failures"]
    info.update({k: res.info[k] for k in ("lp_iterations", "lp_solves", "working_rows", "rounds", "converged")})
    lower, upper = np.clip(res.lower, lo, hi), np.clip(res.upper, lo, hi)
    info["seconds"] = time.perf_counter() - t0
    return Box(lower=lower, upper=upper, names=names, info=info)


# ---------------------------------------------------------------------------------- encoder error radii
def encoder_radii(counts_per_turn: int, dt: float, cutoff_hz: float, order: int = 4, n: int | None = None) -> np.ndarray:
    """Rigorous radii ``(r_q, r_qd, r_qdd)`` [rad, rad/s, rad/s^2] of the encoder part of the state estimates.

    counts_per_turn : encoder counts per turn (error ``|e| <= pi / counts``, rounding to the nearest count);
    dt, cutoff_hz, order : the processing of :func:`ident.processing.filtering.derivatives`; n : the record's length in
    samples (default: long).

    The estimate is linear in the measured angles, ``s = P q_meas``, so the encoder part is ``P e`` and
    ``|(P e)_k| <= ||P_k||_1 max|e|``. The row norms are those of the code's own operator: the processing is
    applied to unit impulses (a probe of ``2 (trim + T) + 1`` samples, ``T`` the number of samples after which
    the Butterworth's impulse response has decayed below ``1e-16`` by its pole radius, ``trim`` the samples
    :func:`derivatives` marks invalid), and the largest row norm over the valid samples is taken; rows of a
    longer record equal the probe's up to those tails, covered by a ``1e-6`` relative margin (with the
    floating-point error of the probe, about 1e-13). Returns (3,) radii.
    """
    if isinstance(counts_per_turn, bool) or not isinstance(counts_per_turn, (int, np.integer)) or counts_per_turn < 1:
        raise ValueError(f"counts_per_turn must be an integer >= 1, got {counts_per_turn!r}")
    trim = default_edge_samples(dt, cutoff_hz) + 2
    sos = scipy.signal.butter(order, cutoff_hz, btype="low", output="sos", fs=1.0 / dt)
    rho = float(np.max(np.abs(scipy.signal.sos2zpk(sos)[1])))
    T = int(math.ceil(math.log(1e-16) / math.log(rho)))
    n_probe = 2 * (trim + T) + 1
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2 * trim + 1:
            raise ValueError(f"n must be an integer > 2 * trim = {2 * trim} (samples of the record), got {n!r}")
        n_probe = min(n_probe, int(n))
    sums = np.zeros((3, n_probe))
    eye = np.eye(n_probe)
    for s in range(0, n_probe, N_JOINTS):
        blk = eye[:, s: s + N_JOINTS]
        if blk.shape[1] < N_JOINTS:
            blk = np.hstack([blk, np.zeros((n_probe, N_JOINTS - blk.shape[1]))])
        qf = lowpass_position(blk, dt, cutoff_hz, order)
        for o, x in enumerate((qf, central_difference(qf, dt), second_difference(qf, dt))):
            sums[o] += np.abs(x).sum(axis=1)
    norms = sums[:, trim: n_probe - trim].max(axis=1)
    eps = up(np.pi / counts_per_turn)
    return up(up(norms * (1.0 + 1e-6)) * eps)


# ------------------------------------------------------------------------------------ interval regressor
def interval_regressor(regressor_fn, q, qd, qdd, r_q, r_qd, r_qdd, *, sign_columns=H4_SIGN_COLUMNS,
                       sign_radius=None, sign_next: bool = True, second_order_margin: float = 0.1):
    """Interval enclosure ``(Wc, D)`` of ``W(s)`` over the state boxes ``s ± r`` (module docstring).

    regressor_fn : callable ``(q, qd, qdd) -> W (4n, p)`` (rows ``4k + i``), e.g.
    ``lambda q, qd, qdd: ident.regressor(geometry, q, qd, qdd)``; q, qd, qdd : (n, 4) estimated states;
    r_q, r_qd, r_qdd : radii, scalar, (4,) or (n, 4) [rad, rad/s, rad/s^2]; sign_columns : the column of
    ``sign(qd_i)`` for each joint i (None: no Coulomb column); sign_radius : (n, 4) radius used to decide the
    sign of the true speed (default ``r_qd``); sign_next : the sign must also be certain at the next sample
    (sampled friction acts with the end-of-step speed; the last sample is then uncertain);
    second_order_margin : relative margin for the mixed second-order terms not bounded (default 0.1).

    Cost: 31 evaluations of ``regressor_fn``. Returns ``(Wc, D)``, both (4n, p); ``Wc`` is W at the estimates
    except the uncertain Coulomb entries (0, radius 1).
    """
    q, qd, qdd = (_states(x, name) for x, name in ((q, "q"), (qd, "qd"), (qdd, "qdd")))
    n = q.shape[0]
    if qd.shape[0] != n or qdd.shape[0] != n:
        raise ValueError(f"q, qd and qdd must have the same number of samples, got {n}, {qd.shape[0]}, {qdd.shape[0]}")
    radii = [_radius(r, name, n) for r, name in ((r_q, "r_q"), (r_qd, "r_qd"), (r_qdd, "r_qdd"))]
    if isinstance(second_order_margin, bool) or not isinstance(second_order_margin, (int, float)) or \
            not (math.isfinite(second_order_margin) and second_order_margin >= 0):
        raise ValueError(f"second_order_margin must be a finite number >= 0, got {second_order_margin!r}")
    states = [q, qd, qdd]
    W0 = np.asarray(regressor_fn(q, qd, qdd), dtype=float)
    if W0.ndim != 2 or W0.shape[0] != N_JOINTS * n:
        raise ValueError(f"regressor_fn must return shape ({N_JOINTS * n}, p), got {W0.shape}")
    p = W0.shape[1]

    def evaluate(o, j, step):
        s = [x.copy() for x in states]
        s[o][:, j] += step
        return np.asarray(regressor_fn(*s), dtype=float)

    D = np.zeros_like(W0)
    plus_qd = {}
    for o in range(3):
        for j in range(N_JOINTS):
            if not np.any(radii[o][:, j]):
                continue
            wp = evaluate(o, j, radii[o][:, j])
            wm = evaluate(o, j, -radii[o][:, j])
            D += 0.5 * np.abs(wp - wm) + 0.5 * np.abs(wp + wm - 2.0 * W0)
            if o == 1:
                plus_qd[j] = wp
    # exact quadratic cross terms in qd: f(+i,+k) - f(+i) - f(+k) + f0 = H_ik r_i r_k
    for i in range(N_JOINTS):
        for k in range(i + 1, N_JOINTS):
            if i not in plus_qd or k not in plus_qd:
                continue
            s = [x.copy() for x in states]
            s[1][:, i] += radii[1][:, i]
            s[1][:, k] += radii[1][:, k]
            wik = np.asarray(regressor_fn(*s), dtype=float)
            D += np.abs(wik - plus_qd[i] - plus_qd[k] + W0)
    # margin for the mixed terms; the float error of evaluating W (~1e-15 relative) is far below it
    D = up(D * (1.0 + second_order_margin) + 16.0 * 2.0**-53 * np.abs(W0))
    Wc = W0.copy()
    if sign_columns is not None:
        cols = tuple(int(c) for c in sign_columns)
        if len(cols) != N_JOINTS or any(not 0 <= c < p for c in cols):
            raise ValueError(f"sign_columns must give one column index in [0, {p}) per joint, got {sign_columns!r}")
        sr = radii[1] if sign_radius is None else _radius(sign_radius, "sign_radius", n)
        uncertain = np.abs(qd) <= sr
        if sign_next:
            nxt = np.ones_like(uncertain)
            nxt[:-1] = (np.abs(qd[1:]) <= sr[1:]) | (np.sign(qd[1:]) != np.sign(qd[:-1]))
            uncertain |= nxt
        rows = np.arange(n)
        for i, c in enumerate(cols):
            D[:, c] = 0.0
            r = N_JOINTS * rows + i
            Wc[r, c] = np.where(uncertain[:, i], 0.0, np.sign(qd[:, i]))
            D[r, c] = np.where(uncertain[:, i], 1.0, 0.0)
    return Wc, D


def filter_interval(Wc, D, y, bound, factor: int, taps):
    """The parallel filter of an interval equation: ``h * [Wc ± D] ⊆ [h * Wc ± (|h| * D + rounding)]``.

    Wc, D : (4n, p); y : (4n,); bound : scalar or (4n,); factor, taps : decimation and FIR as in
    :func:`ident.processing.filtering.parallel_filter` (which computes every filtered quantity and its rounding bound).
    Returns ``(Wc_f, D_f, y_f, bound_f, fe)`` with ``fe`` the :class:`~ident.processing.filtering.FilteredEquation` of the
    centre (sample_index, rows, ...). Rigorous: the radius adds the floating-point error bounds of ``h * Wc``
    and of ``|h| * D`` and is rounded up.
    """
    h = np.asarray(taps, dtype=float)
    fe = parallel_filter(Wc, y, bound, factor, taps=h)
    fd = parallel_filter(D, np.zeros(D.shape[0]), 0.0, factor, taps=np.abs(h))
    D_f = nonneg_upper(fd.W + fd.w_rounding + fe.w_rounding, 3)
    return fe.W, D_f, fe.y, fe.bound, fe


# ---------------------------------------------------------------------------- distortion (an assumption)
@dataclass(frozen=True)
class Distortion:
    """Assumed bounds on the filters' distortion of the TRUE motion (see the module docstring).

    regressor : (4, p) bound on ``|h * [W(s_true) - W(P q_true)]|`` per joint row and column of the filtered
    regressor (Coulomb columns: 0, they are handled by the sign test); qd : (4,) bound on the raw speed
    distortion ``|P_d q_true - qd_true|`` [rad/s] (widens the sign test); source : where the numbers come from.
    """

    regressor: np.ndarray
    qd: np.ndarray
    source: str = ""

    def scaled(self, factor: float) -> "Distortion":
        """The same bounds times a safety factor (rounded up)."""
        def scale(a):
            a = np.asarray(a, dtype=float)
            return np.where(a > 0, up(a * factor), 0.0)

        return Distortion(scale(self.regressor), scale(self.qd), f"{self.source} x {factor:g}")


def _processed_states(q, settings: ProcessingSettings):
    est = derivatives(q, settings.dt, settings.position_cutoff_hz, settings.butter_order,
                      timing=settings.torque_timing)
    v = est.valid
    return est.q[v], est.qd[v], est.qdd[v], np.arange(q.shape[0])[v]


def regressor_distortion(regressor_fn, q_true, qd_true, qdd_true, settings: ProcessingSettings,
                         sign_columns=H4_SIGN_COLUMNS) -> Distortion:
    """Measure the distortion of the processing on a record whose true states are known (a calibration
    simulation): the processing of the exact angles ``q_true`` (no encoder) against the true states.

    q_true, qd_true, qdd_true : (n, 4) true states at the samples; settings : the processing of the experiment.
    Returns the largest distortion per joint row and column after the parallel filter, and the largest raw
    speed distortion per joint. Reads a truth: for calibration only, never on the data being identified.
    """
    q_true, qd_true, qdd_true = (_states(x, name) for x, name in
                                 ((q_true, "q_true"), (qd_true, "qd_true"), (qdd_true, "qdd_true")))
    qf, qd, qdd, samples = _processed_states(q_true, settings)
    W_true = np.asarray(regressor_fn(q_true[samples], qd_true[samples], qdd_true[samples]), dtype=float)
    W_est = np.asarray(regressor_fn(qf, qd, qdd), dtype=float)
    diff = W_true - W_est
    if sign_columns is not None:
        diff[:, list(sign_columns)] = 0.0
    taps = settings.taps()
    if settings.decimation == 1 and taps.size == 1:
        filt = diff
    else:
        filt = parallel_filter(diff, np.zeros(diff.shape[0]), 0.0, settings.decimation, taps=taps).W
    p = diff.shape[1]
    reg = np.abs(filt).reshape(-1, N_JOINTS, p).max(axis=0)
    qd_dist = np.abs(qd - qd_true[samples]).max(axis=0)
    return Distortion(regressor=reg, qd=qd_dist, source="measured on a record with known true states")


# ----------------------------------------------------------------------------------------- the pipeline
@dataclass(frozen=True)
class IntervalEquation:
    """``y = W theta + e`` with ``W in [Wc - D, Wc + D]`` and ``|e| <= bound``: Wc, D (m, p); y, bound (m,);
    sample, joint (m,) the original sample and joint of each row; info: radii, counts, filter data."""

    Wc: np.ndarray
    D: np.ndarray
    y: np.ndarray
    bound: np.ndarray
    sample: np.ndarray
    joint: np.ndarray
    info: dict = field(default_factory=dict, compare=False)

    def __len__(self) -> int:
        return self.y.size


def interval_equation(regressor_fn, q_meas, tau, bound, settings: ProcessingSettings, *, counts_per_turn: int | None,
                      distortion: Distortion | None, sign_columns=H4_SIGN_COLUMNS, sign_band: float = 0.0,
                      second_order_margin: float = 0.1) -> IntervalEquation:
    """The processed equation of measured data with an interval regressor (module docstring).

    regressor_fn : ``(q, qd, qdd) -> W (4n, p)``; q_meas : (n, 4) measured (quantised) angles [rad];
    tau : (n, 4) measured torques [N m]; bound : scalar > 0, the claim on raw rows ``|tau - W(s_true) theta|``
    (noise and model mismatch only: the derivative errors are in the regressor now); settings : processing;
    counts_per_turn : the encoder's resolution (None: exact angles); distortion : the assumed distortion bounds (None: zero, i.e.
    the claim that the filters do not distort the true motion); sign_band : extra speed [rad/s] within which
    the friction law is not trusted (e.g. a simulator's friction smoothing band).

    Every raw sample in the valid range is kept (no speed threshold): uncertain signs become [-1, 1].
    """
    q_meas = _states(q_meas, "q_meas")
    tau = _states(tau, "tau", q_meas.shape[0])
    bound = float(bound)
    if not (math.isfinite(bound) and bound > 0):
        raise ValueError(f"bound must be a finite number > 0 [N m], got {bound!r}")
    if isinstance(sign_band, bool) or not isinstance(sign_band, (int, float)) or not (math.isfinite(sign_band) and sign_band >= 0):
        raise ValueError(f"sign_band must be a finite number >= 0 [rad/s], got {sign_band!r}")
    dt = settings.dt
    radii = np.zeros(3) if counts_per_turn is None else \
        encoder_radii(counts_per_turn, dt, settings.position_cutoff_hz, settings.butter_order, n=q_meas.shape[0])
    qf, qd, qdd, samples = _processed_states(q_meas, settings)
    dist_qd = np.zeros(N_JOINTS) if distortion is None else np.asarray(distortion.qd, dtype=float)
    sign_radius = up(up(radii[1] + dist_qd) + sign_band)[None, :] * np.ones((qf.shape[0], 1))
    Wc, D = interval_regressor(regressor_fn, qf, qd, qdd, radii[0], radii[1], radii[2], sign_columns=sign_columns,
                               sign_radius=sign_radius, second_order_margin=second_order_margin)
    y = tau[samples].reshape(-1)
    taps = settings.taps()
    info = {"encoder_radii": radii.tolist(), "counts_per_turn": counts_per_turn,
            "sign_uncertain_rows": int(np.count_nonzero(D[:, list(sign_columns)] == 1.0)) if sign_columns else 0,
            "raw_rows": int(y.size), "second_order_margin": second_order_margin,
            "distortion_source": None if distortion is None else distortion.source}
    if settings.decimation == 1 and taps.size == 1:
        Wf, Df, yf, bf = Wc, D, y, np.full(y.size, bound)
        sample, joint = np.repeat(samples, N_JOINTS), np.tile(np.arange(N_JOINTS), samples.size)
        info.update({"filtered": False, "l1_norm": 1.0})
    else:
        Wf, Df, yf, bf, fe = filter_interval(Wc, D, y, bound, settings.decimation, taps)
        sample = np.repeat(samples[fe.sample_index], N_JOINTS)
        joint = np.tile(np.arange(N_JOINTS), fe.sample_index.size)
        info.update({"filtered": True, "l1_norm": fe.l1_norm})
    if distortion is not None:
        reg = np.asarray(distortion.regressor, dtype=float)
        if reg.shape != (N_JOINTS, Wf.shape[1]):
            raise ValueError(f"distortion.regressor must have shape ({N_JOINTS}, {Wf.shape[1]}), got {reg.shape}")
        Df = up(Df + reg[joint])
    return IntervalEquation(Wc=Wf, D=Df, y=yf, bound=bf, sample=sample, joint=joint, info=info)
