"""Kind ``certified``: the paper's setting with the derived error model (no allowance) beside the tuned hull.

The simulated robot's :class:`~ident.processing.errorspec.ErrorSpec` comes from the simulator's own settings
(encoder counts per turn, sample period, the injected torque error's rigorous bound) and stated motion bounds
(the reference trajectory's peak |qd|, |qdd| per joint times a stated tracking margin, checked against the truth
in the certificate). The derived interval equation (:mod:`ident.robots.h4_certified`) gives the ``certified``
box (the registry's Oettli-Prager hull with ``regressor_radius``); the tuned ``hull`` of the paper's processing
(``noise.bound + bound.allowance``) runs beside it. The certificate (:mod:`scenarios.certificate`) checks every
radius against the truth, which no estimator sees.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.robots.h4_certified import Processing, certified_equation
from h4bench.scenarios import judging, report
from h4bench.scenarios.certificate import check_certificate
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.rundir import save_run_files, sim_progress
from h4bench.scenarios.spec import ScenarioError
from h4bench.sim.dataset import atomic_write_bytes

DESCRIPTION = "the derived (certified) error model: interval equation from sensor and motion specifications"

# [error_model]: 0 means "from the simulator's own settings" (counts_per_turn: encoder.counts_per_turn;
# torque_error: the injected error's bound noise.bound) or, for qd_max / qdd_max, "stated from the reference
# trajectory's peak times motion_margin_qd / motion_margin_qdd"
SPEC_DEFAULTS = {
    "error_model": {"counts_per_turn": 0, "torque_error": 0.0, "qd_max": 0.0, "qdd_max": 0.0,
                    "motion_margin_qd": 1.25, "motion_margin_qdd": 1.5, "model_error": 0.0},
    "certified": {"kernel_steps": 100, "kernel_shape": "hann", "stride": 2, "curvature_every": 10},
}


def simulated_error_spec(spec: dict, reference, dt: float, noise_bound: float) -> ErrorSpec:
    """The simulated robot's ErrorSpec: its sensor facts from the simulator's settings, its motion bounds stated
    from the reference (see the module docstring); ``sources`` says which is which."""
    em = spec["error_model"]
    counts = int(em["counts_per_turn"]) or int(spec["encoder"]["counts_per_turn"])
    if counts < 1:
        raise ScenarioError("error_model.counts_per_turn (or encoder.counts_per_turn) must be >= 1: the derived "
                            f"error model needs a position resolution, got {counts}")
    for key in ("motion_margin_qd", "motion_margin_qdd"):
        if not (np.isfinite(em[key]) and em[key] >= 1.0):
            raise ScenarioError(f"error_model.{key} must be a number >= 1 (a tracking margin), got {em[key]!r}")
    torque = float(em["torque_error"]) or float(noise_bound)
    qd = float(em["qd_max"]) or em["motion_margin_qd"] * np.abs(np.asarray(reference.qd)).max(axis=0)
    qdd = float(em["qdd_max"]) or em["motion_margin_qdd"] * np.abs(np.asarray(reference.qdd)).max(axis=0)
    sources = {
        "position_resolution": f"the simulator's encoder: {counts} counts per turn, rounded to the nearest count",
        "sample_period": "the simulator's sample period (torques held over each step)",
        "torque_error": ("stated in error_model.torque_error" if em["torque_error"] else
                         "the injected torque error's rigorous bound (noise.bound)"),
        "qd_max": (f"stated: {em['motion_margin_qd']:g} x the reference trajectory's peak |qd| per joint (tracking "
                   "margin), checked against the truth" if not em["qd_max"] else "stated in error_model.qd_max"),
        "qdd_max": (f"stated: {em['motion_margin_qdd']:g} x the reference trajectory's peak |qdd| per joint "
                    "(tracking margin), checked against the truth" if not em["qdd_max"] else
                    "stated in error_model.qdd_max"),
        "model_error": "stated in error_model.model_error",
    }
    return ErrorSpec(n_joints=4, sample_period=float(dt), position_resolution=2 * np.pi / counts,
                     position_rounding="nearest", torque_timing="hold", torque_error=torque, qd_max=qd, qdd_max=qdd,
                     model_error=float(em["model_error"]), sources=sources)


def processing_of(spec: dict) -> Processing:
    c = spec["certified"]
    return Processing(kernel_steps=int(c["kernel_steps"]), kernel_shape=str(c["kernel_shape"]),
                      stride=int(c["stride"]), curvature_every=int(c["curvature_every"]))


def certify(run_, spec: dict) -> dict:
    """The certified box of an experiment run, judged, with its certificate; adds ``certified`` to the run's
    boxes and returns the extra result keys (``certificate``, ``error_model``, ``width_vs_tuned_geomean``,
    ``methods.certified``)."""
    error_spec = simulated_error_spec(spec, run_.reference, run_.dataset.dt, run_.noise_bound)
    processing = processing_of(spec)
    t0 = time.perf_counter()
    ceq = certified_equation(run_.geometry, run_.dataset.q, run_.dataset.tau, error_spec, processing)
    t_eq = time.perf_counter() - t0
    outcomes, _ = judging.run_methods(["certified"], ceq.Wc, ceq.y, ceq.bound, run_.prior,
                                      {"regressor_radius": ceq.D, "groups": ceq.joint.astype(np.int64)})
    entry = judging.judge(outcomes, None, run_.theta_true, list(ceq.names))["certified"]
    entry["equation_seconds"] = t_eq
    t0 = time.perf_counter()
    cert = check_certificate(run_.geometry, ceq, run_.truth, run_.dataset.tau, error_spec, processing,
                             run_.theta_true)
    cert["seconds"] = time.perf_counter() - t0
    out = {"certificate": cert, "error_model": error_spec.to_dict(), "certified_entry": entry,
           "width_vs_tuned_geomean": None, "width_vs_tuned": None}
    tuned = run_.boxes.get("hull")
    if entry["status"] == "ok" and tuned is not None:
        ratio = np.asarray(entry["width"]) / np.maximum(tuned.width, 1e-300)
        out["width_vs_tuned"] = ratio.tolist()
        out["width_vs_tuned_geomean"] = float(np.exp(np.mean(np.log(ratio))))
    return out


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    progress("experiment", 0, 3)
    run_ = run_experiment(spec, seed, progress=sim_progress(progress))
    progress("certified", 1, 3)
    extra = certify(run_, spec)
    progress("files", 2, 3)
    save_run_files(run_, out, progress)
    result = run_.result()
    result["methods"]["certified"] = extra.pop("certified_entry")
    result.update(extra)
    result["bound_parts"]["certified"] = "derived from error_model (no allowance)"
    _write_report(result, out)
    return result


def _write_report(result: dict, out: Path) -> None:
    c = result["certificate"]
    m = result["methods"]["certified"]
    lines = [report.heading(result, "the derived (certified) error model"), "",
             *report.summary_lines(result), "",
             f"- certified box: {'encloses the truth' if m.get('all_enclosed') else 'DOES NOT enclose the truth'}"
             f" ({m['status']}); width / tuned hull, geometric mean: {result['width_vs_tuned_geomean']}",
             f"- certificate: {c['rows']} rows, {c['violations']} violations, smallest margin {c['min_margin']:.4g} N m",
             "", "| term | max radius at the truth [N m] | mean share |", "|---|---|---|",
             *(f"| {k} | {v:.4g} | {c['shares'][k]:.3f} |" for k, v in c["terms"].items()), "",
             "Not proven (stated): " + "; ".join(c["equation"]["not_proven"]), "", report.table1(result)]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())
