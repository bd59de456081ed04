"""``h4bench identify``: the estimators on a user's own log (CSV), with the same result.json as a scenario."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import ident
import sim
from ident.filtering import ProcessingSettings
from ident.processing import build_equation
from scenarios.rundir import RUNS_DIR, OwnedFolder, check_target, write_json
from scenarios.spec import DEFAULTS

METHODS = ("hull", "cgsp", "wls")


def identify_csv(path, bound: float, method: str = "hull", prior=(0.0, 2.0), model=None, out=None) -> dict:
    """Identify the 14 parameters from a CSV log under the raw-row bound ``bound`` [N m]."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not (np.isfinite(bound) and bound > 0):
        raise ValueError(f"bound must be a finite number > 0 [N m], got {bound!r}")
    lo, hi = prior
    if not lo < hi:
        raise ValueError(f"prior lower must be < upper, got ({lo}, {hi})")
    out = check_target(Path(out) if out is not None else RUNS_DIR / f"identify-{Path(path).stem}")
    dataset = sim.Dataset.from_csv(path)
    geometry = sim.H4Geometry.from_model(sim.load_model(model))
    settings = ProcessingSettings(dt=dataset.dt, **DEFAULTS["processing"])
    box_prior = ident.Box(np.full(14, lo), np.full(14, hi))
    eq = build_equation(geometry, dataset, bound, settings, prior=box_prior)
    result = {
        "scenario": f"identify-{Path(path).stem}", "kind": "identify", "seed": None, "model": str(model or sim.DEFAULT_MODEL_PATH),
        "source": str(path), "parameters": list(ident.PARAMETER_NAMES), "true": None, "bound": bound,
        "bound_processed": float(eq.bound.max()), "rows": len(eq), "oracle_residual": None,
        "prior": {"lower": box_prior.lower.tolist(), "upper": box_prior.upper.tolist()}, "methods": {},
    }
    result["min_consistent_bound"] = float(ident.min_consistent_bound(eq.W, eq.y, box_prior))
    if method == "wls":
        w = ident.wls(eq.W, eq.y, joints=4, names=eq.names, joint_of_row=eq.joint)
        result["wls"] = {"theta": np.asarray(w.theta).tolist(), "std": np.asarray(w.std).tolist(),
                         "rel_std_percent": np.asarray(w.rel_std_percent).tolist()}
    else:
        t0 = time.perf_counter()
        try:
            box = ident.estimate(eq.W, eq.y, eq.bound, box_prior, method=method)
            result["methods"][method] = {"status": "ok", "lower": box.lower.tolist(), "upper": box.upper.tolist(),
                                         "enclosed": None, "width": box.width.tolist(),
                                         "seconds": time.perf_counter() - t0}
        except ident.InconsistentDataError as exc:
            result["methods"][method] = {"status": "failed", "message": str(exc), "seconds": time.perf_counter() - t0}
    with OwnedFolder(out, what={"scenario": result["scenario"], "kind": "identify"}) as tmp:
        write_json(tmp / "result.json", result)
    return result
