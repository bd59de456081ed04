"""Kind ``prior_bound``: the assumed bound swept from below the minimum consistent bound to several times the
noise level; box widths against the bound (the paper's future work (i))."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from h4bench.scenarios import judging, report
from h4bench.scenarios.experiment import ExperimentRun, estimate_boxes, run_experiment
from h4bench.scenarios.rundir import save_run_files, sim_progress
from h4bench.sim.dataset import atomic_write_bytes

DESCRIPTION = "the assumed bound against the posterior widths (hull and cgsp)"


def _sweep_bounds(run: ExperimentRun) -> np.ndarray:
    """Processed-row bounds from below the min consistent bound to several times the injected noise level,
    with the points that matter (min consistent bound, oracle residual, assumed bound) included."""
    eq = run.equation
    m_star = run.min_consistent_bound
    l1 = eq.info.get("l1_norm", 1.0)
    noise_level = max(run.noise_bound * l1, m_star)
    factors = np.asarray(run.spec["sweep"]["factors"], dtype=float)
    grid = np.concatenate([factors * noise_level, [m_star * 0.9, m_star * 1.0001, float(np.abs(run.residual).max()),
                                                   float(eq.bound.max())]])
    return np.unique(np.round(grid[grid > 0], 9))


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    progress("experiment", 0, 1)
    run = run_experiment(spec, seed, estimate=False, progress=sim_progress(progress))
    estimate_boxes(run)  # at the assumed bound: the result's methods
    eq, prior = run.equation, run.prior
    sweep = []
    bounds = _sweep_bounds(run)
    for k, b in enumerate(bounds):
        progress("sweep", k, len(bounds))
        entry = {"bound": float(b), "consistent": bool(b >= run.min_consistent_bound), "methods": {}}
        for method in spec["estimators"]["methods"]:  # a method that fails costs only its own entry
            o = judging.run_method(method, eq.W, eq.y, b, prior, {"groups": np.asarray(eq.joint, dtype=np.int64)})
            if o.status == "ok":
                entry["methods"][o.name] = {"lower": o.box.lower.tolist(), "upper": o.box.upper.tolist(),
                                            "enclosed": bool(o.box.contains(run.theta_true).all())}
            elif o.status == "inconsistent":
                entry["methods"][o.name] = {"empty": True, "min_bound": getattr(o.error, "min_bound", None)}
            else:
                entry["methods"][o.name] = {"failed": True, "message": o.message}
        sweep.append(entry)
    result = run.result()
    enclosing = [e["bound"] for e in sweep if e["methods"].get("hull", {}).get("enclosed")]
    result["sweep"] = sweep
    result["points"] = {
        "min_consistent_bound": run.min_consistent_bound,
        "oracle_residual": result["oracle_residual"],
        "assumed_bound_processed": result["bound_processed"],
        "hull_encloses_from": min(enclosing) if enclosing else None,
        "guaranteed_from": result["oracle_residual"],
    }
    save_run_files(run, out, progress)
    plot_widths_vs_bound(result, out / "widths_vs_bound.png")
    report.plot_boxes(result, out / "boxes.png")
    lines = report.summary_lines(result) + [
        f"- data consistent from b = {run.min_consistent_bound:.4g} N m (min consistent bound)",
        f"- truth guaranteed inside the feasible set from b = {result['oracle_residual']:.4g} N m (oracle residual)",
        f"- hull observed to enclose the truth from b = {result['points']['hull_encloses_from']} N m on the grid",
    ]
    text = "\n".join([f"# Scenario `{result['scenario']}`: the assumed bound against the posterior widths", "",
                      *lines, "", "Plot: `widths_vs_bound.png`.", "", "## Boxes at the assumed bound", "",
                      report.table1(result)])
    atomic_write_bytes(out / "report.md", text.encode())
    return result


def plot_widths_vs_bound(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, true = result["parameters"], np.asarray(result["true"])
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), sharex=True)
    for ax, method in zip(axes, ("hull", "cgsp")):
        xs, ws = [], []
        for e in result["sweep"]:
            m = e["methods"].get(method)
            if m and not m.get("empty") and not m.get("failed"):
                xs.append(e["bound"])
                ws.append((np.asarray(m["upper"]) - np.asarray(m["lower"])) / true)
        if xs:
            ws = np.array(ws)
            colours = plt.get_cmap("tab20").colors
            for j, name in enumerate(names):
                ax.plot(xs, ws[:, j], marker=".", lw=1, label=name, color=colours[j % len(colours)],
                        ls="-" if j < 10 else "--")
        pts = result["points"]
        ax.axvline(pts["min_consistent_bound"], color="k", ls=":", label="min consistent bound")
        ax.axvline(pts["oracle_residual"], color="crimson", ls="--", label="oracle residual")
        ax.axvline(pts["assumed_bound_processed"], color="green", ls="-.", label="assumed bound")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("bound on processed rows [N m]")
        ax.set_ylabel("box width / true value")
        ax.set_title(f"{method}: width against the assumed bound")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, ncol=2, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
