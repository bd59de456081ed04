"""Why a box is as wide as it is: slack times geometry, and the comparison with the paper's Table 1.

For the processed equation with row bounds ``b_k`` and oracle residual ``r = y - W theta_true``, scale every row
to the reference bound ``b = max_k b_k`` (``W'_k = W_k b / b_k``, ``r'_k = r_k b / b_k``; the feasible set is
unchanged). With ``h_j = max delta_j s.t. |W' delta| <= 1`` (one LP per parameter:
:func:`trajectories.halfwidths`) and ``rho = max |r'|``, the feasible set contains ``theta_true + (b - rho) P``
and lies in ``theta_true + (b + rho) P`` with ``P = {delta : |W' delta| <= 1}``, so each hull width lies between
``2 (b - rho) h_j`` and ``2 (b + rho) h_j`` before the prior cuts them (here: ``theta_true +- s h_j`` cut by
the prior, an approximation of the cut of the polytope). The lower end is the *predicted width*:
narrow boxes need a small slack ``b - rho`` (an error bound close to the real error) and small ``h_j`` (an
informative motion). Pronzato & Walter (Automatica 25(3), 1989) for bounded-error experiment design.
"""

from __future__ import annotations

import math

import numpy as np

from scenarios.report import PAPER_TABLE1, PAPER_TABLE2


def paper_relative_widths(names) -> np.ndarray:
    """The paper's relative widths per parameter: Table 1 width / |Table 2 WLS value| (NaN where absent)."""
    out = np.full(len(names), np.nan)
    for j, name in enumerate(names):
        if name in PAPER_TABLE1 and name in PAPER_TABLE2:
            lo, hi = PAPER_TABLE1[name]
            out[j] = (hi - lo) / abs(PAPER_TABLE2[name][0])
    return out


def width_analysis(W, y, bound, theta_true, prior_lower, prior_upper, names, hull_width=None) -> dict:
    """Half-widths, slack, predicted and actual widths, and ratios to the paper's Table 1 (module docstring).

    W (m, p), y (m,), bound scalar or (m,) [N m], theta_true (p,), prior bounds (p,), hull_width (p,) or None.
    """
    from trajectories import halfwidths

    W = np.asarray(W, dtype=float)
    b_rows = np.broadcast_to(np.asarray(bound, dtype=float), (W.shape[0],))
    b = float(b_rows.max())
    scale = b / b_rows
    r = (np.asarray(y, float) - W @ np.asarray(theta_true, float)) * scale
    rho = float(np.abs(r).max())
    h = halfwidths(W * scale[:, None]).h
    lo, hi, th = np.asarray(prior_lower, float), np.asarray(prior_upper, float), np.asarray(theta_true, float)
    slack = b - rho

    def clipped(s):  # the interval theta_true +- s h_j, cut by the prior
        return np.minimum(th + s * h, hi) - np.maximum(th - s * h, lo)

    predicted = clipped(max(slack, 0.0))
    predicted_upper = clipped(b + rho)
    true = np.abs(np.asarray(theta_true, float))
    out = {
        "reference_bound": b, "rho": rho, "slack": slack, "h": h.tolist(),
        "predicted_width": predicted.tolist(), "predicted_width_upper": predicted_upper.tolist(),
    }
    paper = paper_relative_widths(names)
    if hull_width is not None:
        width = np.asarray(hull_width, float)
        rel = np.where(true > 0, width / np.where(true > 0, true, 1.0), np.inf)
        ratio = rel / paper
        known = np.isfinite(ratio)
        out.update({
            "width": width.tolist(), "relative_width": rel.tolist(), "paper_relative_width": paper.tolist(),
            "ratio_to_paper": ratio.tolist(),
            "at_most_paper": int(np.sum(ratio[known] <= 1.0)), "compared": int(known.sum()),
            "geometric_mean_ratio": float(math.exp(np.mean(np.log(ratio[known])))) if known.any() else None,
        })
    return out
