"""Kind ``paper``: the paper's setting (Table 1 boxes and Table 2 WLS) on a simulated H4, beside the truth.

Beyond the tables: the projections of the feasible set onto its most coupled pairs of parameters with every
method's set beside them (``feasible_set`` in ``result.json``, ``feasible_set.png``; :mod:`scenarios.feasible`),
and the guaranteed torque on a held-out motion (``prediction``, ``prediction.png``): a second designed
trajectory (seed ``seed + prediction.seed_offset``) simulated and processed the same way, each of a stated
subsample of its rows bounded over the feasible polytope (two warm-started LPs with safe bounds,
:func:`ident.estimators.envelope.prediction_envelope`) and over the hull box (interval evaluation, rounded
outward). A held-out torque lies in the envelope widened by its row's bound whenever the truth is feasible and
the bound covers the held-out oracle residual, so the coverage is 100 % then.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from h4bench.scenarios import report
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.rundir import save_run_files, sim_progress

DESCRIPTION = "the paper's Table 1 (boxes) and Table 2 (WLS) beside the truth"


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    progress("experiment", 0, 1)
    run_ = run_experiment(spec, seed, progress=sim_progress(progress))
    extra, skipped = [], {}
    why = None if "hull" in run_.boxes else run_.failures.get("hull", "the spec's methods do not include hull")
    if spec["feasible"]["enabled"]:
        if why is None:
            progress("feasible set", 0, 1)
            run_.feasible = feasible_set(run_, out)
            extra.append(feasible_lines(run_.feasible))
        else:
            skipped["feasible_set"] = {"pairs": [], "skipped": f"no hull box: {why}"}
    if spec["prediction"]["enabled"]:
        if why is None:
            progress("held-out prediction", 0, 1)
            run_.prediction = held_out_prediction(run_, seed + spec["prediction"]["seed_offset"], out,
                                                  progress=sim_progress(progress))
            extra.append(prediction_lines(run_.prediction))
        else:
            skipped["prediction"] = {"skipped": f"no hull box: {why}"}
    save_run_files(run_, out, progress)
    result = run_.result()
    result.update(skipped)
    for key in ("feasible", "prediction"):
        entry = getattr(run_, key, None)
        if entry is not None:
            result["feasible_set" if key == "feasible" else "prediction"] = entry
            result["timings"][key] = entry["seconds"]
    report.plot_boxes(result, out / "boxes.png")
    report.write_paper_report(result, out, extra="\n".join(extra) + "\n## Controller design\n\n```\n"
                              + run_.controller_report + "\n```\n")
    return result


def feasible_set(run_, out: Path) -> dict:
    """The projections of the run's feasible set, the methods' sets beside them, ``feasible_set.png``."""
    from h4bench.ident.estimators import isolation
    from h4bench.scenarios.feasible import drawn_methods, parse_pairs, plot_feasible_set, reference_sets
    from h4bench.scenarios.feasible import feasible_set as project

    cfg, eq = run_.spec["feasible"], run_.equation
    names = list(eq.names)
    pairs = parse_pairs(",".join(cfg["pairs"]), names, "feasible.pairs") if cfg["pairs"] else None
    polys, entry = project(eq.W, eq.y, eq.bound, run_.boxes["hull"], names, pairs, count=cfg["count"],
                           directions=cfg["directions"], refine=cfg["refine"])
    t0 = time.perf_counter()
    methods = cfg["methods"] or drawn_methods(run_.spec["estimators"]["methods"])
    sets, seconds, skipped = reference_sets(eq.W, eq.y, eq.bound, run_.prior, methods, boxes=run_.boxes,
                                            groups=np.asarray(eq.joint, dtype=np.int64),
                                            timeout=run_.spec["estimators"].get("method_timeout"))
    sets = {m: sets[m] for m in methods if m in sets}
    kinds = {m: isolation.resolve(m).estimator.kind for m in sets}
    from h4bench.ident import parameter_units

    plot_feasible_set(polys, sets, run_.theta_true, out / "feasible_set.png",
                      units=parameter_units(run_.spec["structure"]["regressor"]), kinds=kinds, prior=run_.prior)
    for q, pj in zip(polys, entry["pairs"]):
        i, j = q.indices
        pj["truth_inside"] = q.vertices.shape[0] >= 3 and _inside(q, run_.theta_true[[i, j]])
    entry.update(methods_drawn=list(sets), methods_skipped=skipped, methods_seconds=seconds,
                 drawing_seconds=time.perf_counter() - t0)
    return entry


def _inside(poly, point) -> bool:
    """The point inside the (counter-clockwise) polygon, to a relative 1e-12 of its size."""
    v = poly.vertices
    e = np.roll(v, -1, axis=0) - v
    cross = e[:, 0] * (point[1] - v[:, 1]) - e[:, 1] * (point[0] - v[:, 0])
    return bool(np.all(cross >= -1e-12 * np.abs(e).sum(axis=1) * (np.abs(v).max() + 1e-300)))


def subsample_rows(joint, rows: int) -> np.ndarray:
    """Indices of about ``rows`` rows, the same number from each joint, evenly spaced within it, joint by joint
    (each in time order: consecutive envelope LPs then have close optima, so the warm starts are cheap)."""
    joint = np.asarray(joint)
    groups = np.unique(joint)
    per = max(1, int(rows) // max(groups.size, 1))
    out = []
    for g in groups:
        idx = np.flatnonzero(joint == g)
        out.append(idx[np.unique(np.linspace(0, idx.size - 1, min(per, idx.size)).round().astype(np.int64))])
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def held_out_prediction(run_, seed: int, out: Path, progress=None, arrays: dict | None = None) -> dict:
    """Simulate the held-out motion of ``seed`` on the same robot, process it the same way, bound its torques.

    arrays : a dict that receives the held-out rows and envelopes (``W``, ``y``, ``bound``, ``polytope``
    ``(lo, hi)``, ``box`` ``(lo, hi)``) when given. Returns the ``prediction`` entry of ``result.json``."""
    from h4bench.ident.estimators.envelope import envelope_lp
    from h4bench.ident.estimators.residuals import box_envelope, covered
    from h4bench.scenarios.feasible import plot_prediction

    cfg = run_.spec["prediction"]
    t0 = time.perf_counter()
    held = run_experiment(run_.spec, seed, model=run_.model, model_path=run_.model_path,
                          theta_true=run_.theta_true, estimate=False, progress=progress)
    t_sim = time.perf_counter() - t0
    eq, ho, hull = run_.equation, held.equation, run_.boxes["hull"]
    n = len(ho)
    rows = subsample_rows(ho.joint, int(cfg["rows"]))
    W2, y2, b2 = ho.W[rows], ho.y[rows], ho.bound[rows]
    t1 = time.perf_counter()
    lo_p, hi_p, info = envelope_lp(eq.W, eq.y, eq.bound, hull.lower, hull.upper, W2)
    t_poly = time.perf_counter() - t1
    lo_b, hi_b = box_envelope(W2, hull.lower, hull.upper)  # the box's envelope, rigorous (outward)
    inside_p, inside_b = covered(y2, lo_p, hi_p, b2), covered(y2, lo_b, hi_b, b2)
    if arrays is not None:
        arrays.update(W=W2, y=y2, bound=b2, polytope=(lo_p, hi_p), box=(lo_b, hi_b))
    r_true = np.abs(y2 - W2 @ run_.theta_true)
    pred_true = W2 @ run_.theta_true
    joint = np.asarray(ho.joint)[rows]
    sel = joint == int(cfg["joint"]) - 1
    t_rows = np.asarray(held.dataset.t)[np.asarray(ho.sample)[rows]]
    plot_prediction(t_rows[sel], y2[sel], lo_p[sel], hi_p[sel], lo_b[sel], hi_b[sel], b2[sel],
                    out / "prediction.png", joint=f"joint {cfg['joint']}",
                    title=f"Held-out motion (seed {seed}): joint {cfg['joint']} torque and its guaranteed envelopes")
    return {
        "seed": int(seed),
        "rows": int(rows.size),
        "rows_available": int(n),
        "subsample": "evenly spaced rows of each joint of the held-out processed equation, rows / 4 per joint",
        "coverage": float(np.mean(inside_p)),
        "coverage_box": float(np.mean(inside_b)),
        "envelope_width_median": {"polytope": float(np.median(hi_p - lo_p)), "box": float(np.median(hi_b - lo_b))},
        "envelope_width_median_per_joint": {
            "polytope": [float(np.median((hi_p - lo_p)[joint == k])) for k in range(4) if np.any(joint == k)],
            "box": [float(np.median((hi_b - lo_b)[joint == k])) for k in range(4) if np.any(joint == k)]},
        "bound": float(np.max(b2)),
        "oracle_residual": float(np.max(r_true)),
        "bound_covers_residual": bool(np.all(r_true <= b2)),
        "truth_in_envelope": float(np.mean((pred_true >= lo_p) & (pred_true <= hi_p))),
        "joint_plotted": int(cfg["joint"]),
        "lp_solves": int(info["lp_solves"]),
        "lp_failures": int(info["lp_failures"]),
        "working_rows": int(info["working_rows"]),
        "seconds": float(t_poly),
        "simulation_seconds": float(t_sim),
    }


def feasible_lines(entry: dict) -> str:
    """The report's section on the projections."""
    lines = ["## The feasible set, projected (`feasible_set.png`)", "",
             f"Pairs: {entry['selection']}; outer polygons from safe LP bounds, refined {entry['refine']} rounds "
             f"({entry['lp_solves']} LP solves, {entry['seconds']:.2f} s). Gap: the largest distance of the outer "
             "polygon outside the inner one (the LP points), relative to the box.", "",
             "| pair | directions | vertices | polygon / box area | gap | coupling score | truth inside |",
             "|---|---:|---:|---:|---:|---:|---|"]
    for pj in entry["pairs"]:
        xs, ys = np.asarray(pj["vertices"]).T
        box_area = np.ptp(xs) * np.ptp(ys)
        key = ":".join(pj["parameters"])
        lines.append(f"| {pj['parameters'][0]} vs {pj['parameters'][1]} | {pj['directions']} | {len(pj['vertices'])} "
                     f"| {pj['area'] / box_area:.3f} | {pj['gap']:.1e} | {entry['scores'].get(key, float('nan')):.3f} "
                     f"| {pj.get('truth_inside')} |")
    lines += ["", f"Drawn beside it: {', '.join(entry['methods_drawn'])}"
              + (f"; not drawn: {entry['methods_skipped']}" if entry["methods_skipped"] else "") + ".", ""]
    return "\n".join(lines)


def prediction_lines(entry: dict) -> str:
    """The report's section on the held-out prediction."""
    w = entry["envelope_width_median"]
    return "\n".join([
        "## Guaranteed torque on a held-out motion (`prediction.png`)", "",
        f"Held-out trajectory seed {entry['seed']}, {entry['rows']} of {entry['rows_available']} rows "
        f"({entry['subsample']}). Coverage (measured torque within the envelope widened by the bound): "
        f"polytope {100 * entry['coverage']:.1f} %, box {100 * entry['coverage_box']:.1f} %; held-out oracle "
        f"residual {entry['oracle_residual']:.3f} N m against the bound {entry['bound']:.3f} N m "
        f"(covered: {entry['bound_covers_residual']}). Median envelope width: polytope {w['polytope']:.3f} N m, "
        f"box {w['box']:.3f} N m ({entry['lp_solves']} LP solves, {entry['seconds']:.2f} s).", ""])
