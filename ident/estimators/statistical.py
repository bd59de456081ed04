"""Statistical references: least squares (OLS, Gautier's WLS) and instrumental variables, with confidence boxes.

These estimators ignore ``bound``: they assume random errors instead of bounded ones. Each returns a
*simultaneous* confidence box at ``level`` by the Bonferroni rule: parameter j gets
``theta_j +- t_{1 - (1 - level) / (2 p), dof} std_j`` (Student t, dof = N - p), so the p intervals hold together
with probability at least ``level`` under the assumptions. ``info["set"]`` is the confidence ellipsoid at the
same level, ``(theta - theta_hat)^T C^-1 (theta - theta_hat) <= p F_{p, dof}(level)``, C the estimate's covariance
(exact level for OLS / WLS with known weights under Gaussian errors; asymptotic for IV). The box is intersected
with the prior when they meet (``info["prior_disjoint"]`` says when they do not; the box is then returned
unclipped).

* :func:`ols`: ``y = W theta + e``, e independent, zero-mean, homoscedastic Gaussian; ``s^2 = |r|^2 / (N - p)``,
  ``C = s^2 (W^T W)^-1``.
* :func:`wls`: Gautier's per-joint weighting (Gautier & Poignet, "Extended Kalman filtering and weighted least
  squares dynamic identification of robot", Control Eng. Practice 9(12), 2001): e Gaussian, independent,
  zero-mean, with one variance per group (context ``groups``, e.g. the joint of each row; one group if
  absent). ``sigma_j^2 = |Y_j - W_j theta_j|^2 / (r_j - rank(W_j))`` from the OLS fit of the group's own rows,
  rows weighted by ``1 / sigma_j``, then OLS on the weighted system: :func:`ident.estimators.wls.wls`, the one
  implementation (its rank test and its errors: :class:`~ident.UnidentifiableError` for a rank-deficient W).
* :func:`iv`: instrumental variables (Janot, Vandanjon & Gautier, "A generic instrumental variable approach
  for industrial robot identification", IEEE TCST 22(1):132-145, 2014, IDIM-IV): with instruments Z (N, p)
  (context ``instruments``, e.g. the regressor evaluated on the reference motion), ``theta = (Z^T W)^-1 Z^T y``,
  ``s^2 = |y - W theta|^2 / (N - p)``, ``C = s^2 (Z^T W)^-1 Z^T Z (W^T Z)^-1`` (errors independent of Z,
  homoscedastic; the level is asymptotic).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from h4bench.ident import Box
from h4bench.ident.estimators._common import check_groups, check_inputs
from h4bench.ident.estimators.registry import declare
from h4bench.ident.estimators.wls import wls as gautier_wls

__all__ = ["iv", "iv_at", "ols", "ols_at", "wls", "wls_at"]


def _check_level(level) -> float:
    level = float(level)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    return level


def _confidence(theta, C, dof, level, lo, hi, names, method, extra) -> Box:
    """The Bonferroni box and the F ellipsoid of an estimate with covariance C (see module docstring)."""
    p = theta.size
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    t = stats.t.ppf(1.0 - (1.0 - level) / (2.0 * p), dof)
    lower = theta - t * std
    upper = theta + t * std
    info = {"method": method, "kind": "statistical", "level": level, "theta": theta.tolist(), "std": std.tolist(),
            "dof": int(dof), "t_quantile": float(t), **extra,
            "set": {"type": "ellipsoid", "center": theta.tolist(),
                    "shape": (p * stats.f.ppf(level, p, dof) * C).tolist()}}
    clo = np.maximum(lower, lo)
    chi = np.minimum(upper, hi)
    if np.any(clo > chi):
        info["prior_disjoint"] = True
        return Box(lower, upper, names, info=info)
    return Box(clo, chi, names, info=info)


def _ls(W, y):
    """Least squares through a column-equilibrated SVD: theta, (W^T W)^-1 and the residual."""
    d = np.linalg.norm(W, axis=0)
    d[d == 0.0] = 1.0
    U, s, Vt = np.linalg.svd(W / d, full_matrices=False)
    if s[-1] <= 1e-12 * s[0]:
        raise ValueError(f"W is rank-deficient (condition number {s[0] / max(s[-1], 1e-300):.3g} after column "
                         "scaling): least squares does not determine every parameter")
    theta = (Vt.T @ ((U.T @ y) / s)) / d
    Vs = Vt.T / s
    inv = (Vs @ Vs.T) / d[:, None] / d[None, :]
    return theta, inv, y - W @ theta


def _ols(W, y, bound, prior, level):
    W, y, b, lo, hi, names = check_inputs(W, y, bound, prior)
    N, p = W.shape
    if N <= p:
        raise ValueError(f"ols needs more rows than parameters, got W of shape {W.shape}")
    theta, inv, r = _ls(W, y)
    s2 = float(r @ r) / (N - p)
    return _confidence(theta, s2 * inv, N - p, level, lo, hi, names, "ols", {"s2": s2})


def _wls(W, y, bound, prior, groups, level):
    """Gautier's WLS is :func:`ident.estimators.wls.wls` (the one implementation), its groups as the joints."""
    W, y, b, lo, hi, names = check_inputs(W, y, bound, prior)
    labels, joint_of_row = np.unique(check_groups(groups, W.shape[0]), return_inverse=True)
    res = gautier_wls(W, y, labels.size, names=names, joint_of_row=joint_of_row)
    return _confidence(res.theta, res.cov, res.dof, level, lo, hi, names, "wls",
                       {"s2": res.s2, "group_sigma": res.joint_sigma.tolist(), "groups": labels.tolist()})


