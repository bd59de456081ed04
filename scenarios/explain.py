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

The *slice width* of parameter j is the width of the feasible set's slice through the truth along j (the other
parameters fixed to their true values, cut by the prior): an interval intersection, one per row. The slice lies
in the feasible set, so no box from these data, by any estimator, is narrower: it separates what the data and
the bound allow from what the coupling between parameters costs.
"""

from __future__ import annotations

import math

import numpy as np

from h4bench.scenarios.report import PAPER_TABLE1, PAPER_TABLE2


def paper_relative_widths(names) -> np.ndarray:
    """The paper's relative widths per parameter: Table 1 width / |Table 2 WLS value| (NaN where absent)."""
    out = np.full(len(names), np.nan)
    for j, name in enumerate(names):
        if name in PAPER_TABLE1 and name in PAPER_TABLE2:
            lo, hi = PAPER_TABLE1[name]
            out[j] = (hi - lo) / abs(PAPER_TABLE2[name][0])
    return out


def slice_widths(W, y, bound, theta_true, prior_lower, prior_upper) -> np.ndarray:
    """(p,) width of ``{theta_j : |y - W theta| <= bound, theta_i = theta_true_i for i != j}`` cut by the prior
    (0 where that slice is empty, i.e. the bound does not cover the truth's residual on some row)."""
    W = np.asarray(W, dtype=float)
    b = np.broadcast_to(np.asarray(bound, dtype=float), (W.shape[0],))
    th = np.asarray(theta_true, dtype=float)
    r_all = np.asarray(y, dtype=float) - W @ th  # residual at the truth
    out = np.empty(W.shape[1])
    for j in range(W.shape[1]):
        a = W[:, j]
        nz = a != 0.0
        if np.any(~nz & (np.abs(r_all) > b)):
            out[j] = 0.0
            continue
        # |r_all - a d| <= b with d = theta_j - theta_true_j
        lo_k = (r_all[nz] - np.sign(a[nz]) * b[nz]) / a[nz]
        hi_k = (r_all[nz] + np.sign(a[nz]) * b[nz]) / a[nz]
        lo = max(float(prior_lower[j]) - th[j], float(lo_k.max()) if lo_k.size else -np.inf)
        hi = min(float(prior_upper[j]) - th[j], float(hi_k.min()) if hi_k.size else np.inf)
        out[j] = max(0.0, hi - lo)
    return out


def width_analysis(W, y, bound, theta_true, prior_lower, prior_upper, names, hull_width=None) -> dict:
    """Half-widths, slack, predicted and actual widths, and ratios to the paper's Table 1 (module docstring).

    W (m, p), y (m,), bound scalar or (m,) [N m], theta_true (p,), prior bounds (p,), hull_width (p,) or None.
    """
    from h4bench.trajectories import halfwidths

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
    sw = slice_widths(W, y, b_rows, theta_true, lo, hi)
    s_ratio = np.where(true > 0, sw / np.where(true > 0, true, 1.0), np.inf) / paper
    s_known = np.isfinite(s_ratio) & (s_ratio > 0)
    out.update({"slice_width": sw.tolist(), "slice_ratio_to_paper": s_ratio.tolist(),
                "slice_at_most_paper": int(np.sum(s_ratio[np.isfinite(s_ratio)] <= 1.0)),
                "slice_geometric_mean_ratio": float(math.exp(np.mean(np.log(s_ratio[s_known]))))
                if s_known.all() and s_known.any() else None})
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
