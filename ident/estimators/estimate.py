"""Public entry points of the set-membership estimators: :func:`estimate` and :func:`min_consistent_bound`.

Error model (paper sec. 3): ``|y_k - W_k theta| <= bound_k`` for every row k, ``theta`` in the prior box Q.
The feasible set ``S = {theta in Q : |y - W theta| <= bound}`` is a polytope; the methods return boxes that
contain it:

* ``"hull"`` (:mod:`ident.estimators.hull`): the exact interval hull of S, 2p linear programs with rigorous (safe
  dual) endpoints; shrinks like 1/N.
* ``"cgsp"`` (:mod:`ident.estimators.cgsp`): the paper's preconditioned interval Gauss-Seidel on Rump's system;
  equals ``hull(W^+ [Y]) & Q`` for a point regressor and does not shrink with N.

Both are guaranteed outer enclosures. An empty S raises :class:`InconsistentDataError` (only when the
emptiness is proven: a safe dual bound of the weighted Chebyshev fit exceeds 1, or the contractor emptied
the box). Inputs are validated (:mod:`ident.estimators.checks`); errors name the argument, what was expected and what
came. Every method, built-in or plugin, is resolved by the one registry (:mod:`ident.estimators.registry`).
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from h4bench.portable import jacobi_svd, lstsq
from h4bench.portable import matmul as pmatmul

from h4bench.ident.box import Box, default_names
from h4bench.ident.errors import InconsistentDataError, LPError, LPFallbackWarning, UnidentifiableError
from h4bench.ident.estimators import registry
from h4bench.ident.estimators.cgsp import cgsp
from h4bench.ident.estimators.checks import check_bound, check_prior, check_W_y
from h4bench.ident.estimators.enclosure import Verdict, decide_and_enclose
from h4bench.ident.estimators.chebyshev import chebyshev, scaled_residual_upper
from h4bench.ident.estimators.hull import hull_report, interval_hull, strip_bounds

__all__ = [
    "METHODS",
    "InconsistentDataError",
    "UnidentifiableError",
    "default_names",
    "cgsp_estimator",
    "estimate",
    "hull_estimator",
    "identifiability",
    "min_consistent_bound",
]

METHODS = ("hull", "cgsp")  # the set-membership methods :func:`_builtin_estimate` runs (registered as built-ins)


# ------------------------------------------------------------------------------------------- validation
def _check_method(method) -> str:
    if not isinstance(method, str):
        raise TypeError(f"method must be a string, one of {METHODS}, got {type(method).__name__}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    return method


# --------------------------------------------------------------------------------------- identifiability
def identifiability(W: np.ndarray, names, *, rcond: float = 1e-7, gram=None) -> dict:
    """Condition number of the column-scaled W and the parameters in its (numerically) weak directions.

    Uses the eigen-decomposition of the column-equilibrated ``W^T W`` (cheap: p x p). A direction is weak
    when its singular value is below ``rcond`` times the largest (the Gram matrix resolves singular values
    down to about ``sqrt(eps) ~ 1.5e-8``); a parameter is reported when more than 1 % of it lies in the weak
    subspace (``sum_k V_jk^2 > 0.01``), i.e. when the data cannot tell it apart from other parameters.
    Returns ``{"cond": float, "unidentifiable": tuple of names}``.
    """
    G = pmatmul(W.T, W) if gram is None else gram
    d = np.sqrt(np.diag(G))
    d[d == 0.0] = 1.0
    sv, V = jacobi_svd(G / d[:, None] / d[None, :], vectors=True, waves=True)  # no LAPACK: any CPU's bits
    lam, V = sv[::-1], V[:, ::-1]  # eigenvalues of the PSD Gram matrix, ascending (as eigh's)
    sig = np.sqrt(np.clip(lam, 0.0, None))
    smax = sig[-1] if sig.size else 0.0
    weak = sig <= rcond * smax if smax > 0 else np.ones_like(sig, dtype=bool)
    share = (V[:, weak] ** 2).sum(axis=1)
    cond = float(smax / sig[0]) if sig[0] > 0 else float("inf")
    return {"cond": cond, "unidentifiable": tuple(names[j] for j in np.flatnonzero(share > 0.01))}


# ------------------------------------------------------------------------------------------ consistency
def _min_bound(W, y, lo, hi, center=None) -> float:
    """Rigorous upper bound of the smallest consistent scalar bound: the Chebyshev LP, or, if HiGHS fails on
    it, the residual at ``center`` (default the prior's midpoint), rounded up (larger, still consistent)."""
    try:
        return float(chebyshev(W, y, np.ones_like(y), lo, hi, center=center).upper)
    except LPError as exc:
        c = np.clip(0.5 * lo + 0.5 * hi if center is None else center, lo, hi)
        warnings.warn(f"min_bound: {exc}; using the residual at the least-squares point (an upper bound)",
                      LPFallbackWarning, stacklevel=3)
        return scaled_residual_upper(W, y, np.ones_like(y), c)


def _inconsistent(W, y, b, scalar, lo, hi, scale_lower, center=None) -> InconsistentDataError:
    min_bound = _min_bound(W, y, lo, hi, center)
    given = float(b[0]) if scalar else float(np.max(b))
    if scalar:
        msg = (
            f"the data contradict bound={given:.6g}: no parameter vector in the prior satisfies "
            f"|y - W theta| <= bound; the smallest consistent bound is {min_bound:.6g}, "
            f"{min_bound - given:.3g} ({100.0 * (min_bound / given - 1.0):.3g} %) more than given"
        )
    else:
        msg = (
            f"the data contradict the per-row bounds (largest {given:.6g}): they must be scaled by at least "
            f"{scale_lower:.6g} to admit a parameter vector in the prior; the smallest consistent scalar bound "
            f"is {min_bound:.6g}"
        )
    return InconsistentDataError(msg, min_bound=min_bound, bound=given, scale_lower=scale_lower)


def min_consistent_bound(W, y, prior) -> float:
    """Smallest scalar bound ``t*`` with ``|y - W theta| <= t*`` for some theta in the prior box.

    W : (m, p); y : (m,); prior : Box or (lower, upper). The Chebyshev (L-infinity) fit over the prior
    box as one LP (solved with constraint generation). Returns a rigorous *upper* bound of ``t*``, the
    residual ``max |y - W theta*|`` at the LP's solution rounded upward, so ``bound = min_consistent_bound``
    is guaranteed consistent; it exceeds ``t*`` only by the LP tolerance (about 1e-9 relative).
    """
    W, y = check_W_y(W, y)
    lo, hi, _ = check_prior(prior, W.shape[1])
    G = pmatmul(W.T, W)
    return _min_bound(W, y, lo, hi, least_squares_center(G, W, y, lo, hi))


def min_consistent_scale(W, y, weights, prior) -> float:
    """Rigorous upper bound of the smallest scale ``s*`` with ``|y - W theta| <= s* weights`` row by row for some
    theta in the prior box (the weighted Chebyshev fit, :func:`ident.estimators.chebyshev.chebyshev`).

    W : (m, p); y : (m,); weights : (m,) > 0 (e.g. a per-joint bound shape, [N m]); prior : Box or (lower, upper).
    ``bound = min_consistent_scale(...) * weights`` is guaranteed consistent; it exceeds ``s*`` only by the LP
    tolerance. Raises :class:`~ident.numerics.lp.LPError` when HiGHS cannot solve the LP.
    """
    from h4bench.ident.estimators.chebyshev import chebyshev

    Wc, yc = check_W_y(W, y)
    check_prior(prior, Wc.shape[1])
    lo, hi = (prior.lower, prior.upper) if isinstance(prior, Box) else prior
    # the caller's arrays as given, not the validated contiguous copies: a copy may change how BLAS sums (last bits)
    W, y, lo, hi = (np.asarray(a, dtype=float) for a in (W, y, lo, hi))
    w = np.asarray(weights, dtype=float)
    if w.shape != y.shape or not np.all(np.isfinite(w)) or np.any(w <= 0):
        got = f"shape {w.shape}" if w.shape != y.shape else f"min {np.min(w)!r}, all finite: {np.isfinite(w).all()}"
        raise ValueError(f"weights must be {y.size} finite positive numbers (one per row), got {got}")
    return float(chebyshev(W, y, w, lo, hi).upper)


# ------------------------------------------------------------------------------------------------ estimate
def least_squares_center(G: np.ndarray, W: np.ndarray, y: np.ndarray, lo, hi, b=None) -> np.ndarray:
    """Least squares of the rows weighted by ``1 / b`` (G = W^T W when b is None or constant), clipped to
    the prior; column-equilibrated, so the point does not depend on the units of rows or parameters."""
    if b is not None and np.any(b != b[0]):
        G = np.zeros_like(G)
        rhs = np.zeros(W.shape[1])
        for s in range(0, W.shape[0], 8192):
            Wb = W[s : s + 8192] / b[s : s + 8192, None]
            G += pmatmul(Wb.T, Wb)
            rhs += pmatmul(Wb.T, y[s : s + 8192] / b[s : s + 8192])
    else:
        rhs = pmatmul(W.T, y)
    d = np.sqrt(np.diag(G))
    d[d == 0.0] = 1.0
    with np.errstate(all="ignore"):
        # einsum and Jacobi rotations, not BLAS/LAPACK: the LPs' centre (and so HiGHS's path) on any CPU
        sol = lstsq(G / d[:, None] / d[None, :], rhs / d, rcond=1e-12) / d
    sol = np.where(np.isfinite(sol), sol, 0.5 * lo + 0.5 * hi)
    return np.clip(sol, lo, hi)


def _hull_box(W, y, b, scalar, strips, prior, center, names, info, fallback, check_consistency_by_lp):
    """The hull method of :func:`estimate`: the hull LPs, emptiness decided and the set enclosed by
    :func:`~ident.estimators.enclosure.decide_and_enclose`; records into ``info``, returns (lower, upper)."""
    (bl, bu), (lo, hi) = strips, prior
    p = W.shape[1]

    def hull(factor, start):
        if factor == 1.0:
            return interval_hull(W, bl, bu, lo, hi, scale=b, center=start)
        fbl, fbu = strip_bounds(y, b * factor)
        return interval_hull(W, fbl, fbu, lo, hi, scale=b * factor, center=start)

    def decide() -> Verdict:
        ch = check_consistency_by_lp()  # raises when S is proven empty
        if ch is None:  # nothing proven: the (rigorous, larger) scaled residual at the least-squares point
            return Verdict(0.0, scaled_residual_upper(W, y, b, center), center, False)
        return Verdict(ch.lower, ch.upper, ch.theta, not ch.info["lp_fallback"])

    res, verdict, factor = decide_and_enclose(
        hull, decide, lambda t: scaled_residual_upper(W, y, b, t),
        lambda s_lo, s_up: _inconsistent(W, y, b, scalar, lo, hi, s_lo, center), fallback, center, lo, hi)
    if factor is not None:
        info["bound_inflated_by"] = factor
    if verdict is None:  # the mean of the LP solutions is a verified point of S
        info["nonempty_proven"] = True
        info["nearly_inconsistent"] = False
    if res.info["lp_failures"] or "lp_error" in res.info:
        failed = sorted({names[j % p] for j in res.info["lp_failures"]}) or "some parameters"
        fallback(f"HiGHS could not solve the LPs of {failed} ({res.info.get('lp_error', 'no optimal basis')}); "
                 "their endpoints are coarser safe bounds or the prior's")
    report, message = hull_report(res.info, names)
    if message is not None:
        fallback(message)
    lower, upper = res.lower, res.upper
    if res.points is not None:  # (p, 2p) the LP solutions (unverified floats): the judging's inner points
        info["points"] = np.array(res.points, dtype=float)
    info.update(report)
    return lower, upper


def _builtin_estimate(W, y, bound, prior, method: str = "hull", *, check_consistency: bool = True) -> Box:
    """The built-in estimators ``"hull"`` and ``"cgsp"``: a guaranteed box enclosing ``S = {theta in prior : |y - W theta| <= bound}``.

    W : (m, p) regressor (rows stacked sample k, joint i -> row 4k + i for the H4, any order works);
    y : (m,) measurements (e.g. motor torques [N m]); bound : scalar or (m,) positive error bound(s) in the
    units of y; prior : :class:`~ident.Box` or ``(lower, upper)`` finite arrays of length p;
    method : ``"hull"`` (exact hull, rigorous LP endpoints) or ``"cgsp"`` (the paper's contractor).
    check_consistency : for ``"cgsp"``, also solve one Chebyshev LP to detect an empty S that the
    contractor did not expose (``"hull"`` always detects it).

    Returns a :class:`~ident.Box` (names from the prior Box, else :func:`default_names`) with ``info``:
    ``method``, ``seconds``, ``at_prior`` (parameters whose box is the whole prior interval: not
    determined by the data), ``unidentifiable`` and ``cond`` (see :func:`identifiability`),
    ``nonempty_proven`` (a point of S was verified with rigorous rounding) and ``nearly_inconsistent``
    (S is empty or thinner than the LP tolerance, about 1e-9 relative: neither could be proven; the box
    still encloses S), for the hull ``points`` ((p, 2p) its LP solutions, floats not verified feasible), and per
    method ``lp_iterations``, ``lp_solves``, ``lp_limit_hits``, ``lp_retries``, ``lp_fallbacks``,
    ``lp_fallback_parameters``, ``working_rows``, ``rounds`` (hull: :func:`~ident.estimators.hull.hull_report`)
    or ``sweeps`` (cgsp). With ``check_consistency=False`` a cgsp box carries no emptiness check.
    Raises :class:`InconsistentDataError` when S is proven empty; ``ValueError``/``TypeError`` on bad input.

    Units: any consistent units give the same box (converted back), to ``1e-6`` of its width plus the
    change of the problem by the rounding of the converted data (``tests/ident/test_units.py`` states and
    checks the tolerance); the LPs are scaled inside (rows by their bound, then columns, powers of two).
    When HiGHS cannot solve an LP, or an LP stops at its per-solve budget
    (:class:`~ident.numerics.lp.LPModel`), the affected endpoints are coarser safe bounds or the prior's and a
    :class:`~ident.numerics.lp.LPFallbackWarning` says which (``info['fallbacks']``,
    ``info['lp_fallback_parameters']``); a fallback never makes a box tighter.
    """
    t0 = time.perf_counter()
    method = _check_method(method)
    W, y = check_W_y(W, y)
    n, p = W.shape
    b, scalar = check_bound(bound, n)
    scalar = scalar or bool(np.all(b == b[0]))  # one bound for every row (the registry passes it as (n,))
    lo, hi, names = check_prior(prior, p)
    bl, bu = strip_bounds(y, b)

    G = pmatmul(W.T, W)
    info: dict = {"method": method}
    info.update(identifiability(W, names, gram=G))

    center = least_squares_center(G, W, y, lo, hi, None if scalar else b)

    def fallback(what: str) -> None:
        info.setdefault("fallbacks", []).append(what)
        warnings.warn(f"estimate: {what}", LPFallbackWarning, stacklevel=6)  # the caller of estimate

    def check_consistency_by_lp():
        """Chebyshev LP with weights b: raise if S is proven empty, else record whether it is proven non-empty.
        Returns None (and warns) when HiGHS cannot solve it: nothing is proven either way."""
        try:
            ch = chebyshev(W, y, b, lo, hi, center=center)
        except LPError as exc:
            info["nonempty_proven"] = False
            info["nearly_inconsistent"] = True
            fallback(f"consistency not decided ({exc})")
            return None
        info["consistency_scale"] = (ch.lower, ch.upper)
        if ch.info["lp_fallback"]:  # chebyshev warned; the bounds are coarser, still rigorous
            info.setdefault("fallbacks", []).append("the consistency LP stopped at its per-solve budget")
        if ch.lower > 1.0:
            raise _inconsistent(W, y, b, scalar, lo, hi, ch.lower, center)
        info["nonempty_proven"] = ch.upper <= 1.0  # ch.theta satisfies every row exactly
        info["nearly_inconsistent"] = not info["nonempty_proven"]
        return ch

    if method == "hull":
        lower, upper = _hull_box(W, y, b, scalar, (bl, bu), (lo, hi), center, names, info, fallback,
                                 check_consistency_by_lp)
    else:
        res = cgsp(W, bl, bu, lo, hi)
        if res.empty:
            try:
                scale_lower = max(chebyshev(W, y, b, lo, hi, center=center).lower, 1.0)
            except LPError:
                scale_lower = 1.0  # the contractor's empty box is the proof; its size is unknown
            raise _inconsistent(W, y, b, scalar, lo, hi, scale_lower, center)
        if check_consistency:
            check_consistency_by_lp()
        lower, upper = res.lower, res.upper
        info.update({"sweeps": res.info["sweeps"], "converged": res.info["converged"]})
        info["residual_box_mean_width"] = float(np.mean(res.r_upper - res.r_lower))

    lower = np.clip(lower, lo, hi)
    upper = np.clip(upper, lo, hi)
    at_prior = (lower <= lo) & (upper >= hi) & (hi > lo)
    info["at_prior"] = tuple(names[j] for j in np.flatnonzero(at_prior))
    info["seconds"] = time.perf_counter() - t0
    return Box(lower=lower, upper=upper, names=names, info=info)


@registry.declare(kind="guaranteed", rigorous=True, context=("check_consistency",),
                  description="the exact interval hull of the feasible set: 2p linear programs with safe dual bounds",
                  citation="A. Neumaier, O. Shcherbina, Safe bounds in linear and mixed-integer linear programming, "
                           "Math. Program. 99:283-296, 2004")
def hull_estimator(W, y, bound, prior, *, check_consistency: bool = True) -> Box:
    """The built-in ``"hull"`` (:func:`_builtin_estimate` with ``method="hull"``; ``check_consistency`` is
    accepted for symmetry: the hull always decides emptiness)."""
    return _builtin_estimate(W, y, bound, prior, "hull", check_consistency=check_consistency)


@registry.declare(kind="guaranteed", rigorous=True, context=("check_consistency",),
                  description="the paper's preconditioned interval Gauss-Seidel on Rump's system (an outer box)",
                  citation="P. Poignet, N. Ramdani, O. A. Vivas, Robust estimation of parallel robot dynamic "
                           "parameters with interval analysis, IEEE CDC 2003 (sec. 3); S. M. Rump (2002)")
def cgsp_estimator(W, y, bound, prior, *, check_consistency: bool = True) -> Box:
    """The built-in ``"cgsp"`` (:func:`_builtin_estimate` with ``method="cgsp"``)."""
    return _builtin_estimate(W, y, bound, prior, "cgsp", check_consistency=check_consistency)


def estimate(W, y, bound, prior, method="hull", *, check_consistency: bool = True, **context) -> Box:
    """Guaranteed (or, for a statistical plugin, confidence) box of ``theta`` from ``|y - W theta| <= bound``.

    W : (m, p) regressor (rows stacked sample k, joint i -> row 4k + i for the H4, any order works); y : (m,)
    measurements (e.g. motor torques [N m]); bound : scalar or (m,) positive error bound(s) in the units of y;
    prior : :class:`~ident.Box` or ``(lower, upper)`` finite arrays of length p.
    method : a built-in name (``"hull"``: the exact hull, rigorous LP endpoints; ``"cgsp"``: the paper's
    contractor; see :func:`_builtin_estimate` for their ``info``), the name of an entry point of group
    ``h4bench.estimators``, a ``"package.module:attribute"`` string or a callable ``f(W, y, bound, prior,
    **context) -> Box`` (:mod:`ident.estimators.registry`). check_consistency : for ``"cgsp"``, also solve one
    Chebyshev LP to detect an empty S the contractor did not expose. context : ``groups`` ((m,) ints),
    ``instruments`` ((m, p)), passed only to estimators that accept them.
    Returns the Box (checked: the prior's shape, finite, lower <= upper, else
    :class:`~ident.EstimatorError` naming the estimator). Raises :class:`InconsistentDataError` when S is
    proven empty; ``ValueError``/``TypeError`` on bad input.
    """
    est = registry.get(method)
    context["check_consistency"] = check_consistency  # a keyword of the built-ins, dropped for others
    return registry.call(est, W, y, bound, prior, **context)
