"""Kind ``enclosure_critical``: a campaign whose enclosure check can fail.

Every processed row's bound is a rigorous upper bound, rounded outward, of that row's own oracle residual
``|y_k - W_k theta_true|`` (interval evaluation of ``W_k theta_true``, :func:`ident.estimators.residuals.residual_bound`), so
the true parameters are feasible but touch many strips and the feasible set is tiny: the boxes are orders of
magnitude narrower than in the ordinary campaign, and any unsound rounding in an estimator (a safe bound that is
not safe, a scaling that is not exact, a fallback that shrinks) shows as a miss. The bounds are derived from the
truth on purpose: this is a test of the estimators' rigour, not an identification.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from h4bench.ident.estimators.residuals import residual_bound
from h4bench.scenarios.campaign import run_many
from h4bench.scenarios.campaign_build import campaign_experiment
from h4bench.scenarios.campaign_report import REPORT_IMPORTS, summarise, write_outputs
from h4bench.scenarios.experiment import estimate_boxes
from h4bench.scenarios.spec import ScenarioError

DESCRIPTION = "row bounds = each row's own oracle residual, rounded outward: a tiny feasible set, misses show rigour bugs"
RESUMABLE = True


def critical_job(spec: dict, index: int, base_seed: int) -> dict:
    """One run: the ordinary experiment, then the estimators under the critical row bounds."""
    run_, shape = campaign_experiment(spec, index, base_seed, estimate=False)
    eq = run_.equation
    bound = residual_bound(eq.W, eq.y, run_.theta_true)  # rounded outward
    run_.equation = dataclasses.replace(eq, bound=bound)
    estimate_boxes(run_)
    result = run_.result()
    result.update(index=index, noise_shape=shape, critical_bound_median=float(np.median(bound)),
                  critical_bound_max=float(bound.max()))
    return result


def run(spec: dict, seed: int, out: Path, progress, only: int | None = None, fresh: bool = False) -> dict:
    if only is not None:
        raise ScenarioError("only is not available for enclosure-critical (rerun the ordinary campaign's index)")
    runs, info = run_many(spec, seed, out, critical_job, progress, fresh=fresh,
                           report_imports=REPORT_IMPORTS)
    result = summarise(spec, seed, runs, info)
    result["bound"] = "critical (per row: its own oracle residual, rounded outward)"
    result["critical_bound_median"] = float(np.median([r["critical_bound_median"] for r in runs]))
    facts = [f"- runs: {result['runs']}; every row's bound is its own oracle residual rounded outward (median "
             f"{result['critical_bound_median']:.3g} N m); the truth is feasible in "
             f"{result['runs_bound_covers_residual']} of {result['runs']} runs (must be all)"]
    write_outputs(result, runs, out, "critical bounds, a test of rigour", facts, _method_line)
    return result


def _method_line(name: str, m: dict) -> str:
    return (f"{m['misses']} miss(es) {m['miss_seeds']} (must be none: a miss is a rigour bug); failed runs "
            f"{m['failed_runs']}; median {m['seconds']:.3g} s")
