"""Monte Carlo campaigns: many experiments over seeds, noise shapes, trajectories and randomised true
parameters, on a local process pool or a Dask cluster (``scheduler`` address), resumable.

Each finished run is written at once to ``<out>/runs/<index>.json`` (atomically); a restarted campaign skips
the indices already there, so nothing finished is redone or lost. ``result.json`` and the report are written
only when every run is in, and removed at the start, so a partial campaign never looks complete.
"""

from __future__ import annotations

import concurrent.futures
import copy
import json
import os
from pathlib import Path

import numpy as np

import sim
from scenarios.spec import ScenarioError

METHODS_SUMMARY_KEYS = ("all_enclosed", "width", "seconds", "status")


def campaign_experiment(spec: dict, index: int, base_seed: int):
    """The experiment of run ``index`` of a campaign: seed ``base_seed + index``, the index's noise shape,
    true parameters randomised with that seed. Returns (ExperimentRun, noise shape)."""
    from scenarios.experiment import run_experiment

    camp = spec["campaign"]
    seed = base_seed + index
    spec_i = copy.deepcopy(spec)
    shapes = camp["noise_shapes"]
    spec_i["noise"]["shape"] = shapes[index % len(shapes)]
    path = spec["model"] or None
    model = sim.randomised_model(seed, camp["parameter_spread"], path) if camp["parameter_spread"] > 0 \
        else sim.load_model(path)
    return run_experiment(spec_i, seed, model=model, model_path=path), spec_i["noise"]["shape"]


def campaign_job(spec: dict, index: int, base_seed: int) -> dict:
    """One run of a campaign (a top-level function: picklable for process pools and Dask)."""
    run, shape = campaign_experiment(spec, index, base_seed)
    result = run.result()
    result["index"] = index
    result["noise_shape"] = shape
    return result


def replay_one(spec: dict, index: int, base_seed: int, out: Path, progress) -> dict:
    """Re-run run ``index`` of a campaign alone and write a full run folder (dataset, truth, report, replay),
    e.g. to inspect a miss; ``out`` is an atomic temporary folder."""
    from scenarios import report
    from scenarios.runner import _save_run_files

    progress(f"run {index}", 0, 1)
    spec = copy.deepcopy(spec)
    spec["replay"]["enabled"] = True
    run, shape = campaign_experiment(spec, index, base_seed)
    _save_run_files(run, out, progress)
    result = run.result()
    result["index"] = index
    result["noise_shape"] = shape
    report.plot_boxes(result, out / "boxes.png")
    report.write_paper_report(result, out, extra=f"Run {index} of campaign `{spec['name']}` (noise {shape}).")
    return result


def _run_path(out: Path, index: int) -> Path:
    return out / "runs" / f"{index:04d}.json"


