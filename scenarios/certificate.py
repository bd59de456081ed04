"""The certified box of a simulated run (:func:`certify`, the simulated robot's ErrorSpec) and its certificate,
checked row by row against the run's ground truth.

The certificate of a derived interval equation, checked row by row against a simulation's ground truth.

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

``status`` is ``failed`` when any stated assumption does not hold (a motion bound or the torque error below the
truth's, a stated motion bound the measured positions contradict) or any row violates a check, each named in
``failed`` (entry, joint, stated and true values); ``violations`` counts every failed check (all terms);
``min_margin`` is the smallest ``radius - |actual|`` of the total check [N m]; ``terms`` each term's largest radius
at the true parameters [N m] and ``shares`` its mean share of the row radius.
"""

from __future__ import annotations

import time

import numpy as np

from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.processing.motion_check import check_motion_bounds
from h4bench.ident.processing.weakform import row_check
from h4bench.portable import exp, log
from h4bench.ident.robots.h4_certified import Processing, certified_equation, stated_assumptions
from h4bench.scenarios import judging
from h4bench.scenarios.certified_verdict import H4_HINTS, prior_diagnosis, row_radius_summary
from h4bench.scenarios.spec import ScenarioError
from h4bench.scenarios.threads import hull_processes

__all__ = ["assumption_failures", "certify", "check_certificate", "processing_of", "simulated_error_spec",
           "torque_error_acceleration",
           "verdict_lines"]

_COLUMN_CHECKED = slice(0, 10)  # Imot1-4, Mnac, Ibc, Fv1-4


def check_certificate(geometry, ceq, truth, tau_logged, error_spec, processing, theta_true) -> dict:
    """The certificate entry of ``result.json`` (module docstring).

    ceq : the :class:`~ident.robots.h4_certified.CertifiedEquation` of the measured log; truth : the run's
    ``sim.GroundTruth``; tau_logged (n, 4) [N m]; error_spec, processing : what ``ceq`` was built with.
    """
    th = np.asarray(theta_true, dtype=float)
    # the same kernels and rows as the measured log's equation (the family depends on the log's length only); the
    # measured log's motion tubes hold every true state of their steps, so their second-derivative bounds serve
    # every step whose exact tube they are checked to contain (the jets compute the others)
    exact = certified_equation(geometry, truth.q, truth.tau_applied, error_spec, processing, position_error=0.0,
                               motion=ceq.motion, processes=hull_processes())
    t = ceq.terms
    checks = {
        "torque": row_check(exact.y - ceq.y, t["torque"]),
        "measurement": row_check((ceq.Wc - exact.Wc)[:, _COLUMN_CHECKED],
                              (t["measurement"] + t["second_order"])[:, _COLUMN_CHECKED]),
        "motion": row_check(exact.y - exact.Wc @ th, (exact.terms["truncation"] + exact.terms["sign"]) @ th
                         + exact.terms["model"] + exact.terms["rounding"]),
        "total": row_check(ceq.y - ceq.Wc @ th, ceq.bound + ceq.D @ th),
    }
    radii = {"torque": t["torque"], "model": t["model"], "rounding": t["rounding"],
             **{k: t[k] @ th for k in ("measurement", "second_order", "truncation", "sign")}}
    total = sum(radii.values())
    qd_true, qdd_true = np.abs(truth.qd).max(axis=0), np.abs(truth.qdd).max(axis=0)
    motion_held = bool(np.all(qd_true <= error_spec.qd_max) and np.all(qdd_true <= error_spec.qdd_max))
    failed = assumption_failures(error_spec, qd_true, qdd_true,
                                 np.abs(np.asarray(truth.tau_applied) - np.asarray(tau_logged)).max(axis=0))
    failed += [f"{c['violations']} of {len(ceq)} rows violate the certificate's {name} check (largest actual error "
               f"{c['max_actual_over_radius']:.4g} x its radius)" for name, c in checks.items() if c["violations"]]
    return {
        "status": "failed" if failed else "ok", "failed": failed,
        "rows": len(ceq), "violations": int(sum(c["violations"] for c in checks.values()) + (not motion_held)),
        "min_margin": checks["total"]["min_margin"], "checks": checks,
        "terms": {k: float(np.max(v)) for k, v in radii.items()},
        "shares": {k: float(np.mean(v / total)) for k, v in radii.items()},
        "motion_bounds": {"qd_max": error_spec.qd_max.tolist(), "qd_true_max": qd_true.tolist(),
                          "qdd_max": error_spec.qdd_max.tolist(), "qdd_true_max": qdd_true.tolist(),
                          "held": motion_held},
        "equation": dict(ceq.info),
    }


