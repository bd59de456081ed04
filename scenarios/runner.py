"""The one runner: a scenario spec in, a run folder out (``runs/<name>/`` by default: result.json, report.md, PNG
plots, the dataset, the replay), with progress. The kind of the spec (:mod:`scenarios.registry`) does the work;
the runner owns the folder: written atomically (see :mod:`scenarios.rundir`), never over a user's files."""

from __future__ import annotations

import time
from pathlib import Path

from h4bench.scenarios import registry
from h4bench.scenarios.rundir import RUNS_DIR, OwnedFolder, check_target, write_json
from h4bench.scenarios.spec import ScenarioError


def _noop(stage: str, done: int = 0, total: int = 0) -> None:
    pass


def check_model(path) -> None:
    """Load the H4 model at ``path`` once, before any run (a campaign's workers would each fail on it):
    :class:`sim.ModelError` (a ValueError) names the file and what is wrong."""
    from h4bench import sim

    model = sim.load_model(path)
    sim.H4Geometry.from_model(model)
    sim.true_parameters(model)


def run_scenario(name: str | Path, seed: int | None = None, model: str | Path | None = None,
                 out: str | Path | None = None, quick: bool = False, progress=None,
                 scheduler: str | None = None, workers: int | None = None, only: int | None = None,
                 fresh: bool = False, methods: str | list | None = None, runs: int | None = None,
                 method_timeout: float | None = None, error_model: str = "tuned") -> dict:
    """Run scenario ``name`` (or a TOML path) and write its folder; returns the result dict.

    progress : optional callable(stage, done, total) for a progress display; scheduler, workers : where a
    campaign runs (a Dask scheduler address, or the size of the local process pool); only : for a campaign,
    re-run that one run index alone into ``<out>/run-<index>/`` with its dataset, report and replay; fresh : for
    a campaign, recompute every run instead of resuming; methods : the estimators (``"a,b,c"``, names or
    ``module:attribute``, ``all``: :func:`scenarios.judging.parse_methods`, or a list of those) replacing the
    spec's ``[estimators] methods`` (part of a campaign's provenance: a resumed campaign with other methods
    recomputes its runs); runs : a campaign's number of runs (``campaign.runs``); method_timeout : seconds each
    estimator may run (``[estimators] method_timeout``; None: no limit); error_model : ``"tuned"``
    (the spec's bound) or ``"derived"`` (the enclosure campaign adds the ``certified`` box and its certificate,
    :mod:`scenarios.certificate`; the ``certified`` kind always derives it; ``tx40`` adds the certified box of
    the real log, :mod:`scenarios.tx40_certified`).
    """
    spec = registry.load_spec(name, quick=quick)
    if error_model not in ("tuned", "derived"):
        raise ScenarioError(f"error_model must be 'tuned' or 'derived', got {error_model!r}")
    if error_model == "derived":
        if spec["kind"] not in ("enclosure", "certified", "tx40"):
            raise ScenarioError(f"--error-model derived is available for the kinds enclosure, certified and tx40, "
                                f"got kind {spec['kind']!r}")
        spec["certified"]["enabled"] = True
    if methods is not None:
        from h4bench.scenarios.judging import parse_methods

        try:
            spec["estimators"]["methods"] = parse_methods(methods if isinstance(methods, str) else ",".join(methods))
        except (TypeError, ValueError) as exc:
            raise ScenarioError(f"--methods: {exc}") from None
    if method_timeout is not None:
        if isinstance(method_timeout, bool) or not isinstance(method_timeout, (int, float)) or not method_timeout > 0:
            raise ScenarioError(f"method_timeout must be a number of seconds > 0, got {method_timeout!r}")
        spec["estimators"]["method_timeout"] = float(method_timeout)
    if runs is not None:
        if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
            raise ScenarioError(f"runs must be an integer >= 1, got {runs!r}")
        spec["campaign"]["runs"] = runs
    if scheduler:
        spec["campaign"]["scheduler"] = scheduler
    if workers is not None:
        if isinstance(workers, bool) or int(workers) < 0:
            raise ScenarioError(f"workers must be an integer >= 0 (0: one per core), got {workers!r}")
        spec["campaign"]["workers"] = int(workers)
    if model is not None:
        if not Path(model).is_file():
            raise ScenarioError(f"model path must be an existing MJCF file, got {str(model)!r} (not found)")
        spec["model"] = str(model)
    if seed is not None and (isinstance(seed, bool) or int(seed) < 0):
        raise ScenarioError(f"seed must be an integer >= 0, got {seed!r}")
    seed = spec["seed"] if seed is None else int(seed)
    out = check_target(Path(out) if out is not None else RUNS_DIR / spec["name"])
    progress = progress or _noop
    kind = registry.get(spec["kind"])
    if not getattr(kind, "USES_MODEL", True):
        if model is not None:
            raise ScenarioError(f"--model does not apply to kind {spec['kind']!r} (it does not simulate the H4), got "
                                f"--model {str(model)!r}")
    elif spec["model"]:
        check_model(spec["model"])
    started = time.perf_counter()
    if getattr(kind, "RESUMABLE", False):
        return kind.run(spec, seed, out, progress, only=only, fresh=fresh)
    if only is not None:
        raise ScenarioError(f"only applies to campaigns (kind 'enclosure'), not to kind {spec['kind']!r}")
    with OwnedFolder(out, what={"scenario": spec["name"], "kind": spec["kind"], "seed": seed}) as tmp:
        result = kind.run(spec, seed, tmp, progress)
        result["wall_seconds"] = time.perf_counter() - started
        write_json(tmp / "result.json", result)
    return result
