"""The TX40 with the derived error model (``h4bench run tx40 --error-model derived``): the certified box.

The log's stated specification (``[tx40.error_model]``, :func:`error_spec`), the derived interval equation of
:mod:`ident.robots.serial_certified` on the identification part and, separately, on the held-out part, the
Oettli-Prager hull in the physical prior (:func:`ident.estimators.uncertain_signed.signed_uncertain_hull`), its
held-out coverage (the interval envelope ``[Wc - D, Wc + D] x box`` widened by the row's bound, against the
held-out rows' torques), which term dominates the radii, the width beside the tuned hull, and the width's
sensitivity to the assumed torque error (the bound's torque term scaled, the equation unchanged).

Position error: the file writes MOTOR angles with 5 significant digits (``ErrorSpec.position_error`` of the motor
angles: half a unit in the last written place), mapped to the joints through ``|R^-1|`` (the conversion
``q = R^-1 q_motor + offsets`` of :mod:`ident.robots.tx40`, a linear map: ``|dq| <= |R^-1| |dq_motor|``).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["DEFAULTS", "certify", "error_spec", "report_lines"]

# [tx40.certified] and [tx40.error_model]: every entry a sensor fact or a stated assumption, with its source
DEFAULTS = {
    # refine: at most that many rounds of the hull with the last box as prior, until the widths' geometric mean
    # shrinks by less than refine_rtol; the sweep runs from the largest factor down, each from the box before
    "certified": {"half_width": 200, "stride": 100, "max_samples": 0, "torque_sweep": [0.5, 1.0, 2.0], "refine": 8,
                  "refine_rtol": 0.02},
    "error_model": {
        "sample_period": 2e-4, "significant_digits": 5, "torque_timing": "sample",
        "torque_error": [3.96, 3.96, 3.1, 1.38, 1.3, 0.92],
        "qd_max": [9.69, 8.29, 10.21, 18.06, 19.81, 27.49],
        "qdd_max": [1200.0, 950.0, 2000.0, 1600.0, 1700.0, 2400.0],
        "model_error": 0.0,
        "sources": {
            "sample_period": "TX40_config.yaml ts (5 kHz), a fact of the log",
            "significant_digits": "the file format: pos_read_data.csv writes motor angles with 5 significant "
                                  "digits (mapped to the joints through |R^-1|)",
            "torque_timing": "stated: currents sampled at the sample instants; between samples the torque is "
                             "assumed within torque_error of the samples' interpolation (no torque_rate stated)",
            "torque_error": "stated assumption: 3 % of each joint's URDF effort limit (current sensing, torque "
                            "constant and ripple of current-derived torques); the width's sensitivity is reported",
            "qd_max": "Staubli TX40 data sheet nominal joint speeds (555, 475, 585, 1035, 1135, 1575 deg/s); "
                      "checked against the data (only checked: the radii use the step's own speed bound)",
            "qdd_max": "stated: about twice the largest |qdd| the data prove (586, 468, 999, 781, 844, 1171 "
                       "rad/s^2: second differences over every span, minus the position error, all at a span of one "
                       "0.2 ms step), per joint; checked against the data",
            "model_error": "stated: 0 (the rigid-body model with viscous + Coulomb friction is assumed exact)",
        },
    },
}


def error_spec(cfg_em: dict):
    """The :class:`ErrorSpec` of the TX40 log from ``[tx40.error_model]`` (6 joints)."""
    from h4bench.ident.processing.errorspec import ErrorSpec, ErrorSpecError
    from h4bench.scenarios.spec import ScenarioError

    try:
        return ErrorSpec.from_mapping(dict(cfg_em), 6, where="tx40.error_model")
    except ErrorSpecError as exc:
        raise ScenarioError(str(exc)) from None


def joint_position_error(spec, q_motor) -> np.ndarray:
    """(N, 6) bound on the joint-side position error [rad] from the motor angles' format (module docstring)."""
    from h4bench.ident.robots import tx40

    e_motor = spec.position_error(q_motor)
    return e_motor @ np.abs(np.linalg.inv(tx40.ratio_matrix())).T


def _envelope(eq, lower, upper):
    """Rigorous ``[min, max]`` of ``W theta`` over ``W in [Wc - D, Wc + D]``, ``theta in [lower, upper]``."""
    from h4bench.ident.estimators.residuals import interval_envelope

    return interval_envelope(eq.Wc, eq.D, lower, upper)


def _coverage(eq, box, bound):
    from h4bench.ident.estimators.residuals import covered

    lo, hi = _envelope(eq, box.lower, box.upper)
    inside = covered(eq.y, lo, hi, bound)  # the widened envelope rounded outward
    return float(np.mean(inside)), [float(np.mean(inside[eq.joint == j])) for j in range(6)]


def _hull(eq, bound, prior, refine, rtol):
    from h4bench.ident import InconsistentDataError
    from h4bench.ident.estimators.uncertain_signed import coarse_step, signed_uncertain_hull
    from h4bench.scenarios.threads import hull_processes

    try:
        coarse = coarse_step(len(np.unique(eq.window, axis=0)))
        return signed_uncertain_hull(eq.Wc, eq.D, eq.y, bound, prior, refine=refine, rtol=rtol, coarse=coarse,
                                     groups=eq.window, processes=hull_processes()), None
    except InconsistentDataError as exc:
        return None, str(exc)