def assumption_failures(error_spec, qd_true, qdd_true, torque_error_true) -> list[str]:
    """Every stated bound of ``error_spec`` below the simulated truth's value, one line each (entry, joint, stated,
    true): ``qd_max``, ``qdd_max`` against the true motion's max |qd|, |qdd| (4,) [rad/s, rad/s^2], and
    ``torque_error`` against the injected error's max |applied - logged| (4,) [N m]."""
    out = []
    for entry, stated, true, unit, what in (
            ("qd_max", error_spec.qd_max, qd_true, "rad/s", "max |qd|"),
            ("qdd_max", error_spec.qdd_max, qdd_true, "rad/s^2", "max |qdd|"),
            ("torque_error", error_spec.torque_error, torque_error_true, "N m", "injected max |tau_applied - "
                                                                               "tau_logged|")):
        out += [f"{entry} of joint {i + 1} = {stated[i]:.6g} {unit} is below the simulated truth's {what} = "
                f"{true[i]:.6g} {unit}" for i in np.flatnonzero(np.asarray(true) > np.asarray(stated))]
    return out


def verdict_lines(result: dict) -> list[str]:
    """The first lines of a report with a certified box: the certificate's verdict (every failed assumption or
    check named), then the box's (encloses the truth or not; the parameters left at the prior and why)."""
    c, m = result["certificate"], result["methods"]["certified"]
    if c.get("status") == "failed":
        lines = [f"**Certified box: FAILED**: {len(c['failed'])} stated assumption(s) or check(s) do not hold in "
                 "this simulation, so the box is not certified:", "", *(f"- {f}" for f in c["failed"])]
    else:
        lines = [f"**Certified box: {'encloses the truth' if m.get('all_enclosed') else 'DOES NOT enclose the truth'}"
                 f"** ({m['status']}); the certificate holds: {c['rows']} rows, 0 violations, every stated "
                 "assumption held by the truth."]
    diag = (result.get("certified") or {}).get("prior_diagnosis") or {}
    if diag.get("message"):
        lines += ["", f"- {diag['message']}"]
    return lines


