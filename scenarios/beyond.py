"""Scenarios beyond the paper (its conclusion, future work ii and iii): outliers and an uncertain regressor.

``RUNNERS[kind](spec, seed, out_dir, progress) -> result dict`` (called by :func:`scenarios.runner.run_scenario`
inside its atomic output folder). Each result follows the DESIGN schema (``methods.<name>`` with ``status``,
``lower``, ``upper``, ``enclosed``, ``seconds``) plus a section of its own; each run writes ``report.md``,
``boxes.png``, the dataset and the truth. The truth is read here only to check, never by an estimator.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import ident
import sim
from ident.outliers import OutlierBudgetError, relaxed_hull
from ident.processing import build_equation
from ident.uncertain import interval_equation, regressor_distortion, uncertain_hull
from scenarios import report
from scenarios.experiment import ExperimentRun, run_experiment
from scenarios.runner import _save_run_files, _sim_progress
from scenarios.spec import ScenarioError
from sim.dataset import atomic_write_bytes


def _estimate_plain(run: ExperimentRun) -> None:
    """The ordinary hull on the run's equation: a box, or the failure message when the set is proven empty."""
    eq = run.equation
    t0 = time.perf_counter()
    run.min_consistent_bound = float(ident.min_consistent_bound(eq.W, eq.y, run.prior))
    t1 = time.perf_counter()
    try:
        run.boxes["hull"] = ident.estimate(eq.W, eq.y, eq.bound, run.prior, method="hull")
    except ident.InconsistentDataError as exc:
        run.failures["hull"] = str(exc)
    run.seconds["hull"] = time.perf_counter() - t1
    run.seconds["min_consistent_bound"] = t1 - t0


def _plain_verdict(result: dict) -> str:
    m = result["methods"]["hull"]
    if m["status"] != "ok":
        return "fails: the feasible set is proven empty (InconsistentDataError)"
    if not m["all_enclosed"]:
        missed = [n for n, e in zip(result["parameters"], m["enclosed"]) if not e]
        return f"fails: its box misses the true value of {missed}"
    return "encloses the truth (the failure this scenario is built to show did not happen)"


# ------------------------------------------------------------------------------------------------ outliers
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
    if cfg["method"] not in ("auto", "exact", "groups"):
        raise ScenarioError(f"outliers.method must be one of ('auto', 'exact', 'groups'), got {cfg['method']!r}")


def _outliers(spec: dict, seed: int, out: Path, progress) -> dict:
    """Torque spikes in the measured data: the plain hull fails, the q-relaxed hull encloses the truth."""
    cfg = spec["outliers"]
    _check_outliers_spec(cfg)
    q = int(cfg["relax"])
    progress("experiment", 0, 3)
    run = run_experiment(spec, seed, estimate=False, progress=_sim_progress(progress))
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
    _estimate_plain(run)
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
    _save_run_files(run, out, progress)
    shown = dict(result["methods"])
    if clean_box is not None:  # the spike-free hull as a reference in the figure only
        shown["hull without spikes"] = {"status": "ok", "lower": clean_box.lower.tolist(),
                                        "upper": clean_box.upper.tolist()}
    report.plot_boxes({**result, "methods": shown}, out / "boxes.png",
                      title=f"{result['scenario']}: q-relaxed hull (q = {q}) on spiked data; plain hull: "
                            f"{result['methods']['hull']['status']}")
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
        f"- plain hull {_plain_verdict(result)}",
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


