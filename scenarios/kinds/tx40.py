"""Kind ``tx40``: guaranteed boxes on a real robot's measured torques (Staubli TX40, ``data/tx40``).

The H4 scenarios know the truth; here nothing is known but the log. The study (:func:`run_tx40`; its stages are in
:mod:`scenarios.tx40_steps`, the plots and report in :mod:`scenarios.tx40_report`):

1. the paper's processing (:func:`ident.robots.serial.process`): zero-phase Butterworth on q, central differences,
   the TX40 base regressor (URDF, pinocchio), parallel filter + decimation with the bound propagated
   (``|h| * b = ||h||_1 b`` plus the filter's rigorous rounding); the first ``identify_fraction`` of the log
   identifies, the rest validates (processed separately: no sample is shared);
2. WLS with %sigma (:func:`ident.wls`) and its held-out torque RMS;
3. the minimum consistent bound: all rows, each joint alone, and the joint-shaped bound ``s t_j`` (the
   smallest common scale s of the per-joint minima t_j that makes all rows consistent); what part is
   friction-model error and what part noise: the same minima with a richer friction law (direction-dependent
   viscous, Stribeck, quadratic; :func:`ident.robots.serial.rich_friction_columns`), and the residual spectrum (the
   in-band level against the high-frequency noise floor);
4. hull boxes (:func:`ident.estimate`) at ``factors`` times the joint-shaped bound, in a physical prior
   (:func:`ident.robots.tx40.standard_prior` mapped exactly to the base parameters);
5. the q-relaxed hull (:func:`ident.relaxed_hull`) at ``outlier_factor`` (< 1) times that bound: rows proven
   outliers (certain) whatever theta in the relaxed box;
6. held-out validation: the guaranteed torque envelope ``[min, max] W_k theta`` over each box (rigorous interval
   evaluation, exact for a linear function over a box), widened by the propagated bound, against the
   measured held-out torques; its coverage beside the WLS prediction's RMS error.

Honesty: the bound is derived from the identification data (no truth exists), so the boxes are guaranteed only
under the stated assumption ``|e| <= factor x`` the bound the identification part needs; the held-out coverage
is the test of that assumption on data the estimators never saw.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from h4bench.scenarios import tx40_certified, tx40_report, tx40_steps

DESCRIPTION = "real Staubli TX40 log: WLS, min consistent bound, hull boxes, q-relaxed outliers, held-out envelope"

SPEC_DEFAULTS = {
    "tx40": {
        "samples": 0,  # 0: the whole log (45 000 samples, 9 s)
        "identify_fraction": 2.0 / 3.0,
        "cutoff_hz": 100.0,  # Butterworth on q, one pass (the FIGAROH example's 100 Hz)
        "butter_order": 4,
        "decimation": 100,  # 5 kHz -> 50 Hz rows; the motion holds 99.9 % of its velocity power below 7.5 Hz
        "numtaps": 401,  # 4 x decimation + 1 Hamming taps: ||h||_1 = 1.06, 80 ms windows
        "fir_cutoff": 0.8,
        "speed_threshold": 0.05,  # rad/s: sign(qd) not trusted below
        "base_samples": 200,
        "factors": [1.1, 1.5, 2.0],
        "outlier_factor": 0.9,
        "outlier_q": 8,
        "relaxed_method": "groups",
        "stribeck_velocity": 0.1,  # rad/s, of the richer friction law
        "noise_band_hz": [500.0, 2500.0],  # high-frequency band where W has no content: the torque-noise floor
        "envelope_stride": 2,  # held-out rows (per joint) whose envelope over the feasible polytope is computed
        "envelope_factor": 1.1,  # the box whose polytope envelope is computed (the tightest: the hardest test)
        # --error-model derived (scenarios.tx40_certified): the certified box's settings and the log's stated
        # specification, every entry with its source
        **tx40_certified.DEFAULTS,
    },
}


def _check(cfg: dict) -> None:
    from h4bench.scenarios.spec import ScenarioError

    if not 0.2 <= cfg["identify_fraction"] <= 0.9:
        raise ScenarioError(f"tx40.identify_fraction must be in [0.2, 0.9], got {cfg['identify_fraction']!r}")
    if not cfg["factors"] or any(not isinstance(f, (int, float)) or f < 1.0 for f in cfg["factors"]):
        raise ScenarioError(f"tx40.factors must be a non-empty list of numbers >= 1, got {cfg['factors']!r}")
    if not 0.0 < cfg["outlier_factor"] < 1.0:
        raise ScenarioError(f"tx40.outlier_factor must be in (0, 1), got {cfg['outlier_factor']!r}")
    if cfg["samples"] < 0 or (0 < cfg["samples"] < 3000):
        raise ScenarioError(f"tx40.samples must be 0 (all) or >= 3000, got {cfg['samples']!r}")


def run_tx40(cfg: dict, seed: int, progress=None) -> tuple[dict, dict]:
    """The TX40 study (module docstring), stage by stage (:mod:`scenarios.tx40_steps`).

    Parameters
    ----------
    cfg : dict
        The ``[tx40]`` spec section (:data:`SPEC_DEFAULTS`).
    seed : int
        Seed of the random states of the base-parameter QR.
    progress : callable(stage, i, n) or None

    Returns
    -------
    result : dict
        JSON-ready (the schema is in ``docs/results.md``).
    artefacts : dict
        Arrays for the plots: ``eq``, ``eq_ho`` (identification and held-out equations), ``wls_theta``,
        ``res_ho``, ``boxes``, ``envelope``, ``spectrum``, ``prior`` (lower, upper), ``dt`` [s]; ``study``
        (the stages' record, for the certified box).
    """
    _check(cfg)
    progress = progress or (lambda *a: None)
    t_start, cpu_start = time.perf_counter(), time.process_time()
    stages = 8
    progress("load", 0, stages)
    s = tx40_steps.load(cfg, seed)
    progress("processing", 1, stages)
    tx40_steps.process_log(s)
    progress("wls", 2, stages)
    tx40_steps.fit_wls(s)
    progress("min consistent bound", 3, stages)
    tx40_steps.consistent_bounds(s)
    progress("hull boxes", 4, stages)
    tx40_steps.hull_boxes(s)
    if s.envelope is not None:  # the envelope over the feasible polytope itself (an LP per endpoint) on some rows
        progress("polytope envelope", 5, stages)
        tx40_steps.polytope_envelope(s)
    progress("q-relaxed hull", 6, stages)
    tx40_steps.relaxed(s)
    progress("result", 7, stages)
    result = tx40_steps.result_dict(s, {"total": time.perf_counter() - t_start,
                                   "cpu_total": time.process_time() - cpu_start})
    artefacts = {"eq": s.eq, "eq_ho": s.eq_ho, "wls_theta": s.w.theta, "res_ho": s.res_ho, "boxes": s.boxes,
                 "envelope": s.envelope, "spectrum": s.spec, "prior": (s.blo, s.bhi), "dt": s.log.dt, "study": s}
    return result, artefacts


USES_MODEL = False  # the TX40 comes from its URDF and logs: an H4 --model does not apply


def judge_estimators(methods, result: dict, art: dict) -> dict | None:
    """The spec's estimators (``[estimators] methods`` or ``--methods``) side by side at the envelope's bound
    factor (else the first hull's), the exact hull as reference (:mod:`scenarios.judging`): no truth, so
    ``enclosed`` is null; the narrower-than-hull check runs. None when no hull box was obtained."""
    from h4bench.ident import Box
    from h4bench.scenarios import judging

    env = art.get("envelope")
    name = env["name"] if env is not None else next(iter(art["boxes"]), None)
    if name is None:
        return None
    eq, m = art["eq"], result["methods"][name]
    bound = eq.bound(np.asarray(m["bound_raw_per_joint"], dtype=float))
    prior = Box(*art["prior"], tuple(result["parameters"]))
    outcomes, hull = judging.run_methods(list(methods), eq.W, eq.y, bound, prior,
                                         {"groups": np.asarray(eq.joint, dtype=np.int64)})
    hull = hull if hull is not None else judging.Outcome("hull", None, "ok", box=art["boxes"][name][1])
    ref = judging.hull_reference(eq.W, eq.y, bound, prior, hull.box) if hull.status == "ok" else None
    return tx40_steps.jsonable({"factor": m["factor"], "methods": judging.judge(outcomes, ref, None, result["parameters"]),
                      "hull_reference": None if ref is None else ref.describe()})


def judged_text(result: dict) -> str:
    """The report's side-by-side section of :func:`judge_estimators`."""
    from h4bench.scenarios.judging import judged_table

    j = result.get("estimators")
    if not j:
        return ""
    ref = j["hull_reference"] or {}
    return "\n".join(["", f"## Every estimator at {j['factor']:g}x the bound (the exact hull as reference)", "",
                      judged_table(j["methods"]), "",
                      f"Narrower-than-hull tolerance: {ref.get('source', 'no hull box')} "
                      f"({ref.get('proven_points', 0)} hull LP points proven feasible). No truth: `enclosed` is null.",
                      ""])


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    """Registry entry point: the study, then result files (report.md, PNG plots) in ``out``. With
    ``certified.enabled`` (``--error-model derived``) also the certified box (:mod:`scenarios.tx40_certified`):
    the method entry ``certified``, ``error_model`` and ``certified`` in the result."""
    if spec["certified"]["enabled"]:  # the certified stage's second process starts during the tuned study
        from h4bench.ident.workers import prewarm
        from h4bench.scenarios.threads import hull_processes

        prewarm(hull_processes())
    result, art = run_tx40(spec["tx40"], seed, progress)
    result["quick"] = bool(spec.get("quick_applied", False))
    result["estimators"] = judge_estimators(spec["estimators"]["methods"], result, art)
    cert = None
    if spec["certified"]["enabled"]:
        env = art.get("envelope")
        ok = [n for n, m in result["methods"].items() if m["status"] == "ok"]
        tuned = result["methods"][env["name"]] if env is not None else (result["methods"][ok[0]] if ok else None)
        cert = tx40_certified.certify(art["study"], spec["tx40"], tuned, progress)
    out = Path(out)
    tx40_report.plots(result, art, out)
    text = tx40_report.report_text(result) + judged_text(result)
    if cert is not None:  # after the tuned report: its tables list the tuned hulls only
        result["methods"]["certified"] = cert["entry"]
        result["error_model"], result["certified"] = cert["error_model"], cert["certified"]
        text += "\n".join(tx40_certified.report_lines(result)) + "\n"
    (out / "report.md").write_text(text)
    json.dumps(result)  # JSON-ready check (the runner writes result.json)
    return result