def simulated_error_spec(spec: dict, reference, dt: float, noise_bound: float, tau_logged=None,
                         model=None) -> ErrorSpec:
    """The simulated robot's ErrorSpec: its sensor facts from the simulator's settings, its motion bounds stated
    from the reference (see the module docstring); ``sources`` says which is which.

    model : the simulated ``mujoco.MjModel`` (default the shipped H4): its friction-loss rows give the
    ``friction_band`` (:func:`sim.friction.friction_band`, with the stated ``qdd_max`` and the prior's upper
    bound ``spec["prior"]["upper"]`` on Fs): MuJoCo's soft friction is Coulomb's only above it.

    tau_logged : (N, 4) the logged torques, or None. The simulator adds the injected error to the command in
    floating point, so ``|applied - logged|`` exceeds ``noise.bound`` by up to half an ulp of the applied torque
    (a square wave at its bound does: 1.3 + 7e-15 N m); with the log given, the derived torque error is
    ``noise.bound + 2^-52 (max |tau_logged| + noise.bound)``, which covers it."""
    em = spec["error_model"]
    counts = int(em["counts_per_turn"]) or int(spec["encoder"]["counts_per_turn"])
    if counts < 1:
        raise ScenarioError("error_model.counts_per_turn (or encoder.counts_per_turn) must be >= 1: the derived "
                            f"error model needs a position resolution, got {counts}")
    for key in ("motion_margin_qd", "motion_margin_qdd"):
        if not (np.isfinite(em[key]) and em[key] >= 1.0):
            raise ScenarioError(f"error_model.{key} must be a number >= 1 (a tracking margin), got {em[key]!r}")
    factor = em.get("disturbance_factor_qdd", 0.0)
    if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not (np.isfinite(factor) and factor >= 0):
        raise ScenarioError(f"error_model.disturbance_factor_qdd must be a number >= 0 (0: no torque-error term), "
                            f"got {factor!r}")
    torque = float(em["torque_error"]) or float(noise_bound)
    rounding = not em["torque_error"] and tau_logged is not None
    if rounding:  # the applied torque's float sum (docstring)
        ulp = np.nextafter(2.0**-52 * (float(np.max(np.abs(tau_logged))) + torque), np.inf)
        torque = float(np.nextafter(torque + ulp, np.inf))
    qd = float(em["qd_max"]) or em["motion_margin_qd"] * np.abs(np.asarray(reference.qd)).max(axis=0)
    from h4bench.sim.friction import friction_band  # noqa: PLC0415
    from h4bench.sim.model import load_model  # noqa: PLC0415

    model = load_model() if model is None else model
    qdd, disturbance = float(em["qdd_max"]), None
    if not qdd:
        peak = np.abs(np.asarray(reference.qdd)).max(axis=0)
        qdd = em["motion_margin_qdd"] * peak
        if factor:
            from h4bench import sim  # noqa: PLC0415

            disturbance = torque_error_acceleration(sim.H4Geometry.from_model(model), reference.q, torque)
            qdd = np.maximum(qdd, peak + factor * disturbance)

    fs_max = float(spec["prior"]["upper"])
    band = friction_band(model, qdd, fs_max)
    sources = {
        "friction_band": (f"the simulator's friction law (MuJoCo's soft friction loss, sim.friction): Coulomb's "
                          f"Fs sign(qd) wherever |qd| >= (qdd_max + R Fs) / b, with b and R of its friction rows "
                          f"and Fs <= {fs_max:g} N m (the prior); checked against the truth in the certificate's "
                          "motion and total checks"),
        "position_resolution": f"the simulator's encoder: {counts} counts per turn, rounded to the nearest count",
        "sample_period": "the simulator's sample period (torques held over each step)",
        "torque_error": ("stated in error_model.torque_error" if em["torque_error"] else
                         "the injected torque error's rigorous bound (noise.bound)" + (
                             " plus the float rounding of the applied torque (2^-52 of the largest |tau|)"
                             if rounding else "")),
        "qd_max": (f"stated: {em['motion_margin_qd']:g} x the reference trajectory's peak |qd| per joint (tracking "
                   "margin), checked against the truth" if not em["qd_max"] else "stated in error_model.qd_max"),
        "qdd_max": ("stated in error_model.qdd_max" if em["qdd_max"] else
                    f"stated: {em['motion_margin_qdd']:g} x the reference trajectory's peak |qdd| per joint "
                    "(tracking margin)" + ("" if disturbance is None else
                                           f", or that peak plus {factor:g} x the torque error's acceleration "
                                           "through the nominal inertia (max over the reference of "
                                           "sum_j |M_nom(q)^-1|_ij x torque_error: "
                                           + ", ".join(f"{v:.4g}" for v in disturbance) + " rad/s^2) if larger")
                    + ", checked against the truth"),
        "model_error": (f"stated: {float(em['model_error']):g} N m in the scenario's [error_model] model_error "
                        "(0: the regressor is taken as the simulated robot's exact structure), checked against the "
                        "truth in the certificate's motion and total checks"),
    }
    return ErrorSpec(n_joints=4, sample_period=float(dt), position_resolution=2 * np.pi / counts,
                     position_rounding="nearest", torque_timing="hold", torque_error=torque, qd_max=qd, qdd_max=qdd,
                     model_error=float(em["model_error"]), friction_band=band, sources=sources)


