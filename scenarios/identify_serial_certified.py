"""``h4bench identify log.csv --urdf ROBOT.urdf --spec spec.toml``: the certified box of any serial robot's log
(the H4's ``identify --spec`` is :mod:`scenarios.identify_certified`).

The spec file's ``[error_model]`` table (:class:`ident.processing.errorspec.ErrorSpec`: sample period, position
resolution or significant digits, torque timing, torque error, stated qd_max and qdd_max, model error, sources)
replaces ``--bound``: the derived interval equation (:mod:`ident.robots.serial_certified`) of the whole log,
the Oettli-Prager hull in the physical prior (as ``--urdf`` documents), the stated motion bounds checked
against the data, and the term that dominates the radii. An optional ``[certified]`` table (the H4's keys where
they apply) sets the kernel: ``kernel_steps`` (even; default none: every kernel of
the serial family, :func:`ident.robots.serial_certified.certified_family`), ``kernel_shape`` (``triangle``,
the default, or ``hann``), ``stride`` [samples] (default: a kernel of L steps takes a row every ``L // 4``
samples, or more often on a short log, :func:`ident.robots.serial_certified.serial_strides`) and ``refine`` (default :data:`REFINE`: at most that
many rounds of the hull with the last box as prior, until the widths' geometric mean shrinks by less than
:data:`REFINE_RTOL`; the first rounds on every ``coarse_step``-th window only:
:func:`ident.estimators.uncertain_signed.signed_uncertain_hull`).
"""

from __future__ import annotations

import time
import tomllib
from pathlib import Path

import numpy as np

from h4bench import ident
from h4bench.ident.processing.choice import check_kernel_steps
from h4bench.scenarios.certified_verdict import (SERIAL_HINTS, contradicted_entry, prior_diagnosis,
                                                 row_radius_summary)
from h4bench.scenarios.identify import OptionError, read_serial_log, urdf_robot_and_prior
from h4bench.scenarios.rundir import RUNS_DIR, OwnedFolder, check_target, write_json
from h4bench.scenarios.threads import hull_processes

__all__ = ["REFINE", "REFINE_RTOL", "identify_urdf_spec", "read_kernel"]

REFINE_RTOL = 0.02  # stop refining when the widths' geometric mean shrank by less than this in a round
# at most this many rounds of the hull with the last box as prior: the box keeps shrinking for many rounds (each
# round's chords of |theta| over a smaller box), so REFINE_RTOL, not this cap, ends them (per-round widths and
# seconds: benchmarks/bench_serial_certified.py prints them)
REFINE = 16
_KEYS = {"kernel_steps": int, "kernel_shape": str, "stride": int, "refine": int}


def read_kernel(spec_path) -> dict:
    """The optional ``[certified]`` table of the spec file for a serial robot: ``kernel_steps`` (even, >=
    :data:`ident.processing.choice.MIN_KERNEL_STEPS`; default None: the rows of every kernel of the serial family,
    :func:`ident.robots.serial_certified.certified_family`), ``kernel_shape`` (``triangle`` or ``hann``),
    ``stride`` [samples] (default None: :func:`ident.robots.serial_certified.serial_strides`),
    ``refine`` (default :data:`REFINE`); the H4's ``curvature_every`` does
    not apply. Errors name ``--spec`` and the file."""
    path = Path(spec_path)
    try:
        table = tomllib.loads(path.read_text()).get("certified", {})
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise OptionError(f"--spec {path}: cannot read it as TOML ({exc})") from None
    if not isinstance(table, dict) or set(table) - set(_KEYS):
        raise OptionError(f"--spec {path} [certified]: with --urdf expected some of {sorted(_KEYS)}, got "
                          f"{sorted(table) if isinstance(table, dict) else table!r}")
    out = {"kernel_steps": None, "kernel_shape": "triangle", "stride": None, "refine": REFINE, **table}
    for k, kind in _KEYS.items():
        if not (k in ("kernel_steps", "stride") and out[k] is None) and (isinstance(out[k], bool) or not isinstance(out[k], kind)):
            raise OptionError(f"--spec {path} [certified].{k} must be {kind.__name__}, got {out[k]!r}")
    if out["kernel_steps"] is not None:
        try:
            check_kernel_steps(out["kernel_steps"])
        except ValueError as exc:
            raise OptionError(f"--spec {path} [certified].{exc}") from None
        if out["kernel_steps"] % 2:
            raise OptionError(f"--spec {path} [certified].kernel_steps must be even (a triangle of two halves of "
                              f"kernel_steps / 2 steps), got {out['kernel_steps']!r}")
    if out["kernel_shape"] not in ("triangle", "hann"):
        raise OptionError(f"--spec {path} [certified].kernel_shape must be triangle or hann, got "
                          f"{out['kernel_shape']!r}")
    if out["stride"] is not None and out["stride"] < 1:
        raise OptionError(f"--spec {path} [certified].stride must be an integer >= 1 [samples], got {out['stride']!r}")
    if out["refine"] < 0:
        raise OptionError(f"--spec {path} [certified].refine must be an integer >= 0, got {out['refine']!r}")
    return out


