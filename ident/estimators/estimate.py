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
the box). Inputs are validated here; errors name the argument, what was expected and what came.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from ident.box import Box
from ident.errors import InconsistentDataError, LPError, LPFallbackWarning, UnidentifiableError
from ident.estimators.cgsp import cgsp
from ident.estimators.enclosure import Verdict, decide_and_enclose
from ident.estimators.hull import chebyshev, interval_hull, scaled_residual_upper, strip_bounds
from ident.robots.h4 import PARAMETER_NAMES

__all__ = [
    "METHODS",
    "InconsistentDataError",
    "UnidentifiableError",
    "default_names",
    "estimate",
    "identifiability",
    "min_consistent_bound",
]

METHODS = ("hull", "cgsp")




# ------------------------------------------------------------------------------------------- validation
def default_names(p: int) -> tuple[str, ...]:
    """``PARAMETER_NAMES`` when ``p == 14``, else ``theta1 .. thetap``."""
    return PARAMETER_NAMES if p == len(PARAMETER_NAMES) else tuple(f"theta{i + 1}" for i in range(p))


def _real_array(x, name: str) -> np.ndarray:
    try:
        arr = np.asarray(x)
    except Exception as exc:  # ragged lists and the like
        raise TypeError(f"{name} must be a real numeric array, got {type(x).__name__} ({exc})") from None
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    arr = np.asarray(arr, dtype=float)
    return np.ascontiguousarray(arr) if arr.ndim else arr


def _check_finite(arr: np.ndarray, name: str) -> None:
    if np.isfinite(arr.sum()):  # one pass, no temporary; a NaN or inf anywhere makes the sum non-finite
        return
    bad = ~np.isfinite(arr)
    if not bad.any():
        return  # the sum overflowed, the entries are fine
    n_nan = int(np.isnan(arr).sum())
    n_inf = int(bad.sum()) - n_nan
    first = tuple(int(i) for i in np.unravel_index(int(np.flatnonzero(bad.ravel())[0]), arr.shape))
    raise ValueError(f"{name} must be finite, got {n_nan} NaN and {n_inf} inf entries (first at index {first})")


def _check_W_y(W, y) -> tuple[np.ndarray, np.ndarray]:
    W = _real_array(W, "W")
    if W.ndim != 2 or W.shape[1] < 1 or W.shape[0] < W.shape[1]:
        raise ValueError(f"W must have shape (m, p) with m >= p >= 1, got {W.shape}")
    _check_finite(W, "W")
    y = _real_array(y, "y")
    if y.shape != (W.shape[0],):
        raise ValueError(f"y must have shape (m,) = ({W.shape[0]},) to match W, got {y.shape}")
    _check_finite(y, "y")
    return W, y


def _check_bound(bound, m: int) -> tuple[np.ndarray, bool]:
    b = _real_array(bound, "bound")
    if b.ndim == 0:
        if not (np.isfinite(b) and b > 0):
            raise ValueError(f"bound must be finite and > 0 (a scalar or one value per row), got {float(b)!r}")
        return np.full(m, float(b)), True
    if b.shape != (m,):
        raise ValueError(f"bound must be a scalar or have shape (m,) = ({m},), got shape {b.shape}")
    bad = ~(np.isfinite(b) & (b > 0))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(f"bound must be finite and > 0 in every row, got {float(b[k])!r} at row {k} ({int(bad.sum())} bad rows)")
    return b, False