def _iv(W, y, bound, prior, instruments, level):
    W, y, b, lo, hi, names = check_inputs(W, y, bound, prior)
    N, p = W.shape
    if instruments is None:
        raise ValueError("iv needs instruments: pass instruments=Z, an (N, p) array row-aligned with W (e.g. the "
                         "regressor evaluated on the reference motion); none were given")
    Z = np.asarray(instruments, dtype=float)
    if Z.shape != W.shape:
        raise ValueError(f"instruments must have the shape of W, {W.shape}, got {Z.shape}")
    if not np.all(np.isfinite(Z)):
        raise ValueError("instruments must be finite")
    if N <= p:
        raise ValueError(f"iv needs more rows than parameters, got W of shape {W.shape}")
    ZW = Z.T @ W
    if np.linalg.cond(ZW) > 1e12:
        raise ValueError(f"iv: Z^T W is singular (condition number {np.linalg.cond(ZW):.3g}): the instruments do not "
                         "identify every parameter")
    theta = np.linalg.solve(ZW, Z.T @ y)
    r = y - W @ theta
    s2 = float(r @ r) / (N - p)
    A = np.linalg.solve(ZW, Z.T @ Z)  # (Z^T W)^-1 Z^T Z
    C = s2 * np.linalg.solve(ZW, A.T).T  # A (W^T Z)^-1 = (Z^T W)^-1 A^T, transposed
    C = 0.5 * (C + C.T)
    return _confidence(theta, C, N - p, level, lo, hi, names, "iv", {"s2": s2})


_CLAIMS = {  # name: (description with {pct} for the level, citation)
    "ols": ("least squares, {pct} % Bonferroni confidence box (Gaussian homoscedastic errors)",
            "ordinary least squares; Bonferroni simultaneous t intervals"),
    "wls": ("Gautier's per-group weighted least squares, {pct} % Bonferroni confidence box",
            "M. Gautier, P. Poignet, Extended Kalman filtering and weighted least squares dynamic identification "
            "of robot, Control Engineering Practice 9(12):1361-1372, 2001"),
    "iv": ("instrumental variables (IDIM-IV), {pct} % Bonferroni confidence box (asymptotic)",
           "A. Janot, P.-O. Vandanjon, M. Gautier, A generic instrumental variable approach for industrial robot "
           "identification, IEEE Trans. Control Systems Technology 22(1):132-145, 2014"),
}


_CONTEXT = {"ols": (), "wls": ("groups",), "iv": ("instruments",)}  # the context keywords each one takes


def _attach(f, name: str, level: float, suffix: str = ""):
    """Declare the claims of the statistical estimator ``name`` at ``level`` on ``f``; returns ``f``."""
    description, citation = _CLAIMS[name]
    f.__name__ = name + suffix
    return declare(kind="statistical", rigorous=False, level=level, context=_CONTEXT[name], citation=citation,
                   description=description.format(pct=f"{100 * level:g}"))(f)


def ols_at(level: float):
    """The :func:`ols` estimator at confidence ``level`` in (0, 1)."""
    level = _check_level(level)
    return _attach(lambda W, y, bound, prior: _ols(W, y, bound, prior, level), "ols", level, f"_{level:g}")


def wls_at(level: float):
    """The :func:`wls` estimator at confidence ``level`` in (0, 1)."""
    level = _check_level(level)
    return _attach(lambda W, y, bound, prior, groups=None: _wls(W, y, bound, prior, groups, level), "wls", level,
                   f"_{level:g}")


def iv_at(level: float):
    """The :func:`iv` estimator at confidence ``level`` in (0, 1)."""
    level = _check_level(level)
    return _attach(lambda W, y, bound, prior, instruments=None: _iv(W, y, bound, prior, instruments, level), "iv",
                   level, f"_{level:g}")


def ols(W, y, bound, prior, *, level: float = 0.95) -> Box:
    """Ordinary least squares with a simultaneous (Bonferroni) confidence box at ``level``.

    Parameters
    ----------
    W : (N, p) regressor; y : (N,) observations; bound : (N,) or scalar > 0, checked but not used;
    prior : ident.Box (the box is intersected with it); level : confidence level in (0, 1).

    Returns
    -------
    ident.Box
        ``info``: ``theta``, ``std``, ``s2``, ``dof``, ``t_quantile``, ``set`` (the F confidence ellipsoid).
    """
    return _ols(W, y, bound, prior, _check_level(level))


def wls(W, y, bound, prior, *, groups=None, level: float = 0.95) -> Box:
    """Gautier's per-group weighted least squares with a simultaneous (Bonferroni) confidence box.

    Parameters
    ----------
    W, y, bound, prior : as :func:`ols`; groups : (N,) int, the group (joint) of each row (one group if None);
    level : confidence level in (0, 1).

    Returns
    -------
    ident.Box
        ``info`` as :func:`ols`, plus ``group_sigma`` (the per-group standard deviations, y's units).
    """
    return _wls(W, y, bound, prior, groups, _check_level(level))


def iv(W, y, bound, prior, *, instruments=None, level: float = 0.95) -> Box:
    """Instrumental-variable estimate (IDIM-IV) with a simultaneous (Bonferroni) confidence box.

    Parameters
    ----------
    W, y, bound, prior : as :func:`ols`; instruments : (N, p) instrument matrix row-aligned with W (required;
    ``ValueError`` without it); level : confidence level in (0, 1).

    Returns
    -------
    ident.Box
        ``info`` as :func:`ols` (``set`` the asymptotic confidence ellipsoid).
    """
    return _iv(W, y, bound, prior, instruments, _check_level(level))


for _f in (ols, wls, iv):
    _attach(_f, _f.__name__, 0.95)