# ----------------------------------------------------------------------------------------- uncertain regressor
def _uncertain(spec: dict, seed: int, out: Path, progress) -> dict:
    """Quantisation and filtering errors in the regressor: the point hull fails under a bound that covers the
    noise only, the interval-regressor (Oettli-Prager) hull encloses the truth."""
    cfg = spec["uncertain"]
    if not (np.isfinite(cfg["safety"]) and cfg["safety"] > 0):
        raise ScenarioError(f"uncertain.safety must be a finite number > 0, got {cfg['safety']!r}")
    if not 0.0 <= cfg["calibration_spread"] < 1.0:
        raise ScenarioError(f"uncertain.calibration_spread must be in [0, 1), got {cfg['calibration_spread']!r}")
    for key in ("sign_band", "second_order_margin"):
        if not (np.isfinite(cfg[key]) and cfg[key] >= 0):
            raise ScenarioError(f"uncertain.{key} must be a finite number >= 0, got {cfg[key]!r}")
    structure = spec["structure"]["regressor"]
    progress("experiment", 0, 4)
    run = run_experiment(spec, seed, estimate=False, progress=_sim_progress(progress))
    progress("point hull", 1, 4)
    _estimate_plain(run)
    # the distortion assumption: measured on a calibration simulation (same reference trajectory, another
    # noise seed, a robot whose parameters differ by up to calibration_spread), times a safety factor
    progress("calibration", 2, 4)
    cal_seed = seed + int(cfg["calibration_seed_offset"])
    spread = float(cfg["calibration_spread"])
    cal_model = sim.randomised_model(cal_seed, spread, spec["model"] or None) if spread > 0 else run.model
    cal = run_experiment(spec, cal_seed, model=cal_model, reference=run.reference, estimate=False)
    geometry = run.geometry

    def regressor_fn(q, qd, qdd):
        return ident.regressor(geometry, q, qd, qdd, structure=structure)

    measured = regressor_distortion(regressor_fn, cal.truth.q, cal.truth.qd, cal.truth.qdd, run.settings)
    assumed = measured.scaled(float(cfg["safety"]))
    progress("interval hull", 3, 4)
    counts = int(spec["encoder"]["counts_per_turn"]) or None
    t0 = time.perf_counter()
    ieq = interval_equation(regressor_fn, run.dataset.q, run.dataset.tau, run.bound_raw, run.settings,
                            counts_per_turn=counts, distortion=assumed, sign_band=float(cfg["sign_band"]),
                            second_order_margin=float(cfg["second_order_margin"]))
    t_eq = time.perf_counter() - t0
    try:
        run.boxes["interval"] = uncertain_hull(ieq.Wc, ieq.D, ieq.y, ieq.bound, run.prior)
    except ident.InconsistentDataError as exc:
        run.failures["interval"] = str(exc)
    run.seconds["interval"] = time.perf_counter() - t0
    # checks with the truth (never seen by the estimators)
    own = regressor_distortion(regressor_fn, run.truth.q, run.truth.qd, run.truth.qdd, run.settings)
    th = run.theta_true
    op_violation = float(np.max(np.maximum((ieq.Wc - ieq.D) @ th - ieq.y - ieq.bound,
                                           ieq.y - ieq.bound - (ieq.Wc + ieq.D) @ th)))
    result = run.result()
    names = list(result["parameters"])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(assumed.regressor > 0, own.regressor / assumed.regressor, 0.0)
    result["uncertain"] = {
        "encoder_counts_per_turn": counts,
        "encoder_radii": {"q": ieq.info["encoder_radii"][0], "qd": ieq.info["encoder_radii"][1],
                          "qdd": ieq.info["encoder_radii"][2]} if counts else None,
        "interval_rows": len(ieq), "raw_rows": ieq.info["raw_rows"],
        "sign_uncertain_raw_rows": ieq.info["sign_uncertain_rows"],
        "bound_processed": float(ieq.bound.max()),
        "calibration": {"seed": cal_seed, "parameter_spread": spread, "safety": float(cfg["safety"]),
                        "same_reference": True},
        "distortion_assumed_max_per_column": dict(zip(names, assumed.regressor.max(axis=0).tolist())),
        "distortion_assumed_qd": assumed.qd.tolist(),
        "distortion_run_max_per_column": dict(zip(names, own.regressor.max(axis=0).tolist())),
        "distortion_run_qd": own.qd.tolist(),
        "distortion_run_over_assumed_max": float(max(np.max(ratio), np.max(own.qd / np.maximum(assumed.qd, 1e-300)))),
        "distortion_assumption_held": bool(np.all(own.regressor <= assumed.regressor) and np.all(own.qd <= assumed.qd)),
        "truth_in_interval_set": bool(op_violation <= 0.0),
        "truth_interval_set_margin": -op_violation,
        "radius_mean_per_column": dict(zip(names, ieq.D.mean(axis=0).tolist())),
        "second_order_margin": float(cfg["second_order_margin"]),
        "interval_equation_seconds": t_eq,
    }
    progress("files", 4, 4)
    _save_run_files(run, out, progress)
    report.plot_boxes(result, out / "boxes.png", title=f"{result['scenario']}: interval-regressor hull; point-regressor hull: "
                            f"{result['methods']['hull']['status']}")
    _write_uncertain_report(result, out)
    return result


def _write_uncertain_report(result: dict, out: Path) -> None:
    u = result["uncertain"]
    m = result["methods"].get("interval", {})
    enc = u["encoder_radii"]
    lines = [
        report.heading(result, "an interval regressor"), "",
        "The regressor is built from quantised angles through filters; its error is put where it belongs, in an "
        "interval regressor [Wc - D, Wc + D], and the bound keeps only the torque noise and model allowance.", "",
        *report.summary_lines(result), "",
        f"- point-regressor hull {_plain_verdict(result)}",
        f"- interval-regressor hull: {'encloses the truth' if m.get('all_enclosed') else 'DOES NOT enclose the truth'}"
        + (f", mean width {np.mean(m['width']):.4g}" if m.get("status") == "ok" else f" ({m.get('message')})"),
        "", "## What the interval regressor rests on", "",
        (f"- encoder: {u['encoder_counts_per_turn']} counts/turn, |e| <= pi/counts; state radii through the code's own "
         f"filters (rigorous): q {enc['q']:.3g} rad, qd {enc['qd']:.3g} rad/s, qdd {enc['qdd']:.3g} rad/s^2"
         if enc else "- encoder: exact angles"),
        f"- nonlinear columns (Mnac, Ibc): first-order central differences, exact quadratic qd terms, mixed terms "
        f"covered by a {100 * u['second_order_margin']:.0f} % margin (stated, not proven)",
        f"- Coulomb column [-1, 1] on {u['sign_uncertain_raw_rows']} of {u['raw_rows']} raw rows (sign of the true "
        "speed not certain); no speed-threshold exclusion",
        f"- filter distortion of the true motion: ASSUMED <= {u['calibration']['safety']:g} x its value on a calibration "
        f"simulation (same reference, noise seed {u['calibration']['seed']}, robot parameters within "
        f"+-{100 * u['calibration']['parameter_spread']:.0f} %); on this run it reached "
        f"{u['distortion_run_over_assumed_max']:.3g} of the assumed value "
        f"(assumption {'held' if u['distortion_assumption_held'] else '**VIOLATED**'})",
        f"- the true parameter vector {'is' if u['truth_in_interval_set'] else '**is NOT**'} in the interval feasible "
        f"set (margin {u['truth_interval_set_margin']:.3g} N m)",
        "", "## Boxes", "", report.table1(result), "", "Plot: `boxes.png`.",
    ]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())


RUNNERS = {"outliers": _outliers, "uncertain_regressor": _uncertain}
