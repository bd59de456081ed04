"""Kind ``outliers`` (beyond the paper, its conclusion): torque spikes in the measured data; the plain hull is
proven empty, the q-relaxed hull encloses the truth and proves which rows are outliers.

Each run writes ``report.md``, ``boxes.png``, the dataset and the truth; the truth is read here only to check,
never by an estimator.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from h4bench import ident
from h4bench import sim
from h4bench.ident.estimators.outliers import METHODS as OUTLIER_METHODS
from h4bench.ident.estimators.outliers import OutlierBudgetError, relaxed_hull
from h4bench.ident.robots.h4_equation import build_equation
from h4bench.scenarios import report
from h4bench.scenarios.experiment import ExperimentRun, estimate_hull, run_experiment
from h4bench.scenarios.rundir import save_run_files, sim_progress
from h4bench.scenarios.spec import ScenarioError
from h4bench.sim.dataset import atomic_write_bytes

DESCRIPTION = "torque spikes: the plain hull is empty, the q-relaxed hull encloses the truth and proves the outlier rows"


def inject_spikes(run: ExperimentRun, count: int, magnitude: float, rng: np.random.Generator):
    """Add ``+-magnitude`` N m to the measured torque of ``count`` (sample, joint) pairs whose rows the
    estimators see (distinct samples). Returns (spiked Dataset, list of {sample, joint, value})."""
    eq = run.equation
    samples = np.unique(eq.sample)
    if count > samples.size:
        raise ValueError(f"outliers.count must be at most the {samples.size} samples in the equation, got {count}")
    chosen = rng.choice(samples, count, replace=False)
    spikes = []
    tau = run.dataset.tau.copy()
    for s in np.sort(chosen):
        joints = np.unique(eq.joint[eq.sample == s])
        j = int(rng.choice(joints))
        value = float(magnitude * rng.choice([-1.0, 1.0]))
        tau[s, j] += value
        spikes.append({"sample": int(s), "joint": j, "time": float(run.dataset.t[s]), "value": value})
    meta = {**run.dataset.metadata, "outliers_injected": spikes}
    return sim.Dataset(run.dataset.t, run.dataset.q, tau, meta), spikes


def _check_outliers_spec(cfg: dict) -> None:
    for key in ("count", "relax"):
        if isinstance(cfg[key], bool) or not isinstance(cfg[key], int) or cfg[key] < (1 if key == "count" else 0):
            raise ScenarioError(f"outliers.{key} must be an integer >= {1 if key == 'count' else 0}, got {cfg[key]!r}")
    if not (np.isfinite(cfg["magnitude"]) and cfg["magnitude"] > 0):
        raise ScenarioError(f"outliers.magnitude must be a finite number > 0 [N m], got {cfg['magnitude']!r}")
    if cfg["method"] not in OUTLIER_METHODS:
        raise ScenarioError(f"outliers.method must be one of {OUTLIER_METHODS}, got {cfg['method']!r}")


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    """Torque spikes in the measured data: the plain hull fails, the q-relaxed hull encloses the truth."""
    cfg = spec["outliers"]
    _check_outliers_spec(cfg)
    q = int(cfg["relax"])
    progress("experiment", 0, 3)
    run = run_experiment(spec, seed, estimate=False, progress=sim_progress(progress))
    clean = run.equation
    rng = np.random.default_rng([seed, 7])
    dataset, spikes = inject_spikes(run, int(cfg["count"]), float(cfg["magnitude"]), rng)
    eq = build_equation(run.geometry, dataset, run.bound_raw, run.settings, prior=run.prior,
                        structure=spec["structure"]["regressor"])
    if eq.y.shape != clean.y.shape or not np.array_equal(eq.sample, clean.sample):
        raise RuntimeError("the spikes changed the rows of the equation (they must only change the torques)")
    t0 = time.perf_counter()
    try:  # reference: the hull of the same experiment without the spikes (what the relaxed hull should approach)
        clean_box = ident.estimate(clean.W, clean.y, clean.bound, run.prior)
    except ident.InconsistentDataError:
        clean_box = None
    clean_seconds = time.perf_counter() - t0
    run.dataset, run.equation = dataset, eq
    injected_rows = np.flatnonzero(eq.y != clean.y)
    progress("plain hull", 1, 3)
    estimate_hull(run)
    run.claims["relaxed"] = ("guaranteed", True)  # rigorous outer box (see its module)
    progress("relaxed hull", 2, 3)
    t0 = time.perf_counter()
    try:
        run.boxes["relaxed"] = relaxed_hull(eq.W, eq.y, eq.bound, run.prior, q, method=cfg["method"])
    except OutlierBudgetError as exc:
        run.failures["relaxed"] = str(exc)
    run.seconds["relaxed"] = time.perf_counter() - t0
    if spec["estimators"]["wls"]:
        run.wls = ident.wls(eq.W, eq.y, joints=4, names=eq.names, joint_of_row=eq.joint)
    result = run.result()
    box = run.boxes.get("relaxed")
    certain = box.info["certain_rows"] if box is not None else []
    suspected = box.info["suspected_rows"] if box is not None else []
    residual = np.abs(run.residual)
    result["outliers"] = {
        "q": q, "count": int(cfg["count"]), "magnitude": float(cfg["magnitude"]),
        "parallel_filter": bool(eq.info.get("filtered", False)),
        "injected_samples": spikes,
        "injected_rows": injected_rows.tolist(),
        "rows_breaking_bound_at_truth": np.flatnonzero(residual > eq.bound).tolist(),
        "detected_rows_certain": certain,
        "detected_rows_suspected": suspected,
        "certain_are_injected": bool(set(certain) <= set(injected_rows.tolist())),
        "injected_detected_certain": int(len(set(certain) & set(injected_rows.tolist()))),
        "relaxed_exact": bool(box.info["exact"]) if box is not None else False,
        "relaxed_info": {k: box.info[k] for k in ("undecided_rows", "budget_left", "rounds", "partitions")}
        if box is not None else None,
        "clean_hull": None if clean_box is None else {
            "lower": clean_box.lower.tolist(), "upper": clean_box.upper.tolist(),
            "enclosed": clean_box.contains(run.theta_true).tolist(), "seconds": clean_seconds},
        "relaxed_over_clean_width": None if clean_box is None or box is None else
        (box.width / np.where(clean_box.width > 0, clean_box.width, np.nan)).tolist(),
    }
    progress("files", 3, 3)
    save_run_files(run, out, progress)
    shown = dict(result["methods"])
    if clean_box is not None:  # the spike-free hull as a reference in the figure only
        shown["hull without spikes"] = {"status": "ok", "lower": clean_box.lower.tolist(),
                                        "upper": clean_box.upper.tolist()}
    report.plot_beside_plain_hull(result, out, f"q-relaxed hull (q = {q}) on spiked data", shown)
    _write_outliers_report(result, out)
    return result


def _write_outliers_report(result: dict, out: Path) -> None:
    o = result["outliers"]
    relaxed = result["methods"].get("relaxed", {})
    spikes = ", ".join(f"sample {s['sample']} joint {s['joint'] + 1} ({s['value']:+g} N m)" for s in o["injected_samples"])
    lines = [
        report.heading(result, f"{o['count']} torque spikes of {o['magnitude']:g} N m, q = {o['q']}"), "",
        "The q-relaxed set keeps every parameter vector that satisfies all rows but at most q. Parallel filter: "
        + ("on (a spike spreads over several processed rows; q must count them)" if o["parallel_filter"] else
           "off (one spike = one row: processed rows are the raw samples, bound sized for raw-row derivative errors)"),
        "",
        *report.summary_lines(result), "",
        f"- plain hull {report.hull_verdict(result)}",
        f"- q-relaxed hull: {'encloses the truth' if relaxed.get('all_enclosed') else 'DOES NOT enclose the truth'}"
        + (f" (exact hull of S_q: {o['relaxed_exact']})" if relaxed.get("status") == "ok" else ""),
        "", "## Outlier rows", "",
        f"- injected: {spikes}",
        f"- rows they changed: {o['injected_rows']}",
        f"- rows breaking the bound at the true parameters: {o['rows_breaking_bound_at_truth']}",
        f"- certain outliers (proven by interval evaluation over the relaxed box): {o['detected_rows_certain']} "
        f"({o['injected_detected_certain']} of {len(o['injected_rows'])} injected rows)",
        f"- suspected (violated at the relaxed box's midpoint): {o['detected_rows_suspected']}",
        "", "## Against the hull of the same data without spikes", "",
        ("- relaxed width / spike-free hull width: median "
         f"{np.nanmedian(o['relaxed_over_clean_width']):.3g}, max {np.nanmax(o['relaxed_over_clean_width']):.3g} "
         "(parameters at the prior width in both count as 1)" if o["relaxed_over_clean_width"] else
         "- (no spike-free hull: that data set is inconsistent with the bound too)"),
        "", "## Boxes", "", report.table1(result), "", "Plot: `boxes.png`.",
    ]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())