def _executor(camp: dict):
    if camp["scheduler"]:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - a dependency
            raise ScenarioError("scheduler needs dask.distributed (pip install distributed)") from exc
        try:
            client = Client(camp["scheduler"], timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise ScenarioError(f"the Dask scheduler at {camp['scheduler']!r} does not answer: {exc}") from exc
        return client.get_executor(), client
    workers = camp["workers"] or max(1, (os.cpu_count() or 1))
    return concurrent.futures.ProcessPoolExecutor(max_workers=workers), None


def run_campaign(spec: dict, seed: int, out: Path, progress) -> dict:
    from scenarios.runner import write_json

    camp = spec["campaign"]
    n = int(camp["runs"])
    if n < 1:
        raise ScenarioError(f"campaign.runs must be >= 1, got {n}")
    out = Path(out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    for stale in ("result.json", "report.md"):
        (out / stale).unlink(missing_ok=True)
    todo = [i for i in range(n) if not _run_path(out, i).is_file()]
    progress("campaign", n - len(todo), n)
    if todo:
        executor, client = _executor(camp)
        try:
            with executor:
                futures = {executor.submit(campaign_job, spec, i, seed): i for i in todo}
                for k, fut in enumerate(concurrent.futures.as_completed(futures)):
                    i = futures[fut]
                    write_json(_run_path(out, i), fut.result())
                    progress("campaign", n - len(todo) + k + 1, n)
        finally:
            if client is not None:
                client.close()
    runs = [json.loads(_run_path(out, i).read_text()) for i in range(n)]
    result = summarise(spec, seed, runs)
    write_report(result, runs, out)
    write_json(out / "result.json", result)
    return result


def summarise(spec: dict, seed: int, runs: list[dict]) -> dict:
    first = runs[0]
    methods = {}
    for name in first["methods"]:
        ok = [r for r in runs if r["methods"][name].get("status") == "ok"]
        enclosed = np.array([r["methods"][name]["enclosed"] for r in ok]) if ok else np.zeros((0, len(first["true"])))
        misses = [r["seed"] for r in ok if not r["methods"][name]["all_enclosed"]]
        misses_covered = [r["seed"] for r in ok if not r["methods"][name]["all_enclosed"] and r["bound_covers_residual"]]
        rel_w = np.array([np.asarray(r["methods"][name]["width"]) / np.asarray(r["true"]) for r in ok])
        methods[name] = {
            "status": "ok",
            "lower": first["methods"][name].get("lower"),
            "upper": first["methods"][name].get("upper"),
            "enclosed": enclosed.all(axis=0).tolist() if len(ok) else [],
            "all_enclosed": bool(len(ok) == len(runs) and enclosed.all()),
            "misses": len(misses),
            "miss_seeds": misses,
            "misses_with_bound_covering_residual": misses_covered,
            "failed_runs": [r["seed"] for r in runs if r["methods"][name].get("status") != "ok"],
            "relative_width_median": np.median(rel_w, axis=0).tolist() if len(ok) else [],
            "relative_width_p90": np.percentile(rel_w, 90, axis=0).tolist() if len(ok) else [],
            "seconds": float(np.median([r["methods"][name]["seconds"] for r in runs])),
        }
    return {
        "scenario": spec["name"], "kind": "enclosure", "seed": seed, "quick": spec.get("quick_applied", False),
        "model": first["model"], "parameters": first["parameters"], "true": first["true"],
        "bound": first["bound"], "runs": len(runs),
        "min_consistent_bound": float(max(r["min_consistent_bound"] for r in runs)),
        "oracle_residual": float(max(r["oracle_residual"] for r in runs)),
        "runs_bound_covers_residual": int(sum(r["bound_covers_residual"] for r in runs)),
        "noise_shapes": spec["campaign"]["noise_shapes"], "parameter_spread": spec["campaign"]["parameter_spread"],
        "methods": methods,
    }


def write_report(result: dict, runs: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim.dataset import atomic_write_bytes

    names = result["parameters"]
    fig, axes = plt.subplots(1, len(result["methods"]), figsize=(7 * len(result["methods"]), 5), squeeze=False)
    for ax, (name, m) in zip(axes[0], result["methods"].items()):
        rel = [np.asarray(r["methods"][name]["width"]) / np.asarray(r["true"]) for r in runs
               if r["methods"][name].get("status") == "ok"]
        if rel:
            ax.boxplot(np.array(rel), tick_labels=names)
        ax.set_yscale("log")
        ax.set_title(f"{name}: relative widths over {len(rel)} runs, {m['misses']} miss(es)")
        ax.tick_params(axis="x", rotation=60)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "widths.png", dpi=110)
    plt.close(fig)
    lines = [f"# Scenario `{result['scenario']}`: is the truth always enclosed?", "",
             f"- runs: {result['runs']} (noise shapes {result['noise_shapes']}, true parameters randomised by "
             f"+-{100 * result['parameter_spread']:.0f} %)",
             f"- bound covers the oracle residual in {result['runs_bound_covers_residual']} of {result['runs']} runs "
             f"(max oracle residual {result['oracle_residual']:.4g} N m)"]
    for name, m in result["methods"].items():
        lines.append(f"- {name}: {m['misses']} miss(es) {m['miss_seeds']}; misses where the bound covered the "
                     f"residual (must be none): {m['misses_with_bound_covering_residual']}; median {m['seconds']:.3g} s")
    lines += ["", f"Inspect one run (a miss, say) with its dataset and Rerun replay: `h4bench run {result['scenario']} "
              f"--seed {result['seed']} --only INDEX` (run INDEX has seed {result['seed']} + INDEX).", "",
              "Plot: `widths.png`."]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())
