"""Where a campaign's time goes: per-stage seconds of each run, and the campaign's overhead outside its runs.

A run's ``timings`` (written by :func:`scenarios.experiment.run_experiment` and the campaign engine) map a
measured section to wall seconds; :data:`STAGES` groups them:

- ``design``: the run's model (a randomised variant, ``model``), the trajectory (a design-cache lookup,
  ``trajectory``; ``trajectory_source`` says ``memory``, ``disk`` or ``computed``) and the controller with its
  feed-forward (``controller``);
- ``simulation``, ``processing``: the closed loop; the processed equation;
- ``methods``: every estimator and the minimum consistent bound (``timings["methods"]``, one entry per name);
- ``judging``: the per-method verdicts against the truth and the hull (``judging``);
- ``analysis``: the error budget (``budget``) and the width analysis (``methods["width_analysis"]`` when run);
- ``certified``: with a derived error model, the certified equation, its box and its certificate (``certified``);
- ``io``: writing the run's file (``io``, measured by the campaign engine in the parent process).

``run`` is the whole job as the worker saw it (:class:`TimedJob`); what the stages do not cover is ``other``
(building the result dict, the worker's first imports, ...). The campaign's overhead is its wall time minus the
runs' time divided by the workers: pool start-up, provenance, resumed runs' loading, the idle tail of the pool,
summaries, plots and the report (everything but the final ``result.json`` write, which holds the figures). The
parent imports only what the kind's set-up and reports need (the code hash reads the source files without
importing them): a worker imports the rest of what its runs use on its first run, inside that run's time.
"""

from __future__ import annotations

import statistics
import time

__all__ = ["STAGES", "TimedJob", "campaign_timings", "run_stages", "timing_lines"]

STAGES = ("design", "simulation", "processing", "methods", "judging", "analysis", "certified", "io", "other")
_DESIGN = ("model", "trajectory", "controller")
_ANALYSIS_METHODS = ("width_analysis",)


class TimedJob:
    """A campaign job ``job(spec, index, seed) -> dict`` that also records its own wall seconds in
    ``result["timings"]["run"]`` (picklable when ``job`` is: a top-level function)."""

    def __init__(self, job):
        self.job = job

    def __call__(self, spec: dict, index: int, seed: int) -> dict:
        started = time.perf_counter()
        result = self.job(spec, index, seed)
        if isinstance(result, dict):
            result.setdefault("timings", {})["run"] = time.perf_counter() - started
        return result


def run_stages(timings: dict) -> dict:
    """The :data:`STAGES` seconds of one run's ``timings`` (missing sections count 0; ``other`` = ``run`` minus
    the rest, never below 0, and 0 without ``run``)."""
    methods = timings.get("methods") or {}
    out = {
        "design": sum(float(timings.get(k, 0.0)) for k in _DESIGN),
        "simulation": float(timings.get("simulation", 0.0)),
        "processing": float(timings.get("processing", 0.0)),
        "methods": sum(float(v) for k, v in methods.items() if k not in _ANALYSIS_METHODS),
        "judging": float(timings.get("judging", 0.0)),
        "analysis": float(timings.get("budget", 0.0)) + sum(float(methods.get(k, 0.0)) for k in _ANALYSIS_METHODS),
        "certified": float(timings.get("certified", 0.0)),
        "io": float(timings.get("io", 0.0)),
    }
    run = timings.get("run")
    out["other"] = max(0.0, float(run) - sum(out.values())) if run is not None else 0.0
    return out


def _stats(values: list[float]) -> dict:
    return {"total": float(sum(values)), "median": float(statistics.median(values)) if values else 0.0}


def campaign_timings(runs: list[dict], computed: list[int], workers: int, started: float, sections: dict) -> dict:
    """The campaign's ``timings`` (docs/results.md): per-stage and per-method total and median seconds over the
    runs computed now (``computed``: their indices in ``runs``), the runs' summed time, and the overhead.

    started : ``time.time()`` when the campaign began; sections : the engine's own measured seconds (e.g.
    ``setup``, ``pool``, ``report``); workers : the local pool's size (0 on a Dask cluster, whose size the engine
    does not know: no overhead is then computed)."""
    wall = time.time() - started
    per_run = [(runs[i].get("timings") or {}) for i in computed]
    stages = {s: _stats([run_stages(t)[s] for t in per_run]) for s in STAGES}
    names = sorted({k for t in per_run for k in (t.get("methods") or {})})
    methods = {k: _stats([float((t.get("methods") or {}).get(k, 0.0)) for t in per_run]) for k in names}
    run_seconds = [float(t["run"]) for t in per_run if t.get("run") is not None]
    busy = sum(run_seconds) / workers if workers >= 1 else None
    sources = {}
    for t in per_run:
        src = t.get("trajectory_source")
        if src:
            sources[src] = sources.get(src, 0) + 1
    return {
        "wall": wall, "runs_computed": len(computed), "workers": workers,
        "run_seconds": _stats(run_seconds), "stages": stages, "methods": methods,
        "trajectory_sources": sources, "sections": {k: float(v) for k, v in sections.items()},
        "overhead": wall - busy if run_seconds and busy is not None else None,
        "overhead_share": (wall - busy) / wall if run_seconds and busy is not None and wall > 0 else None,
    }


def timing_lines(t: dict | None) -> list[str]:
    """The report's section on where the campaign's time went (none without computed runs)."""
    if not t or not t.get("runs_computed"):
        return []
    n = t["runs_computed"]
    total = sum(v["total"] for v in t["stages"].values()) or 1.0
    lines = ["", "## Where the time went", "",
             f"{n} run(s) computed on {t['workers']} worker(s) in {t['wall']:.4g} s of wall time; the runs took "
             f"{t['run_seconds']['total']:.4g} s together (median {t['run_seconds']['median']:.3g} s per run); "
             + (f"overhead outside the runs (wall - run time / workers): {t['overhead']:.3g} s "
                f"({100 * t['overhead_share']:.1f} % of the wall time)." if t.get("overhead") is not None
                else "overhead not measured (Dask cluster)."), "",
             "| stage | total [s] | median per run [s] | share |", "|---|---:|---:|---:|"]
    lines += [f"| {s} | {v['total']:.4g} | {v['median']:.3g} | {100 * v['total'] / total:.1f} % |"
              for s, v in t["stages"].items()]
    lines += ["", "| method | total [s] | median per run [s] |", "|---|---:|---:|"]
    lines += [f"| {k} | {v['total']:.4g} | {v['median']:.3g} |" for k, v in t["methods"].items()]
    if t.get("trajectory_sources"):
        lines += ["", "Trajectory designs served from: " + ", ".join(
            f"{k} {v}" for k, v in sorted(t["trajectory_sources"].items())) + " (memory: loaded and checked earlier "
            "by the same worker; disk: the design cache; computed: designed now)."]
    if t.get("sections"):
        lines += ["", "Engine sections [s]: " + ", ".join(f"{k} {v:.3g}" for k, v in t["sections"].items()) + "."]
    return lines + [""]
