"""The certificate of a derived interval equation, checked row by row against a simulation's ground truth.

The truth (exact sampled positions, applied torques, true parameters) is read here only to check, never by an
estimator. Per processed row and term, the derived radius beside the actual error:

* ``torque``: ``sum_w K_w (tau_applied - tau_logged)`` against ``torque_error * integral |k|``;
* ``measurement``: each column's centre from the measured positions minus the same functional of the true
  sampled positions, against the column's measurement + second-order radius (Imot, Mnac, Ibc, Fv columns;
  the Coulomb columns are checked in ``motion`` and ``total``);
* ``motion``: the weak-form equation of the TRUE positions and applied torques, ``|y - Wc theta|``, against its
  truncation + sign radii at the true parameters plus the model bound (what the stated qd_max, qdd_max and the
  model bound must cover);
* ``total``: ``|y - Wc theta_true| <= bound + D theta_true`` on the equation the estimator saw.

``violations`` counts every failed check (all terms); ``min_margin`` is the smallest ``radius - |actual|`` of
the total check [N m]; ``terms`` each term's largest radius at the true parameters [N m] and ``shares`` its mean
share of the row radius.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_certificate"]

_COLUMN_CHECKED = slice(0, 10)  # Imot1-4, Mnac, Ibc, Fv1-4


def _check(actual, radius) -> dict:
    actual, radius = np.abs(np.asarray(actual, dtype=float)), np.asarray(radius, dtype=float)
    margin = radius - actual
    return {"violations": int(np.sum(margin < 0)), "min_margin": float(margin.min()),
            "max_actual": float(actual.max()), "max_radius": float(radius.max()),
            "max_actual_over_radius": float(np.max(actual / np.maximum(radius, 1e-300)))}


def check_certificate(geometry, ceq, truth, tau_logged, error_spec, processing, theta_true) -> dict:
    """The certificate entry of ``result.json`` (module docstring).

    ceq : the :class:`~ident.robots.h4_certified.CertifiedEquation` of the measured log; truth : the run's
    ``sim.GroundTruth``; tau_logged (n, 4) [N m]; error_spec, processing : what ``ceq`` was built with.
    """
    from h4bench.ident.robots.h4_certified import certified_equation  # noqa: PLC0415

    th = np.asarray(theta_true, dtype=float)
    exact = certified_equation(geometry, truth.q, truth.tau_applied, error_spec, processing, position_error=0.0)
    t = ceq.terms
    checks = {
        "torque": _check(exact.y - ceq.y, t["torque"]),
        "measurement": _check((ceq.Wc - exact.Wc)[:, _COLUMN_CHECKED],
                              (t["measurement"] + t["second_order"])[:, _COLUMN_CHECKED]),
        "motion": _check(exact.y - exact.Wc @ th, (exact.terms["truncation"] + exact.terms["sign"]) @ th
                         + exact.terms["model"] + exact.terms["rounding"]),
        "total": _check(ceq.y - ceq.Wc @ th, ceq.bound + ceq.D @ th),
    }
    radii = {"torque": t["torque"], "model": t["model"], "rounding": t["rounding"],
             **{k: t[k] @ th for k in ("measurement", "second_order", "truncation", "sign")}}
    total = sum(radii.values())
    qd_true, qdd_true = np.abs(truth.qd).max(axis=0), np.abs(truth.qdd).max(axis=0)
    motion_held = bool(np.all(qd_true <= error_spec.qd_max) and np.all(qdd_true <= error_spec.qdd_max))
    return {
        "rows": len(ceq), "violations": int(sum(c["violations"] for c in checks.values()) + (not motion_held)),
        "min_margin": checks["total"]["min_margin"], "checks": checks,
        "terms": {k: float(np.max(v)) for k, v in radii.items()},
        "shares": {k: float(np.mean(v / total)) for k, v in radii.items()},
        "motion_bounds": {"qd_max": error_spec.qd_max.tolist(), "qd_true_max": qd_true.tolist(),
                          "qdd_max": error_spec.qdd_max.tolist(), "qdd_true_max": qdd_true.tolist(),
                          "held": motion_held},
        "equation": dict(ceq.info),
    }
