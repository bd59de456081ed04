"""The error budget of a simulated dataset: where the oracle residual ``y - W theta_true`` comes from.

On the rows the estimators see, the residual splits exactly (everything is linear, the filter included):

    y - W_est theta = -e                          injected torque noise (measured = applied - e)
                      + (W_exact - W_est) theta   derivative estimation (filtered q, central differences)
                      + (tau_applied - W_exact theta)   model mismatch (soft loops, friction band, structure)

with W_exact the regressor on the simulator's exact states. Each part is passed through the same parallel
filter and row selection as the data. Reads the ground truth: scenario layer only.
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.processing.filtering import ProcessingSettings, parallel_filter
from h4bench.ident.robots.h4_equation import raw_equation
from h4bench.ident.robots.h4 import regressor

PARTS = ("noise", "derivatives", "model")


def error_budget(geometry, dataset, truth, settings: ProcessingSettings, structure: str = "paper",
                 theta=None, raw=None) -> dict:
    """Max |.| (and 99th percentile) of each part of the oracle residual, raw and after the processing.

    Returns {"raw": {part: {"max", "p99"}}, "processed": {...}, "total_raw_max", "total_processed_max",
    "rows_processed"}; theta defaults to the truth's (for the extended structure pass the 22 values); raw : the
    dataset's ``raw_equation(geometry, dataset.q, dataset.tau, dataset.dt, settings, structure)`` when the caller
    has it already (evaluated here otherwise).
    """
    theta = truth.theta if theta is None else np.asarray(theta, dtype=float)
    if raw is None:
        raw = raw_equation(geometry, dataset.q, dataset.tau, dataset.dt, settings, structure)
    w_est, y, keep, samples, _ = raw
    w_exact = regressor(geometry, truth.q[samples], truth.qd[samples], truth.qdd[samples], structure=structure)
    parts = {
        "noise": -truth.noise[samples].reshape(-1),
        "derivatives": (w_exact - w_est) @ theta,
        "model": truth.tau_applied[samples].reshape(-1) - w_exact @ theta,
    }
    total = y - w_est @ theta

    def stats(v):
        a = np.abs(v)
        return {"max": float(a.max()) if a.size else 0.0, "p99": float(np.percentile(a, 99)) if a.size else 0.0}

    out = {"raw": {k: stats(v[keep]) for k, v in parts.items()}, "total_raw_max": stats(total[keep])["max"]}
    taps = settings.taps()
    if settings.decimation == 1 and taps.size == 1:
        out["processed"] = out["raw"]
        out["total_processed_max"] = out["total_raw_max"]
        out["rows_processed"] = int(keep.sum())
        return out
    # the parts and the total filtered together as the columns of one regressor (each column by the same recursive
    # sum over the taps as a y alone: the same values)
    names = list(PARTS) + ["total"]
    fe = parallel_filter(np.column_stack([parts[k] for k in PARTS] + [total]), np.zeros(y.size), 0.0,
                         settings.decimation, taps=taps)
    mask = fe.propagate_mask(keep)
    filtered = {name: fe.W[mask, i] for i, name in enumerate(names)}
    out["processed"] = {k: stats(filtered[k]) for k in PARTS}
    out["total_processed_max"] = stats(filtered["total"])["max"]
    out["rows_processed"] = int(mask.sum())
    return out
