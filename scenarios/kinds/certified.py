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

from pathlib import Path

from h4bench.scenarios import report
from h4bench.scenarios.certificate import certify, verdict_lines
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.rundir import save_run_files, sim_progress
from h4bench.sim.dataset import atomic_write_bytes

DESCRIPTION = "the derived (certified) error model: interval equation from sensor and motion specifications"

# [error_model]: 0 means "from the simulator's own settings" (counts_per_turn: encoder.counts_per_turn;
# torque_error: the injected error's bound noise.bound) or, for qd_max / qdd_max, "stated from the reference
# trajectory's peak times motion_margin_qd / motion_margin_qdd", qdd_max at least that peak plus
# disturbance_factor_qdd times the torque error's acceleration through the nominal inertia (0: without it)
SPEC_DEFAULTS = {
    "error_model": {"counts_per_turn": 0, "torque_error": 0.0, "qd_max": 0.0, "qdd_max": 0.0,
                    "motion_margin_qd": 1.25, "motion_margin_qdd": 2.0, "disturbance_factor_qdd": 2.0,
                    "model_error": 0.0},
    # enabled: other kinds (the enclosure campaign, `h4bench run ... --error-model derived`) add the certified box
    "certified": {"kernel_steps": 0, "kernel_shape": "hann", "stride": 2, "curvature_every": 10,
                  "encoder_jets": "auto", "enabled": False},
}


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    from h4bench.ident.workers import prewarm
    from h4bench.scenarios.threads import hull_processes

    prewarm(hull_processes())  # the certified stage's second process starts while the simulation runs
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
    rr = (result.get("certified") or {}).get("row_radius")
    lines = [*verdict_lines(result), "", report.heading(result, "the derived (certified) error model"), "",
             f"- certified box: {'encloses the truth' if m.get('all_enclosed') else 'DOES NOT enclose the truth'}"
             f" ({m['status']}); width / tuned hull, geometric mean: {result['width_vs_tuned_geomean']}",
             f"- certificate: {c['status']}, {c['rows']} rows, {c['violations']} violations, smallest margin "
             f"{c['min_margin']:.4g} N m",
             *([f"- certified row radius: torque side (torque, model, rounding) max {rr['torque_side_max']:.4g} N m; "
                f"whole row at {rr['at']}: median {rr['total_median']:.4g} N m, max {rr['total_max']:.4g} N m"]
               if rr else []),
             "", "The tuned hull beside it (the paper's processing and allowance):", "",
             *report.summary_lines(result),
             "", "| term | max radius at the truth [N m] | mean share |", "|---|---|---|",
             *(f"| {k} | {v:.4g} | {c['shares'][k]:.3f} |" for k, v in c["terms"].items()), "",
             "Not proven (sampled bounds instead): " + ("; ".join(c["equation"]["not_proven"]) or
                                                        f"nothing ({c['equation']['encoder_boxes_proven']} encoder "
                                                        f"boxes and {c['equation']['motion_boxes_proven']} motion "
                                                        "tubes verified)"), "", report.table1(result)]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())