def identify_urdf_spec(path, urdf, spec_path, *, mass=None, reach=None, friction: bool = True,
                       rotor_inertia: bool = True, offset: bool = True, coupled_wrist=None, out=None,
                       progress=None) -> dict:
    """The certified box of a joint-side CSV log (``t, q1..qn, tau1..taun``) of the serial robot ``urdf`` under the
    error specification ``spec_path``; writes ``result.json`` into ``out``. Returns the result dict
    (``methods.certified``, ``error_model``, ``certified``; ``consistent`` False when the data contradict the
    spec: the hull's set is proven empty). progress : callable(stage, done, total) or None (the equation's windows,
    the hull's rounds)."""
    from h4bench.ident.processing.errorspec import ErrorSpec, ErrorSpecError
    from h4bench.ident.estimators.uncertain_signed import coarse_step, signed_uncertain_hull
    from h4bench.ident.processing.motion_check import check_motion_bounds
    from h4bench.ident.robots.serial_certified import certified_equation, certified_family, serial_strides

    from h4bench.ident.workers import prewarm

    prewarm(hull_processes())  # the certified stage's second process starts while the URDF and the log are read
    t0 = time.perf_counter()

    def stage(name):  # progress(done, total) of one stage, or None
        return None if progress is None else (lambda done, total: progress(name, done, total))
    robot, base, prior_info = urdf_robot_and_prior(urdf, mass, reach, friction=friction, rotor_inertia=rotor_inertia,
                                                   offset=offset, coupled_wrist=coupled_wrist)
    nj = robot.n_joints
    spec_path = Path(spec_path)
    if not spec_path.is_file():
        raise OptionError(f"--spec must name an existing TOML file, got {str(spec_path)!r} (not found)")
    try:
        spec = ErrorSpec.from_toml(spec_path, nj)
    except ErrorSpecError as exc:
        msg = str(exc)
        raise OptionError(msg if msg.startswith("--spec") else f"--spec {spec_path}: {msg}") from None
    kernel = read_kernel(spec_path)
    out = check_target(Path(out) if out is not None else RUNS_DIR / f"identify-{Path(path).stem}")
    q, tau, dt = read_serial_log(path, nj)
    if abs(dt - spec.sample_period) > 1e-3 * spec.sample_period:
        raise OptionError(f"--spec {spec_path}: sample_period = {spec.sample_period:g} s, but the log {str(path)!r} "
                          f"is sampled every {dt:g} s")
    check = check_motion_bounds(q, spec)
    result = {
        "scenario": f"identify-{Path(path).stem}", "kind": "identify", "robot": str(urdf), "source": str(path),
        "samples": int(q.shape[0]), "dt": dt, "joints": list(robot.joint_names), "parameters": list(base.names),
        "parameter_expressions": list(base.expressions), "parameter_units": list(base.units),
        "standard_parameters": list(robot.names), "true": None, "rows": 0, "prior": prior_info,
        "error_model": {**spec.to_dict(), "file": str(spec_path)}, "consistent": None,
        "base_parameters": {"count": len(base), "standard_count": robot.n_parameters,
                            "singular_gap": base.singular_gap},
    }
    result["error_model"]["sources"].update(stated_assumptions(spec))
    if check.contradicted:  # a false premise: no equation, no box
        result.update(consistent=False, methods={"certified": contradicted_entry(check, f"--spec {spec_path}")},
                      certified={"spec_check": check.to_dict()})
        return _write(out, result)
    try:
        if kernel["kernel_steps"] is None:
            eq = certified_family(robot, base, q, tau, spec, stride=kernel["stride"],
                                  kernel_shape=kernel["kernel_shape"], progress=stage("certified equation"),
                                  processes=hull_processes())
        else:
            eq = certified_equation(robot, base, q, tau, spec, half_width=kernel["kernel_steps"] // 2,
                                    stride=kernel["stride"] or serial_strides(q.shape[0], [kernel["kernel_steps"]])[0],
                                    kernel_shape=kernel["kernel_shape"],
                                    progress=stage("certified equation"))
    except ValueError as exc:
        raise OptionError(f"CSV {str(path)!r} with --spec {spec_path}: {exc}") from None
    if len(eq) <= len(base):
        raise OptionError(f"CSV {str(path)!r} with --spec {spec_path}: {len(eq)} rows ({eq.info['windows']} kernel "
                          f"windows x {nj} joints) must exceed the {len(base)} base parameters: a longer log or a "
                          "smaller [certified] stride")
    result["rows"] = len(eq)
    prior = ident.Box(np.asarray(prior_info["lower"]), np.asarray(prior_info["upper"]), names=base.names)
    entry: dict = {"kind": "guaranteed", "rigorous": True}
    t1 = time.perf_counter()
    try:
        windows = len(np.unique(eq.window, axis=0))
        box = signed_uncertain_hull(eq.Wc, eq.D, eq.y, eq.bound, prior, refine=int(kernel["refine"]),
                                    rtol=REFINE_RTOL, coarse=coarse_step(windows), groups=eq.window,
                                    processes=hull_processes(), progress=stage("certified hull: rounds (at most)"))
    except ident.InconsistentDataError as exc:
        box = None
        scale = getattr(exc, "scale_lower", None)
        entry.update(status="inconsistent", message=str(exc), error=type(exc).__name__, scale_lower=scale)
        result["consistent"] = False
        result["inconsistency"] = {"scale_lower": scale, "min_bound": None if scale is None else
                                   float(scale * np.max(eq.bound))}
    if box is not None:
        result["consistent"] = True
        rel = box.width / (prior.upper - prior.lower)
        entry.update(status="ok", lower=box.lower.tolist(), upper=box.upper.tolist(), width=box.width.tolist(),
                     relative_width_to_prior=rel.tolist(), narrowed_parameters=int(np.sum(rel < 0.99)),
                     info={k: box.info.get(k) for k in ("nonempty_proven", "refinements", "coarse_rounds", "lp_solves",
                                                        "lp_limit_hits", "lp_retries", "lp_fallbacks",
                                                        "lp_fallback_parameters")})
    entry["seconds"] = time.perf_counter() - t1
    theta_abs = (np.maximum(np.abs(box.lower), np.abs(box.upper)) if box is not None
                 else np.maximum(np.abs(prior.lower), np.abs(prior.upper)))
    result["methods"] = {"certified": entry}
    at = "the certified box's largest |theta|" if box is not None else "the prior's largest |theta|"
    result["certified"] = {
        "rows": len(eq), "kernel": {k: eq.info.get(k) for k in ("kernel", "half_width", "stride", "window_seconds",
                                                                 "secant_half_span", "kernels")},
        "geometry": eq.info["geometry"], **eq.summary(theta_abs),
        "terms_at": "|theta| = the certified box's largest magnitudes (the prior's when the set is empty)",
        "row_radius": row_radius_summary(eq.bound, eq.D, theta_abs, at),
        "spec_check": check.to_dict(), "seconds": {"equation": eq.info["seconds"], "total": time.perf_counter() - t0},
    }
    if box is not None:
        result["certified"]["prior_diagnosis"] = prior_diagnosis(base.names, rel, eq.terms, theta_abs, eq.y,
                                                                 SERIAL_HINTS)
    return _write(out, result)


def stated_assumptions(spec) -> dict:
    """What the serial certified equation states without proving it (:mod:`ident.robots.serial_certified`'s
    docstring), entry -> source, for ``error_model.sources``."""
    out = {"regressor_float": "stated, not proven: the regressor's floating-point error (ident.robots.chain for a "
                              "chain of revolute joints, pinocchio otherwise) is below 1e-12 of the magnitudes "
                              "summed (the rows' float term; measured against long double: about 2e-15 of each "
                              "joint row's largest entry)"}
    if spec.torque_timing == "sample" and spec.torque_rate is None:
        out["torque_between_samples"] = ("stated, not proven: between samples the torque stays within torque_error "
                                         "of the samples' linear interpolation (no torque_rate)")
    return out


def _write(out, result: dict) -> dict:
    with OwnedFolder(out, what={"scenario": result["scenario"], "kind": "identify"}) as tmp:
        write_json(tmp / "result.json", result)
    return result