def _check_prior(prior, p: int) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    if isinstance(prior, Box):
        lo, hi, names = np.array(prior.lower, dtype=float), np.array(prior.upper, dtype=float), prior.names
    elif isinstance(prior, (tuple, list)) and len(prior) == 2:
        lo = _real_array(prior[0], "prior lower")
        hi = _real_array(prior[1], "prior upper")
        names = default_names(p)
    else:
        raise TypeError(f"prior must be a Box or a (lower, upper) pair of arrays of length {p}, got {type(prior).__name__}")
    if lo.shape != (p,) or hi.shape != (p,):
        raise ValueError(f"prior lower and upper must have shape ({p},) to match W's columns, got {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("prior must be finite: an interval hull needs a bounded prior box (got NaN or inf bounds)")
    if np.any(lo > hi):
        bad = [names[i] for i in np.flatnonzero(lo > hi)]
        raise ValueError(f"prior lower must be <= upper, violated for {bad}")
    return lo, hi, tuple(names)


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
    G = W.T @ W if gram is None else gram
    d = np.sqrt(np.diag(G))
    d[d == 0.0] = 1.0
    lam, V = np.linalg.eigh(G / d[:, None] / d[None, :])
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
    W, y = _check_W_y(W, y)
    lo, hi, _ = _check_prior(prior, W.shape[1])
    G = W.T @ W
    return _min_bound(W, y, lo, hi, _least_squares_center(G, W, y, lo, hi))


# ------------------------------------------------------------------------------------------------ estimate
def _least_squares_center(G: np.ndarray, W: np.ndarray, y: np.ndarray, lo, hi, b=None) -> np.ndarray:
    """Least squares of the rows weighted by ``1 / b`` (G = W^T W when b is None or constant), clipped to
    the prior; column-equilibrated, so the point does not depend on the units of rows or parameters."""
    if b is not None and np.any(b != b[0]):
        G = np.zeros_like(G)
        rhs = np.zeros(W.shape[1])
        for s in range(0, W.shape[0], 8192):
            Wb = W[s : s + 8192] / b[s : s + 8192, None]
            G += Wb.T @ Wb
            rhs += Wb.T @ (y[s : s + 8192] / b[s : s + 8192])
    else:
        rhs = W.T @ y
    d = np.sqrt(np.diag(G))
    d[d == 0.0] = 1.0
    with np.errstate(all="ignore"):
        sol = np.linalg.lstsq(G / d[:, None] / d[None, :], rhs / d, rcond=1e-12)[0] / d
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
        return Verdict(ch.lower, ch.upper, ch.theta, True)

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
    lower, upper = res.lower, res.upper
    info.update({k: res.info[k] for k in ("lp_iterations", "lp_solves", "working_rows", "rounds", "lp_failures", "converged")})
    return lower, upper


def estimate(W, y, bound, prior, method: str = "hull", *, check_consistency: bool = True) -> Box:
    """Guaranteed box enclosing ``S = {theta in prior : |y - W theta| <= bound}``.

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
    still encloses S), and per method ``lp_iterations``, ``lp_solves``, ``working_rows``, ``rounds``
    (hull) or ``sweeps`` (cgsp). With ``check_consistency=False`` a cgsp box carries no emptiness check.
    Raises :class:`InconsistentDataError` when S is proven empty; ``ValueError``/``TypeError`` on bad input.

    Units: any consistent units give the same box (converted back), to ``1e-6`` of its width plus the
    change of the problem by the rounding of the converted data (``tests/ident/test_units.py`` states and
    checks the tolerance); the LPs are scaled inside (rows by their bound, then columns, powers of two).
    When HiGHS cannot solve an LP, the affected endpoints are coarser safe bounds or the prior's and a
    :class:`~ident.numerics.lp.LPFallbackWarning` says which (``info['fallbacks']``); a fallback never makes a
    box tighter.
    """
    t0 = time.perf_counter()
    method = _check_method(method)
    W, y = _check_W_y(W, y)
    n, p = W.shape
    b, scalar = _check_bound(bound, n)
    lo, hi, names = _check_prior(prior, p)
    bl, bu = strip_bounds(y, b)

    G = W.T @ W
    info: dict = {"method": method}
    info.update(identifiability(W, names, gram=G))

    center = _least_squares_center(G, W, y, lo, hi, None if scalar else b)

    def fallback(what: str) -> None:
        info.setdefault("fallbacks", []).append(what)
        warnings.warn(f"estimate: {what}", LPFallbackWarning, stacklevel=3)

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
