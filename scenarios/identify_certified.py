"""``h4bench identify LOG.csv --spec SPEC.toml`` for the H4: the certified box of a user's log.

SPEC.toml holds the ``[error_model]`` table of :class:`~ident.processing.errorspec.ErrorSpec` (sensor facts and
stated motion bounds, with an optional ``[error_model.sources]``) and optionally a ``[certified]`` table with the
weak form's processing (``kernel_steps``, ``kernel_shape``, ``stride``, ``curvature_every``; defaults of
:class:`~ident.robots.h4_certified.Processing`). No bound and no allowance: the interval equation's radii come
from the specification only (:mod:`ident.robots.h4_certified`), and the box is the registry's ``certified``
estimator. ``result.json`` carries the specification (``error_model``) and what it rests on unproven
(``certified.not_proven``).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from h4bench import ident, sim
from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.robots.h4_certified import Processing, certified_equation
from h4bench.scenarios import judging
from h4bench.scenarios.rundir import RUNS_DIR, OwnedFolder, check_target, write_json

__all__ = ["identify_certified_csv", "read_processing"]

_PROCESSING_KEYS = {"kernel_steps": int, "kernel_shape": str, "stride": int, "curvature_every": int}


def read_processing(path) -> Processing:
    """The optional ``[certified]`` table of a spec file (errors name the file and the key)."""
    from h4bench.scenarios.identify import OptionError

    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise OptionError(f"--spec {path}: cannot read it as TOML ({exc})") from None
    table = data.get("certified", {})
    if not isinstance(table, dict):
        raise OptionError(f"--spec {path}: [certified] must be a table, got {type(table).__name__}")
    unknown = set(table) - set(_PROCESSING_KEYS)
    if unknown:
        raise OptionError(f"--spec {path}: [certified] has unknown keys {sorted(unknown)}; expected some of "
                          f"{sorted(_PROCESSING_KEYS)}")
    for key, value in table.items():
        kind = _PROCESSING_KEYS[key]
        if isinstance(value, bool) or not isinstance(value, kind):
            raise OptionError(f"--spec {path}: [certified] {key} must be {kind.__name__}, got {value!r}")
    return Processing(**table)


def identify_certified_csv(path, spec_path, prior=(0.0, 2.0), model=None, out=None) -> dict:
    """The certified box of the H4 log ``path`` (CSV ``t,q1..q4,tau1..tau4``) under the specification file
    ``spec_path``; writes ``result.json`` into ``out`` (default ``runs/identify-<stem>``) and returns it.

    prior : (lower, upper) numbers, (14,) arrays or a Box (lower >= 0: the Oettli-Prager polytope form).
    A log whose sample period differs from the specification's, or proven inconsistent with it, is reported:
    the first as a ValueError naming both periods, the second as ``consistent: false`` (status inconsistent).
    """
    from h4bench.scenarios.identify import OptionError, _prior_box

    error_spec = ErrorSpec.from_toml(spec_path, 4)
    processing = read_processing(spec_path)
    box_prior = _prior_box(prior)
    out = check_target(Path(out) if out is not None else RUNS_DIR / f"identify-{Path(path).stem}")
    dataset = sim.Dataset.from_csv(path)
    if abs(dataset.dt - error_spec.sample_period) > 1e-6 * error_spec.sample_period:
        raise OptionError(f"--spec {spec_path}: sample_period {error_spec.sample_period:g} s must be the log's "
                          f"sample period, got {dataset.dt:g} s in {path}")
    geometry = sim.H4Geometry.from_model(sim.load_model(model))
    ceq = certified_equation(geometry, dataset.q, dataset.tau, error_spec, processing)
    outcomes, _ = judging.run_methods(["certified"], ceq.Wc, ceq.y, ceq.bound, box_prior,
                                      {"regressor_radius": ceq.D, "groups": ceq.joint.astype(np.int64)})
    entry = judging.judge(outcomes, None, None, list(ceq.names))
    o = outcomes["certified"]
    if o.status == "inconsistent":
        entry["certified"].update(error=type(o.error).__name__, min_bound=getattr(o.error, "min_bound", None),
                                  scale_lower=getattr(o.error, "scale_lower", None))
    result = {
        "scenario": f"identify-{Path(path).stem}", "kind": "identify", "seed": None,
        "model": str(model or sim.DEFAULT_MODEL_PATH), "source": str(path), "samples": len(dataset),
        "parameters": list(ident.PARAMETER_NAMES), "true": None, "bound": None,
        "bound_processed": float(ceq.bound.max()), "rows": len(ceq), "oracle_residual": None,
        "consistent": {"ok": True, "inconsistent": False}.get(o.status),
        "prior": {"lower": box_prior.lower.tolist(), "upper": box_prior.upper.tolist()},
        "methods": entry, "error_model": error_spec.to_dict(), "certified": ceq.info,
        "certified_terms_max": {k: float(np.max(v)) for k, v in ceq.terms.items()},
    }
    with OwnedFolder(out, what={"scenario": result["scenario"], "kind": "identify"}) as tmp:
        write_json(tmp / "result.json", result)
    return result