def torque_error_acceleration(geometry, q, torque_error) -> np.ndarray:
    """(4,) the acceleration a torque error of ``torque_error`` [N m] per motor gives each joint through the
    NOMINAL inertia, at worst along the motion q (n, 4) [rad]: ``max_t sum_j |M(q_t)^-1|_ij torque_error``
    [rad/s^2], with ``M = diag(Ia) + J^T diag(M, M, M, Mz) J`` of :data:`ident.NOMINAL_PARAMETERS` (what the
    controller is designed on, never the truth; :func:`sim.axis_inertia` is its diagonal). Solved without LAPACK
    (:func:`h4bench.portable.solve4`), so the same on every CPU. The torque error is disturbance the feedback
    answers only after it acts: a statement of the motion bounds adds (a multiple of) it to the reference's
    accelerations (:func:`simulated_error_spec`)."""
    from h4bench.ident import NOMINAL_PARAMETERS  # noqa: PLC0415
    from h4bench.portable import solve4  # noqa: PLC0415
    from h4bench.sim.kinematics import jacobians  # noqa: PLC0415

    theta = np.asarray(NOMINAL_PARAMETERS, dtype=float)
    J = jacobians(geometry, np.atleast_2d(np.asarray(q, dtype=float))).J
    mass = np.array([theta[4], theta[4], theta[4], theta[5]])
    M = np.einsum("nai,a,naj->nij", J, mass, J) + np.diag(theta[:4])
    inv = solve4(M, np.broadcast_to(np.eye(4), M.shape))
    return np.abs(inv).sum(axis=2).max(axis=0) * float(torque_error)


def processing_of(spec: dict) -> Processing:
    """The scenario's ``[certified]`` table as :class:`Processing`; errors name the table and the key."""
    c = spec["certified"]
    try:  # kernel_steps 0: every kernel of the family (ident.processing.choice)
        return Processing(kernel_steps=int(c["kernel_steps"]) or None, kernel_shape=str(c["kernel_shape"]),
                          stride=int(c["stride"]), curvature_every=int(c["curvature_every"]),
                          encoder_jets=str(c.get("encoder_jets", "auto")))
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"[certified] {exc}") from None


def certify(run_, spec: dict) -> dict:
    """The certified box of an experiment run, judged, with its certificate; adds ``certified`` to the run's
    boxes and returns the extra result keys (``certificate``, ``error_model``, ``width_vs_tuned_geomean``,
    ``methods.certified``)."""
    error_spec = simulated_error_spec(spec, run_.reference, run_.dataset.dt, run_.noise_bound, run_.dataset.tau,
                                      model=run_.model)
    processing = processing_of(spec)
    t0 = time.perf_counter()
    ceq = certified_equation(run_.geometry, run_.dataset.q, run_.dataset.tau, error_spec, processing,
                             processes=hull_processes())
    t_eq = time.perf_counter() - t0
    outcomes, _ = judging.run_methods(["certified"], ceq.Wc, ceq.y, ceq.bound, run_.prior,
                                      {"regressor_radius": ceq.D, "groups": ceq.joint.astype(np.int64)})
    entry = judging.judge(outcomes, None, run_.theta_true, list(ceq.names))["certified"]
    entry["equation_seconds"] = t_eq
    t0 = time.perf_counter()
    cert = check_certificate(run_.geometry, ceq, run_.truth, run_.dataset.tau, error_spec, processing,
                             run_.theta_true)
    cert["seconds"] = time.perf_counter() - t0
    data_check = check_motion_bounds(run_.dataset.q, error_spec)  # what identify --spec would say, no truth
    cert["spec_check"] = data_check.to_dict()
    if data_check.contradicted:
        cert["failed"] += [f"data check: {c}" for c in data_check.contradicted]
        cert["status"] = "failed"
    error_model = error_spec.to_dict()
    error_model["sources"].update(stated_assumptions(ceq.info))
    out = {"certificate": cert, "error_model": error_model, "certified_entry": entry,
           "width_vs_tuned_geomean": None, "width_vs_tuned": None}
    if entry["status"] == "ok":
        theta_abs = np.maximum(np.abs(np.asarray(entry["lower"])), np.abs(np.asarray(entry["upper"])))
        rel = np.asarray(entry["width"]) / (run_.prior.upper - run_.prior.lower)
        out["certified"] = {"prior_diagnosis": prior_diagnosis(ceq.names, rel, ceq.terms, theta_abs, ceq.y, H4_HINTS),
                            "row_radius": row_radius_summary(ceq.bound, ceq.D, theta_abs,
                                                             "the certified box's largest |theta|")}
    tuned = run_.boxes.get("hull")
    if entry["status"] == "ok" and tuned is not None:
        ratio = np.asarray(entry["width"]) / np.maximum(tuned.width, 1e-300)
        out["width_vs_tuned"] = ratio.tolist()
        out["width_vs_tuned_geomean"] = float(exp(np.mean(log(ratio))))
    return out
