"""``h4bench identify LOG.csv --spec SPEC.toml`` for the H4: the certified box of a user's log.

SPEC.toml holds the ``[error_model]`` table of :class:`~ident.processing.errorspec.ErrorSpec` (sensor facts and
stated motion bounds, with an optional ``[error_model.sources]``) and optionally a ``[certified]`` table with the
weak form's processing (``kernel_steps``, ``kernel_shape``, ``stride``, ``curvature_every``; defaults of
:class:`~ident.robots.h4_certified.Processing`). No bound and no allowance: the interval equation's radii come
from the specification only (:mod:`ident.robots.h4_certified`), and the box is the registry's ``certified``
estimator. Before any of it, the stated motion bounds are checked against what the motor angles prove
(:mod:`ident.processing.motion_check`): a bound the data contradict gives no box (status ``spec_contradicted``).
``result.json`` carries the specification (``error_model``, every assumption stated without proof in its
``sources``), what the equation rests on unproven (``certified.not_proven``), the row radius by its parts
(``certified.row_radius``) and the parameters the box leaves at the prior with the reason
(``certified.prior_diagnosis``).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from h4bench import ident, sim
from h4bench.ident.processing.errorspec import ErrorSpec, ErrorSpecError
from h4bench.ident.processing.motion_check import check_motion_bounds
from h4bench.ident.robots.h4_certified import Processing, certified_equation, stated_assumptions
from h4bench.scenarios import judging
from h4bench.scenarios.certified_verdict import H4_HINTS, contradicted_entry, prior_diagnosis, row_radius_summary
from h4bench.scenarios.rundir import RUNS_DIR, OwnedFolder, check_target, write_json
from h4bench.scenarios.threads import hull_processes

__all__ = ["identify_certified_csv", "read_processing"]

_PROCESSING_KEYS = {"kernel_steps": int, "kernel_shape": str, "stride": int, "curvature_every": int,
                    "encoder_jets": str}


def read_processing(path) -> Processing:
    """The optional ``[certified]`` table of a spec file: ``kernel_steps`` (>= ``MIN_KERNEL_STEPS``; 0 or absent: the
    rows of every kernel of :func:`ident.processing.choice.kernel_family`),
    ``kernel_shape`` (``hann`` or ``triangle``), ``stride`` and ``curvature_every`` (>= 1), ``encoder_jets``
    (``auto``, ``box`` or ``tube``: :data:`ident.robots.h4_certified.ENCODER_JETS`). Errors name ``--spec``,
    the file and the key."""
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
    if table.get("kernel_steps") == 0:  # 0: every kernel of the family, as in the scenarios' [certified] tables
        table = {**table, "kernel_steps": None}
    try:
        return Processing(**table)
    except ValueError as exc:  # Processing's messages start with the key
        raise OptionError(f"--spec {path}: [certified] {exc}") from None


def _read_spec(spec_path) -> ErrorSpec:
    from h4bench.scenarios.identify import OptionError

    if not Path(spec_path).is_file():
        raise OptionError(f"--spec must name an existing TOML file, got {str(spec_path)!r} (not found)")
    try:
        return ErrorSpec.from_toml(spec_path, 4)
    except ErrorSpecError as exc:
        msg = str(exc)
        raise OptionError(msg if msg.startswith("--spec") else f"--spec {spec_path}: {msg}") from None


def identify_certified_csv(path, spec_path, prior=(0.0, 2.0), model=None, out=None) -> dict:
    """The certified box of the H4 log ``path`` (CSV ``t,q1..q4,tau1..tau4``) under the specification file
    ``spec_path``; writes ``result.json`` into ``out`` (default ``runs/identify-<stem>``) and returns it.

    prior : (lower, upper) numbers, (14,) arrays or a Box (lower >= 0: the Oettli-Prager polytope form).
    A log whose sample period differs from the specification's is refused (OptionError naming both periods).
    Reported in the result: stated motion bounds the motor angles prove false (``methods.certified.status``
    ``spec_contradicted``, no box, ``consistent: false``: the command exits 3), data proven inconsistent with the
    specification (``consistent: false``), and the parameters the box leaves at the prior with the radius term
    that is why (``certified.prior_diagnosis``).
    """
    from h4bench.ident.workers import prewarm
    from h4bench.scenarios.identify import OptionError, _prior_box

    prewarm(hull_processes())  # the certified stage's second process starts while the log is read

    error_spec = _read_spec(spec_path)
    processing = read_processing(spec_path)
    box_prior = _prior_box(prior)
    out = check_target(Path(out) if out is not None else RUNS_DIR / f"identify-{Path(path).stem}")
    dataset = sim.Dataset.from_csv(path)
    if abs(dataset.dt - error_spec.sample_period) > 1e-6 * error_spec.sample_period:
        raise OptionError(f"--spec {spec_path}: sample_period {error_spec.sample_period:g} s must be the log's "
                          f"sample period, got {dataset.dt:g} s in {path}")
    check = check_motion_bounds(dataset.q, error_spec)  # motor angles: the H4's stated bounds are the motors'
    result = {
        "scenario": f"identify-{Path(path).stem}", "kind": "identify", "seed": None,
        "model": str(model or sim.DEFAULT_MODEL_PATH), "source": str(path), "samples": len(dataset),
        "parameters": list(ident.PARAMETER_NAMES), "true": None, "bound": None, "oracle_residual": None,
        "prior": {"lower": box_prior.lower.tolist(), "upper": box_prior.upper.tolist()},
        "error_model": {**error_spec.to_dict(), "file": str(spec_path)},
    }
    if check.contradicted:
        result.update(rows=0, consistent=False, methods={"certified": contradicted_entry(check, f"--spec {spec_path}")},
                      certified={"spec_check": check.to_dict()})
        return _write(out, result)
    geometry = sim.H4Geometry.from_model(sim.load_model(model))
    try:
        ceq = certified_equation(geometry, dataset.q, dataset.tau, error_spec, processing,
                                 processes=hull_processes())
    except ValueError as exc:
        raise OptionError(f"CSV {str(path)!r} with --spec {spec_path}: {exc}") from None
    outcomes, _ = judging.run_methods(["certified"], ceq.Wc, ceq.y, ceq.bound, box_prior,
                                      {"regressor_radius": ceq.D, "groups": ceq.joint.astype(np.int64)})
    entry = judging.judge(outcomes, None, None, list(ceq.names))
    o = outcomes["certified"]
    if o.status == "inconsistent":
        entry["certified"].update(error=type(o.error).__name__, min_bound=getattr(o.error, "min_bound", None),
                                  scale_lower=getattr(o.error, "scale_lower", None))
    result["error_model"]["sources"].update(stated_assumptions(ceq.info))
    box = o.box if o.status == "ok" else box_prior
    theta_abs = np.maximum(np.abs(box.lower), np.abs(box.upper))
    at = "the certified box's largest |theta|" if o.status == "ok" else "the prior's largest |theta|"
    certified = {**ceq.info, "spec_check": check.to_dict(),
                 "row_radius": row_radius_summary(ceq.bound, ceq.D, theta_abs, at)}
    if o.status == "ok":
        rel = box.width / (box_prior.upper - box_prior.lower)
        entry["certified"]["relative_width_to_prior"] = rel.tolist()
        certified["prior_diagnosis"] = prior_diagnosis(ceq.names, rel, ceq.terms, theta_abs, ceq.y, H4_HINTS)
    result.update(rows=len(ceq), consistent={"ok": True, "inconsistent": False}.get(o.status), methods=entry,
                  certified=certified, certified_terms_max={k: float(np.max(v)) for k, v in ceq.terms.items()})
    return _write(out, result)


def _write(out, result: dict) -> dict:
    with OwnedFolder(out, what={"scenario": result["scenario"], "kind": "identify"}) as tmp:
        write_json(tmp / "result.json", result)
    return result
