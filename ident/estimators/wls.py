"""Weighted least squares with Gautier's per-joint weights and the relative standard deviation %sigma.

The classical estimator the paper compares with (its Table 2; Gautier & Poignet 2001). Rows are stacked
sample k, joint i -> row ``joints * k + i``.

1. For each joint j, an ordinary least-squares fit of the joint's own rows ``W_j theta = Y_j`` gives
   ``sigma_j^2 = ||Y_j - W_j theta_j||^2 / (r_j - c_j)`` with ``r_j`` rows and ``c_j = rank(W_j)`` (equal
   to the number of columns p when the joint's rows determine all parameters; for a parallel robot
   some columns vanish on a joint's rows, e.g. the other joints' frictions).
2. Rows of joint j are weighted by ``1 / sigma_j``; on the weighted system (r rows, c = p columns)
   ``theta`` is the least-squares solution, ``s2 = ||Y - W theta||^2 / (r - c)``, ``C = s2 (W^T W)^-1``,
   ``std_i = sqrt(C_ii)`` and ``%sigma_i = 100 std_i / |theta_i|``.

Computed with an SVD of the column-equilibrated weighted matrix, so a rank-deficient W is detected and
reported by parameter name (:class:`~ident.estimators.estimate.UnidentifiableError`) instead of producing NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench.ident.box import default_names
from h4bench.ident.errors import UnidentifiableError
from h4bench.ident.estimators.checks import check_W_y

__all__ = ["WLSResult", "wls"]


@dataclass(frozen=True)
class WLSResult:
    """Result of :func:`wls`.

    theta : (p,) estimate; std : (p,) standard deviations; rel_std_percent : (p,) ``100 std / |theta|``
    (``inf`` where theta is exactly 0); joint_sigma : (joints,) per-joint residual standard deviations used
    as weights (units of y); s2 : residual variance of the weighted system (dimensionless); dof : r - c;
    cond : condition number of the column-equilibrated weighted regressor; poorly_identified : names whose
    direction has a singular value below ``1e-8`` of the largest (determined, but barely); cov : (p, p) the
    covariance ``C = s2 (W_w^T W_w)^-1`` of theta (``std = sqrt(diag C)``), or None.
    """

    theta: np.ndarray
    std: np.ndarray
    rel_std_percent: np.ndarray
    joint_sigma: np.ndarray
    names: tuple[str, ...]
    s2: float
    dof: int
    cond: float
    poorly_identified: tuple[str, ...] = ()
    cov: np.ndarray | None = None

    def to_dict(self) -> dict:
        """JSON-ready: every field (arrays as lists: the estimate, its standard deviations, the per-joint sigma, ...)."""
        return {
            "names": list(self.names),
            "theta": self.theta.tolist(),
            "std": self.std.tolist(),
            "rel_std_percent": self.rel_std_percent.tolist(),
            "joint_sigma": self.joint_sigma.tolist(),
            "s2": self.s2,
            "dof": self.dof,
            "cond": self.cond,
            "poorly_identified": list(self.poorly_identified),
        }


def _null_names(V: np.ndarray, weak: np.ndarray, names) -> tuple[str, ...]:
    share = (V[:, weak] ** 2).sum(axis=1)
    return tuple(names[j] for j in np.flatnonzero(share > 0.01))


def wls(W, y, joints: int = 4, *, names=None, joint_of_row=None) -> WLSResult:
    """Gautier's weighted least squares with %sigma (see module docstring).

    W : (m, p) regressor with ``m = joints * n_samples`` rows stacked sample-major; y : (m,) torques;
    joints : rows per sample (4 for the H4); names : p parameter names (default :func:`default_names`);
    joint_of_row : optional (m,) joint index of each row (0..joints-1), for equations whose rows were
    selected individually (e.g. ``ident.processing.processing.Equation.joint``); then m need not be a multiple of joints.
    Raises ``ValueError`` on bad input (shapes, non-finite values, too few rows per joint, a joint whose
    OLS residual is at rounding level, below 1e-12 of its rms torque, so its weight is undefined) and :class:`UnidentifiableError` naming the
    parameters the data do not determine when W (weighted, column-equilibrated) is rank-deficient.
    """
    W, y = check_W_y(W, y)
    m, p = W.shape
    if isinstance(joints, bool) or not isinstance(joints, (int, np.integer)):
        raise TypeError(f"joints must be an int >= 1, got {type(joints).__name__}")
    if joint_of_row is None:
        if joints < 1 or m % joints:
            raise ValueError(f"W must have a multiple of joints={joints} rows (sample k, joint i -> row {joints}k + i), "
                             f"got {m}; pass joint_of_row for individually selected rows")
        joint_of_row = np.tile(np.arange(joints), m // joints)
    else:
        joint_of_row = np.asarray(joint_of_row)
        if joint_of_row.shape != (m,) or not np.issubdtype(joint_of_row.dtype, np.integer) \
                or joint_of_row.min(initial=0) < 0 or joint_of_row.max(initial=0) >= joints:
            raise ValueError(f"joint_of_row must be ({m},) integers in [0, {joints}), got shape {joint_of_row.shape}, "
                             f"dtype {joint_of_row.dtype}")
    if m <= p:
        raise ValueError(f"W must have shape (m, p) with m > p for a variance estimate, got {W.shape}")
    names = default_names(p) if names is None else tuple(names)
    if len(names) != p:
        raise ValueError(f"names must have {p} entries to match W's columns, got {len(names)}")

    sigma = np.empty(joints)
    for j in range(joints):
        Wj, yj = W[joint_of_row == j], y[joint_of_row == j]
        th_j, _, rank_j, _ = np.linalg.lstsq(Wj, yj, rcond=None)
        dof_j = Wj.shape[0] - int(rank_j)
        if dof_j < 1:
            raise ValueError(f"joint {j + 1} needs more rows than the rank of its regressor ({rank_j}), got {Wj.shape[0]} rows")
        ss = float(np.sum((yj - Wj @ th_j) ** 2))
        sigma[j] = np.sqrt(ss / dof_j)
        if not sigma[j] > 1e-12 * np.sqrt(np.mean(yj**2)):
            raise ValueError(
                f"joint {j + 1}: the OLS residual of its own rows is at rounding level (sigma = {sigma[j]:.3g}), so its "
                "weight 1/sigma is undefined (noise-free data?)"
            )

    w = (1.0 / sigma)[joint_of_row]
    Wt = W * w[:, None]
    Yt = y * w
    d = np.sqrt(np.einsum("ij,ij->j", Wt, Wt))
    zero = d == 0.0
    d[zero] = 1.0
    U, s, Vt = np.linalg.svd(Wt / d, full_matrices=False)
    V = Vt.T
    tol = max(m, p) * np.finfo(float).eps * s[0]
    deficient = s <= tol
    if deficient.any() or zero.any():
        bad = set(_null_names(V, deficient, names)) | {names[j] for j in np.flatnonzero(zero)}
        bad_names = tuple(n for n in names if n in bad)
        raise UnidentifiableError(
            f"W is rank-deficient (numerical rank {int(np.sum(~deficient))} < {p} columns): the data do not "
            f"determine {list(bad_names)}; remove or regroup these parameters or use richer excitation",
            names=bad_names,
        )
    theta = (V @ ((U.T @ Yt) / s)) / d
    resid = Yt - Wt @ theta
    dof = m - p
    s2 = float(resid @ resid) / dof
    Vs = V / s  # C = s2 D^-1 V diag(1/s^2) V^T D^-1
    cov = s2 * (Vs @ Vs.T) / d[:, None] / d[None, :]
    std = np.sqrt(s2 * np.einsum("ij,ij->i", Vs, Vs) / d**2)
    with np.errstate(divide="ignore"):
        rel = np.where(theta != 0.0, 100.0 * std / np.abs(np.where(theta != 0.0, theta, 1.0)), np.inf)
    weak = s < 1e-8 * s[0]
    return WLSResult(
        theta=theta,
        std=std,
        rel_std_percent=rel,
        joint_sigma=sigma,
        names=names,
        s2=s2,
        dof=dof,
        cond=float(s[0] / s[-1]),
        poorly_identified=_null_names(V, weak, names),
        cov=cov,
    )