def certify(s, cfg: dict, tuned: dict | None, progress=None) -> dict:
    """The certified box of the TX40 study ``s`` (:class:`scenarios.tx40_steps.Study` after its stages).

    cfg : the ``[tx40]`` section (``certified``, ``error_model``); tuned : the tuned hull's method entry the width
    is compared with (None: no comparison). Returns ``{"entry": the method entry, "error_model": ...,
    "certified": ...}`` (JSON-ready; the schema is in ``docs/results.md``).
    """
    from h4bench import ident
    from h4bench.ident.processing.motion_check import check_motion_bounds
    from h4bench.ident.robots.serial_certified import certified_equation
    from h4bench.scenarios.threads import hull_processes
    from h4bench.scenarios.certified_verdict import SERIAL_HINTS, prior_diagnosis, row_radius_summary
    from h4bench.scenarios.identify_serial_certified import stated_assumptions
    from h4bench.scenarios.tx40_steps import jsonable

    progress = progress or (lambda *a: None)
    cc = cfg["certified"]
    spec = error_spec(cfg["error_model"])
    if abs(spec.sample_period - s.log.dt) > 1e-12:
        raise ValueError(f"tx40.error_model.sample_period must be the log's {s.log.dt} s, got {spec.sample_period}")
    t0 = time.perf_counter()
    n1 = s.n1 if not cc["max_samples"] else min(s.n1, int(cc["max_samples"]))
    n2 = s.n - s.n1 if not cc["max_samples"] else min(s.n - s.n1, max(int(cc["max_samples"]) // 2, 3000))
    e = joint_position_error(spec, s.log.q_motor[:s.n])
    check = check_motion_bounds(s.q[:s.n], spec, position_error=e[:s.n])
    if check.contradicted:  # a false premise: no equation, no box (as identify --spec)
        from h4bench.scenarios.certified_verdict import contradicted_entry

        em = spec.to_dict()
        em["sources"].update(stated_assumptions(spec))
        return jsonable({"entry": {**contradicted_entry(check, "tx40.error_model"), "rows": 0, "rows_heldout": 0,
                                   "seconds": time.perf_counter() - t0},
                         "error_model": em, "certified": {"spec_check": check.to_dict()}})
    kw = {"half_width": int(cc["half_width"]), "stride": int(cc["stride"])}
    sl = slice(s.n1, s.n1 + n2)
    # each equation's second half in a worker process beside its first when 2 cores are there (same bits)
    procs = hull_processes()
    eq = certified_equation(s.robot, s.base, s.q[:n1], s.tau[:n1], spec, position_error=e[:n1], **kw,
                            progress=lambda i, n: progress("certified equation", i, 2 * n), processes=procs)
    eq_ho = certified_equation(s.robot, s.base, s.q[sl], s.tau[sl], spec, position_error=e[sl], first_sample=s.n1,
                               **kw, progress=lambda i, n: progress("certified equation", n + i, 2 * n),
                               processes=procs)
    t_eq = time.perf_counter() - t0
    prior = ident.Box(s.blo, s.bhi, names=s.base.names)
    refine, rtol = int(cc["refine"]), float(cc["refine_rtol"])
    sweep = {}
    box1 = None
    t1 = time.perf_counter()
    start = prior  # a smaller torque error gives a subset of the larger one's set: its box is a valid prior
    for f in sorted(cc["torque_sweep"], reverse=True):
        bound = eq.bound + (float(f) - 1.0) * eq.terms["torque"]
        bound_ho = eq_ho.bound + (float(f) - 1.0) * eq_ho.terms["torque"]
        box, msg = _hull(eq, bound, start, refine, rtol)
        if box is None:
            sweep[f"{f:g}"] = {"status": "inconsistent", "message": msg}
            continue
        start = box
        rel = box.width / (s.bhi - s.blo)
        cov, cov_j = _coverage(eq_ho, box, bound_ho)
        sweep[f"{f:g}"] = {"status": "ok", "relative_width_to_prior_median": float(np.median(rel)),
                           "relative_width_to_prior_geomean": float(np.exp(np.mean(np.log(np.maximum(rel, 1e-300))))),
                           "narrowed_parameters": int(np.sum(rel < 0.99)), "heldout_coverage": cov,
                           "refinements": box.info.get("refinements")}
        if float(f) == 1.0:
            box1, cov1, cov1_j = box, cov, cov_j
    t_hull = time.perf_counter() - t1
    entry: dict = {"kind": "guaranteed", "rigorous": True, "seconds": t_eq + t_hull,
                   "rows": len(eq), "rows_heldout": len(eq_ho)}
    if box1 is None:
        entry.update({"status": "inconsistent", "message": sweep.get("1", {}).get("message", "no 1x entry")})
    else:
        rel = box1.width / (s.bhi - s.blo)
        entry.update({"status": "ok", "lower": box1.lower.tolist(), "upper": box1.upper.tolist(),
                      "width": box1.width.tolist(), "relative_width_to_prior": rel.tolist(),
                      "wls_inside": bool(box1.contains(s.w.theta).all()),
                      "heldout_coverage": cov1, "heldout_coverage_per_joint": cov1_j,
                      "info": {k: box1.info.get(k) for k in ("nonempty_proven", "refinements", "lp_solves")}})
        if tuned is not None and tuned.get("status") == "ok":
            ratio = box1.width / np.asarray(tuned["width"], dtype=float)
            entry["width_vs_tuned"] = ratio.tolist()
            entry["width_vs_tuned_geomean"] = float(np.exp(np.mean(np.log(ratio))))
            entry["tuned_method"] = f"hull_{tuned['factor']:g}x"
    # which term dominates: the row radii at the largest |theta| of the box the hull worked with
    theta_abs = (np.maximum(np.abs(box1.lower), np.abs(box1.upper)) if box1 is not None
                 else np.maximum(np.abs(s.blo), np.abs(s.bhi)))
    rw = eq.row_radius(np.abs(s.w.theta))
    certified = {
        "rows": len(eq), "rows_heldout": len(eq_ho), "identify_samples": int(n1), "heldout_samples": int(n2),
        "kernel": {k: eq.info[k] for k in ("kernel", "half_width", "stride", "window_seconds", "secant_half_span")},
        "geometry": eq.info["geometry"],
        "terms_at": "|theta| = the certified box's largest magnitudes (the radius the hull had to allow)",
        **eq.summary(theta_abs),
        "radius_median_per_joint_at_wls": [float(np.median(rw["total"][eq.joint == j])) for j in range(6)],
        "wls_residual_max_per_joint": [float(np.max(np.abs((eq.y - eq.Wc @ s.w.theta)[eq.joint == j])))
                                       for j in range(6)],
        "torque_error_sweep": sweep,
        "row_radius": row_radius_summary(eq.bound, eq.D, theta_abs, "the certified box's largest |theta|"
                                         if box1 is not None else "the prior's largest |theta|"),
        "spec_check": check.to_dict(),
        "position_error_max_per_joint": e[:s.n].max(axis=0).tolist(),
        "seconds": {"equations": t_eq, "hulls": t_hull},
    }
    if box1 is not None:
        certified["prior_diagnosis"] = prior_diagnosis(s.base.names, box1.width / (s.bhi - s.blo), eq.terms,
                                                       theta_abs, eq.y, SERIAL_HINTS)
    em = spec.to_dict()
    em["sources"].update(stated_assumptions(spec))
    em["position_error_note"] = "5 significant digits of the MOTOR angles, mapped to the joints through |R^-1|"
    return jsonable({"entry": entry, "error_model": em, "certified": certified})


def report_lines(result: dict) -> list[str]:
    """The report's section on the certified box."""
    c, m = result.get("certified"), result["methods"].get("certified")
    if not c or not m:
        return []
    if m["status"] == "spec_contradicted":
        return ["", "## Certified box (derived error model)", "",
                "**No certified box: the data contradict the stated motion bounds** (the radii rest on them):", "",
                *(f"- {line}" for line in m["contradicted"])]
    lines = ["", "## Certified box (derived error model)", "",
             f"{c['rows']} identification rows, {c['rows_heldout']} held-out rows (triangle kernel of "
             f"{c['kernel']['window_seconds'] * 1e3:.0f} ms, a row every {c['kernel']['stride']} samples). Status: "
             f"{m['status']}."]
    if m["status"] == "ok" and (c.get("prior_diagnosis") or {}).get("message"):
        lines.append(c["prior_diagnosis"]["message"])
    if m["status"] == "ok":
        lines.append(f"Median width / prior {np.median(m['relative_width_to_prior']):.3g}; held-out coverage "
                     f"{m['heldout_coverage']:.4f}; WLS inside: {m['wls_inside']}"
                     + (f"; width / {m['tuned_method']} geometric mean {m['width_vs_tuned_geomean']:.3g}."
                        if "width_vs_tuned_geomean" in m else "."))
    lines += ["", "| term | max [N m] | median [N m] | share |", "|---|---|---|---|"]
    lines += [f"| {k} | {v['max']:.4g} | {v['median']:.4g} | {v['share']:.3f} |" for k, v in c["terms"].items()]
    lines += ["", f"Dominant term: {c['dominant']} ({c['terms_at']}).", "",
              "| torque error x | status | median width / prior | narrowed parameters | held-out coverage |",
              "|---|---|---|---|---|"]
    for f, v in c["torque_error_sweep"].items():
        lines.append(f"| {f} | {v['status']} | {v.get('relative_width_to_prior_median', float('nan')):.3g} | "
                     f"{v.get('narrowed_parameters', '')} | {v.get('heldout_coverage', float('nan')):.4f} |")
    bad = c["spec_check"]["contradicted"]
    lines += ["", "Stated motion bounds against the data: " + ("; ".join(bad) if bad else "not contradicted") + "."]
    return lines
