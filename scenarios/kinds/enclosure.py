"""Kind ``enclosure``: a Monte Carlo campaign over seeds, noise shapes, trajectories and randomised true
parameters: is the truth always enclosed? Runs on a local process pool or a Dask cluster, resumable (see
:mod:`scenarios.campaign`); ``only`` re-runs one index alone with its dataset, report and replay.
"""

from __future__ import annotations

import time
from pathlib import Path

from h4bench.scenarios import report
from h4bench.scenarios.campaign import check_same_campaign, provenance, run_many
from h4bench.scenarios.campaign_build import campaign_experiment
from h4bench.scenarios.campaign_report import REPORT_IMPORTS, summarise, write_outputs
from h4bench.scenarios.rundir import OwnedFolder, save_run_files, write_json
from h4bench.scenarios.spec import ScenarioError

DESCRIPTION = "Monte Carlo over seeds, noise shapes, trajectories and true parameters: is the truth always enclosed?"
RESUMABLE = True


def campaign_job(spec: dict, index: int, base_seed: int) -> dict:
    """One run of the campaign (a top-level function: picklable for process pools and Dask)."""
    run_, shape = campaign_experiment(spec, index, base_seed)
    result = run_.result()
    result["index"] = index
    result["noise_shape"] = shape
    _add_certified(result, run_, spec)
    return result


def _add_certified(result: dict, run_, spec: dict) -> None:
    """With --error-model derived: the certified box and its certificate beside the run's boxes."""
    if spec["certified"]["enabled"]:
        from h4bench.scenarios.certificate import certify

        started = time.perf_counter()
        extra = certify(run_, spec)
        result.setdefault("timings", {})["certified"] = time.perf_counter() - started
        result["methods"]["certified"] = extra.pop("certified_entry")
        result.update(extra)


def replay_one(spec: dict, index: int, base_seed: int, out: Path, progress) -> dict:
    """Re-run run ``index`` alone and write a full run folder (dataset, truth, report, replay) into ``out``."""
    progress(f"run {index}", 0, 1)
    spec = {**spec, "replay": {**spec["replay"], "enabled": True},
            "estimators": {**spec["estimators"], "explain": True}}  # the width analysis, on demand
    run_, shape = campaign_experiment(spec, index, base_seed)
    save_run_files(run_, out, progress)
    result = run_.result()
    result["index"] = index
    result["noise_shape"] = shape
    _add_certified(result, run_, spec)  # the same run as the campaign's: its certified box too
    report.plot_boxes(result, out / "boxes.png")
    report.write_paper_report(result, out, extra=f"Run {index} of campaign `{spec['name']}` (noise {shape}).")
    return result


def run(spec: dict, seed: int, out: Path, progress, only: int | None = None, fresh: bool = False) -> dict:
    """The campaign into ``out`` (resumable), or with ``only`` the one run of that index into
    ``<out>/run-<index>/`` with its dataset, report and replay."""
    if only is not None:
        if not 0 <= only < spec["campaign"]["runs"]:
            raise ScenarioError(f"only must be a run index in [0, {spec['campaign']['runs']}), got {only}")
        check_same_campaign(out, provenance(spec, seed),  # run `only` of this campaign, not of another seed
                            "Give the campaign's own --seed (and options), or another --out")
        with OwnedFolder(Path(out) / f"run-{only:04d}", option="--only") as tmp:
            result = replay_one(spec, only, seed, tmp, progress)
            write_json(tmp / "result.json", result)
        return result
    runs, info = run_many(spec, seed, out, campaign_job, progress, fresh=fresh, report_imports=REPORT_IMPORTS)
    result = summarise(spec, seed, runs, info)
    head: list[str] = []
    if spec["certified"]["enabled"]:
        certs = [r["certificate"] for r in runs]
        failed = [f"run {r['index']} (seed {r['seed']}): {f}" for r in runs for f in r["certificate"].get("failed", [])]
        result["certificate"] = {
            "status": "failed" if failed else "ok", "failed": failed,
            "runs": len(certs), "rows": int(sum(c["rows"] for c in certs)),
            "violations": int(sum(c["violations"] for c in certs)),
            "min_margin": float(min(c["min_margin"] for c in certs)),
            "max_actual_over_radius": float(max(c["checks"]["total"]["max_actual_over_radius"] for c in certs)),
            "width_vs_tuned_geomean": [r.get("width_vs_tuned_geomean") for r in runs]}
        bad = sorted({r["index"] for r in runs if r["certificate"].get("status") == "failed"})
        head = ([f"**Certified box: FAILED** in {len(bad)} of {len(runs)} runs ({bad}): a stated assumption or a "
                 "row check does not hold, so those boxes are not certified:", "", *(f"- {f}" for f in failed[:20]),
                 *([f"- ... {len(failed) - 20} more in result.json `certificate.failed`"] if len(failed) > 20 else []),
                 ""] if failed else
                [f"**Certified box: the certificate holds** in all {len(runs)} runs ({result['certificate']['rows']} "
                 "rows, 0 violations, every stated assumption held by the truth).", ""])
    facts = [f"- runs: {result['runs']} (noise shapes {result['noise_shapes']}, true parameters randomised by "
             f"+-{100 * result['parameter_spread']:.0f} %); reused from an earlier start: {info['reused']}",
             f"- bound covers the oracle residual in {result['runs_bound_covers_residual']} of {result['runs']} runs "
             f"(max oracle residual {result['oracle_residual']:.4g} N m)"]
    tail = [f"Inspect one run (a miss, say) with its dataset and Rerun replay: `h4bench run {result['scenario']} "
            f"--seed {result['seed']} --only INDEX` (run INDEX has seed {result['seed']} + INDEX).", ""]
    write_outputs(result, runs, out, "is the truth always enclosed?", facts, _method_line, tail, head=head)
    return result


def _method_line(name: str, m: dict) -> str:
    return (f"{m['misses']} miss(es) {m['miss_seeds']}; misses where the bound covered the residual (must be none): "
            f"{m['misses_with_bound_covering_residual']}; median {m['seconds']:.3g} s")
