"""The one runner: a scenario spec in, ``runs/<name>/`` out (result.json, report.md, PNG plots, the dataset,
the replay), written atomically: everything goes to a temporary folder that replaces the target at the end,
so an interrupted run never leaves a result that looks complete."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

import ident
import sim
from scenarios import report
from scenarios.experiment import ExperimentRun, estimate_boxes, run_experiment
from scenarios.spec import ScenarioError, load_spec
from sim.dataset import _json_default, atomic_write_bytes

RUNS_DIR = Path("runs")


def write_json(path: Path, obj) -> None:
    atomic_write_bytes(path, json.dumps(obj, indent=2, default=_json_default).encode())


class _AtomicDir:
    """A temporary sibling folder that replaces ``target`` on success and is removed on failure."""

    def __init__(self, target: Path):
        self.target = Path(target)
        self.tmp = self.target.parent / f".{self.target.name}.tmp-{os.getpid()}"

    def __enter__(self) -> Path:
        shutil.rmtree(self.tmp, ignore_errors=True)
        self.tmp.mkdir(parents=True)
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        old = self.target.parent / f".{self.target.name}.old-{os.getpid()}"
        if self.target.exists():
            os.replace(self.target, old)
        os.replace(self.tmp, self.target)
        shutil.rmtree(old, ignore_errors=True)


def _noop(stage: str, done: int = 0, total: int = 0) -> None:
    pass


def run_scenario(name: str | Path, seed: int | None = None, model: str | Path | None = None,
                 out: str | Path | None = None, quick: bool = False, progress=None,
                 scheduler: str | None = None, workers: int | None = None, only: int | None = None) -> dict:
    """Run scenario ``name`` (or a TOML path) and write its folder; returns the result dict.

    progress : optional callable(stage, done, total) for a progress display; scheduler, workers : where a
    campaign runs (a Dask scheduler address, or the size of the local process pool); only : for a campaign,
    re-run that one run index alone into ``<out>/run-<index>/`` with its dataset, report and replay.
    """
    spec = load_spec(name, quick=quick)
    if scheduler:
        spec["campaign"]["scheduler"] = scheduler
    if workers is not None:
        spec["campaign"]["workers"] = int(workers)
    if model is not None:
        if not Path(model).is_file():
            raise sim.ModelError(f"model path must be an existing MJCF file, got {str(model)!r} (not found)")
        spec["model"] = str(model)
    seed = spec["seed"] if seed is None else int(seed)
    out = Path(out) if out is not None else RUNS_DIR / spec["name"]
    progress = progress or _noop
    started = time.perf_counter()
    if spec["kind"] == "enclosure":
        from scenarios.campaign import replay_one, run_campaign

        if only is None:
            return run_campaign(spec, seed, out, progress)
        if not 0 <= only < spec["campaign"]["runs"]:
            raise ScenarioError(f"only must be a run index in [0, {spec['campaign']['runs']}), got {only}")
        with _AtomicDir(out / f"run-{only:04d}") as tmp:
            result = replay_one(spec, only, seed, tmp, progress)
            write_json(tmp / "result.json", result)
        return result
    if only is not None:
        raise ScenarioError(f"only applies to campaigns (kind 'enclosure'), not to kind {spec['kind']!r}")
    with _AtomicDir(out) as tmp:
        kind_runner = {"paper": _paper, "prior_bound": _prior_bound, "structure": _structure}.get(spec["kind"])
        if kind_runner is None:
            from scenarios import beyond

            kind_runner = beyond.RUNNERS[spec["kind"]]
        result = kind_runner(spec, seed, tmp, progress)
        result["wall_seconds"] = time.perf_counter() - started
        write_json(tmp / "result.json", result)
    return result


def _sim_progress(progress):
    return lambda k, n: progress("simulate", k, n)


def _save_run_files(run: ExperimentRun, out: Path, progress) -> None:
    run.dataset.save(out / "dataset")
    run.truth.save(out / "truth")
    if hasattr(run.reference, "save"):
        run.reference.save(out / "trajectory.npz")
    if run.spec["replay"]["enabled"]:
        progress("replay", 0, 1)
        try:
            from scenarios.replay import write_replay
        except ImportError:  # replay not available in this build
            return
        t0 = time.perf_counter()
        write_replay(run, out / "replay.rrd", history_points=run.spec["replay"]["history_points"])
        run.timings["replay"] = time.perf_counter() - t0


def _paper(spec: dict, seed: int, out: Path, progress) -> dict:
    progress("experiment", 0, 1)
    run = run_experiment(spec, seed, progress=_sim_progress(progress))
    _save_run_files(run, out, progress)
    result = run.result()
    report.plot_boxes(result, out / "boxes.png")
    report.write_paper_report(result, out, extra="## Controller design\n\n```\n" + run.controller_report + "\n```\n")
    return result


def _sweep_bounds(run: ExperimentRun) -> np.ndarray:
    """Processed-row bounds from below the min consistent bound to several times the injected noise level,
    with the points that matter (min consistent bound, oracle residual, assumed bound) included."""
    eq = run.equation
    m_star = run.min_consistent_bound
    l1 = eq.info.get("l1_norm", 1.0)
    noise_level = max(run.spec["noise"]["bound"] * l1, m_star)
    factors = np.asarray(run.spec["sweep"]["factors"], dtype=float)
    grid = np.concatenate([factors * noise_level, [m_star * 0.9, m_star * 1.0001, float(np.abs(run.residual).max()),
                                                   float(eq.bound.max())]])
    return np.unique(np.round(grid[grid > 0], 9))


def _prior_bound(spec: dict, seed: int, out: Path, progress) -> dict:
    progress("experiment", 0, 1)
    run = run_experiment(spec, seed, estimate=False, progress=_sim_progress(progress))
    estimate_boxes(run)  # at the assumed bound: the result's methods
    eq, prior = run.equation, run.prior
    sweep = []
    bounds = _sweep_bounds(run)
    for k, b in enumerate(bounds):
        progress("sweep", k, len(bounds))
        entry = {"bound": float(b), "consistent": bool(b >= run.min_consistent_bound), "methods": {}}
        for method in spec["estimators"]["methods"]:
            try:
                box = ident.estimate(eq.W, eq.y, b, prior, method=method)
                entry["methods"][method] = {"lower": box.lower.tolist(), "upper": box.upper.tolist(),
                                            "enclosed": bool(box.contains(run.theta_true).all())}
            except ident.InconsistentDataError as exc:
                entry["methods"][method] = {"empty": True, "min_bound": exc.min_bound}
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
    _save_run_files(run, out, progress)
    plot_prior_bound(result, out / "widths_vs_bound.png")
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


def plot_prior_bound(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, true = result["parameters"], np.asarray(result["true"])
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), sharex=True)
    for ax, method in zip(axes, ("hull", "cgsp")):
        xs, ws = [], []
        for e in result["sweep"]:
            m = e["methods"].get(method)
            if m and not m.get("empty"):
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


def _structure(spec: dict, seed: int, out: Path, progress) -> dict:
    """The robot breaks the paper's hypotheses (unbalanced arms, heavy forearm rods): the bound the paper's
    structure then needs, and what the extended structure recovers."""
    offsets = np.full(4, spec["structure"]["arm_com_offset"])
    forearm_mass = spec["structure"]["forearm_mass"]
    model, theta22 = sim.broken_hypotheses_model(offsets, forearm_mass, spec["model"] or None)
    theta14 = theta22[:14]
    progress("experiment (paper structure)", 0, 2)
    paper_spec = {**spec, "structure": {**spec["structure"], "regressor": "paper"}}
    run14 = run_experiment(paper_spec, seed, model=model, theta_true=theta14, progress=_sim_progress(progress))
    progress("experiment (extended structure)", 1, 2)
    ext_spec = {**spec, "structure": {**spec["structure"], "regressor": "extended"}}
    run22 = run_experiment(ext_spec, seed, model=model, theta_true=theta22, reference=run14.reference)
    r14, r22 = run14.result(), run22.result()
    result = dict(r22)
    result["arm_com_offset"] = offsets.tolist()
    result["forearm_mass"] = forearm_mass
    result["paper_structure"] = r14
    _save_run_files(run22, out, progress)
    report.plot_boxes(r22, out / "boxes_extended.png", title="extended structure: boxes against the truth")
    report.plot_boxes(r14, out / "boxes_paper.png", title="paper structure on unbalanced arms")
    text = "\n".join([
        f"# Scenario `{result['scenario']}`: arms unbalanced by {offsets[0]} m, forearms as {forearm_mass} kg rods",
        "", "True values of the extended structure: the paper's 14 hold the rods' lumped halves; MXa = "
        f"{theta22[14]:.4g} kg m (arm offset and the rod half at the arm tip), mf = {forearm_mass} kg.", "",
        "## The paper's 14-parameter structure", "", *report.summary_lines(r14),
        f"- the bound this structure needs for the guarantee: {r14['oracle_residual']:.4g} N m on processed rows "
        f"(assumed {r14['bound_processed']:.4g})", "", report.table1(r14), "",
        "## The extended structure (arm gravity MXa, forearm rods mf)", "", *report.summary_lines(r22), "",
        report.table1(r22),
    ])
    atomic_write_bytes(out / "report.md", text.encode())
    return result
