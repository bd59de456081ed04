"""Kind ``tx40``: guaranteed boxes on a real robot's measured torques (Staubli TX40, ``data/tx40``).

The H4 scenarios know the truth; here nothing is known but the log. The study (:func:`run_tx40`):

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

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

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
    },
}


def _check(cfg: dict) -> None:
    from scenarios.spec import ScenarioError

    if not 0.2 <= cfg["identify_fraction"] <= 0.9:
        raise ScenarioError(f"tx40.identify_fraction must be in [0.2, 0.9], got {cfg['identify_fraction']!r}")
    if not cfg["factors"] or any(not isinstance(f, (int, float)) or f < 1.0 for f in cfg["factors"]):
        raise ScenarioError(f"tx40.factors must be a non-empty list of numbers >= 1, got {cfg['factors']!r}")
    if not 0.0 < cfg["outlier_factor"] < 1.0:
        raise ScenarioError(f"tx40.outlier_factor must be in (0, 1), got {cfg['outlier_factor']!r}")
    if cfg["samples"] < 0 or (0 < cfg["samples"] < 3000):
        raise ScenarioError(f"tx40.samples must be 0 (all) or >= 3000, got {cfg['samples']!r}")


def _select(eq, cols):
    """The equation restricted to some columns (the rounding term, computed for all columns, stays: outer)."""
    return dataclasses.replace(eq, W=eq.W[:, cols], names=tuple(eq.names[c] for c in cols), info=dict(eq.info))


def _per_joint(x, joint, fn, nj=6):
    return [float(fn(x[joint == j])) if np.any(joint == j) else float("nan") for j in range(nj)]


def _rms(x):
    return np.sqrt(np.mean(np.square(x)))


def _spectrum(raw: dict, theta: np.ndarray, r: int, dt: float, band, pass_hz: float, taps) -> dict:
    """Residual spectrum of the unfiltered rows at theta (WLS): per joint the noise floor (median PSD in
    ``band``), the in-band (below ``pass_hz``) mean PSD and their ratio, and the white-noise RMS the parallel
    filter lets into a processed row, ``sqrt(S fs/2) ||h||_2``."""
    import scipy.signal

    res = raw["y"] - np.einsum("njc,c->nj", raw["W"][:, :, :r], theta)
    f, P = scipy.signal.welch(res, fs=1.0 / dt, nperseg=4096, axis=0)
    hi = (f >= band[0]) & (f <= band[1])
    lo = (f > 0) & (f <= pass_hz)
    floor = np.median(P[hi], axis=0)
    inband = np.mean(P[lo], axis=0)
    white = np.sqrt(floor * 0.5 / dt) * np.linalg.norm(taps)
    return {"freq": f, "psd": P, "floor": floor, "inband": inband, "ratio": inband / floor,
            "white_rms_processed": white, "raw_rms": np.sqrt(np.mean(res**2, axis=0))}


def run_tx40(cfg: dict, seed: int, progress=None) -> tuple[dict, dict]:
    """The TX40 study (module docstring). cfg : the ``[tx40]`` spec section (:data:`SPEC_DEFAULTS`); seed : of the
    random states of the base-parameter QR; progress : callable(stage, i, n) or None.
    Returns (result: JSON-ready dict, artefacts: arrays for the plots)."""
    import ident
    from ident.robots import tx40
    from ident.processing.filtering import decimation_fir
    from ident.estimators.hull import chebyshev
    from ident.numerics.interval import point_matvec
    from ident.estimators.outliers import OutlierBudgetError
    from ident.robots.serial import prediction_envelope, process

    _check(cfg)
    progress = progress or (lambda *a: None)
    t_start, cpu_start = time.perf_counter(), time.process_time()
    seconds = {}
    stages = 8
    progress("load", 0, stages)
    log = tx40.load_log()
    n = log.q.shape[0] if not cfg["samples"] else min(int(cfg["samples"]), log.q.shape[0])
    q, tau = log.q[:n], log.tau[:n]
    robot = tx40.robot()
    t0 = time.perf_counter()
    base = robot.base(int(cfg["base_samples"]), seed)
    r = len(base)
    lo_s, hi_s = tx40.standard_prior(robot)
    blo, bhi = base.box_from_standard(lo_s, hi_s)
    flo, fhi = tx40.rich_friction_prior(robot)
    t_abs = np.maximum(np.abs(np.r_[blo, flo]), np.abs(np.r_[bhi, fhi]))
    seconds["base_parameters"] = time.perf_counter() - t0

    progress("processing", 1, stages)
    t0 = time.perf_counter()
    n1 = round(cfg["identify_fraction"] * n)
    kw = {"cutoff_hz": cfg["cutoff_hz"], "decimation": int(cfg["decimation"]), "numtaps": int(cfg["numtaps"]) or None,
          "fir_cutoff": cfg["fir_cutoff"], "speed_threshold": cfg["speed_threshold"], "theta_abs_max": t_abs,
          "butter_order": int(cfg["butter_order"]), "rich_friction": cfg["stribeck_velocity"],
          "torque_timing": "sample"}  # the regressor at the sampling instants (the log's processing, unchanged)
    eq_rich = process(robot, base, q[:n1], tau[:n1], log.dt, keep_raw=True, **kw)
    eq_ho_rich = process(robot, base, q[n1:], tau[n1:], log.dt, first_sample=n1, **kw)
    raw = eq_rich.info.pop("raw")
    eq, eq_ho = _select(eq_rich, np.arange(r)), _select(eq_ho_rich, np.arange(r))
    prior = ident.Box(blo, bhi, names=base.names)
    gain = eq.gain
    taps = decimation_fir(int(cfg["decimation"]), int(cfg["numtaps"]) or None, cfg["fir_cutoff"])
    seconds["processing"] = time.perf_counter() - t0

    progress("wls", 2, stages)
    t0 = time.perf_counter()
    w = ident.wls(eq.W, eq.y, joints=6, names=base.names, joint_of_row=eq.joint)
    res_id = eq.y - eq.W @ w.theta
    res_ho = eq_ho.y - eq_ho.W @ w.theta
    seconds["wls"] = time.perf_counter() - t0

    progress("min consistent bound", 3, stages)
    t0 = time.perf_counter()
    t_all = ident.min_consistent_bound(eq.W, eq.y, prior)
    t_j = np.array(_per_joint(np.arange(len(eq)), eq.joint,
                              lambda rows: ident.min_consistent_bound(eq.W[rows], eq.y[rows], prior)))
    scale = float(chebyshev(eq.W, eq.y, t_j[eq.joint], blo, bhi).upper)
    b_joint = scale * t_j  # processed-row bound per joint that makes all identification rows consistent
    rich_prior = (np.r_[blo, flo], np.r_[bhi, fhi])
    t_all_rich = ident.min_consistent_bound(eq_rich.W, eq_rich.y, rich_prior)
    t_j_rich = np.array(_per_joint(np.arange(len(eq)), eq.joint,
                                   lambda rows: ident.min_consistent_bound(eq_rich.W[rows], eq_rich.y[rows],
                                                                           rich_prior)))
    w_rich = ident.wls(eq_rich.W, eq_rich.y, joints=6, names=eq_rich.names, joint_of_row=eq_rich.joint)
    res_ho_rich = eq_ho_rich.y - eq_ho_rich.W @ w_rich.theta
    pass_hz = cfg["fir_cutoff"] * 0.5 / (log.dt * cfg["decimation"])
    spec = _spectrum(raw, w.theta, r, log.dt, cfg["noise_band_hz"], pass_hz, taps)
    seconds["min_consistent_bound"] = time.perf_counter() - t0

    progress("hull boxes", 4, stages)
    methods, boxes, envelope = {}, {}, None
    for k in cfg["factors"]:
        name = f"hull_{k:g}x"
        t0 = time.perf_counter()
        b = eq.bound(k * b_joint / gain)
        try:
            box = ident.estimate(eq.W, eq.y, b, prior, method="hull")
        except ident.InconsistentDataError as exc:
            methods[name] = {"status": "inconsistent", "message": str(exc), "seconds": time.perf_counter() - t0}
            continue
        boxes[name] = (k, box)
        lo_e, hi_e = point_matvec(eq_ho.W, box.lower, box.upper)
        b_ho = eq_ho.bound(k * b_joint / gain)
        inside_model = (eq_ho.y >= lo_e) & (eq_ho.y <= hi_e)
        inside = (eq_ho.y >= lo_e - b_ho) & (eq_ho.y <= hi_e + b_ho)
        excess = np.maximum(0.0, np.maximum(lo_e - b_ho - eq_ho.y, eq_ho.y - hi_e - b_ho))
        methods[name] = {
            "status": "ok", "factor": k, "lower": box.lower.tolist(), "upper": box.upper.tolist(),
            "width": box.width.tolist(), "relative_width_to_prior": (box.width / (bhi - blo)).tolist(),
            "wls_inside": bool(box.contains(w.theta).all()),
            "seconds": time.perf_counter() - t0,
            "bound_processed_per_joint": (k * b_joint).tolist(),
            "bound_raw_per_joint": (k * b_joint / gain).tolist(),
            "heldout_coverage": float(np.mean(inside)),
            "heldout_coverage_per_joint": _per_joint(inside, eq_ho.joint, np.mean),
            "heldout_coverage_model_envelope": float(np.mean(inside_model)),
            "heldout_envelope_halfwidth_mean_per_joint": _per_joint(0.5 * (hi_e - lo_e), eq_ho.joint, np.mean),
            "heldout_max_excess_per_joint": _per_joint(excess, eq_ho.joint, np.max),
            "info": {kk: box.info.get(kk) for kk in ("cond", "nonempty_proven", "lp_solves", "working_rows")},
        }
        if envelope is None or k == cfg["envelope_factor"]:
            envelope = {"factor": k, "lower": lo_e, "upper": hi_e, "bound": b_ho, "name": name}
    seconds["hulls"] = sum(m["seconds"] for m in methods.values())

    if envelope is not None:  # the envelope over the feasible polytope itself (an LP per endpoint) on some rows
        progress("polytope envelope", 5, stages)
        t0 = time.perf_counter()
        k, box = boxes[envelope["name"]]
        stride = max(1, int(cfg["envelope_stride"]))
        rows = np.concatenate([np.flatnonzero(eq_ho.joint == j)[::stride] for j in range(6)])
        lo_p, hi_p, pinfo = prediction_envelope(eq.W, eq.y, eq.bound(k * b_joint / gain), box.lower, box.upper,
                                                eq_ho.W[rows], center=w.theta)
        yb, bb = eq_ho.y[rows], envelope["bound"][rows]
        inside = (yb >= lo_p - bb) & (yb <= hi_p + bb)
        inside_model = (yb >= lo_p) & (yb <= hi_p)
        pred = eq_ho.W[rows] @ w.theta
        envelope.update({"rows": rows, "poly_lower": lo_p, "poly_upper": hi_p})
        methods[envelope["name"]]["heldout_polytope_envelope"] = {
            "rows": int(rows.size), "stride": stride, "coverage": float(np.mean(inside)),
            "coverage_per_joint": _per_joint(inside, eq_ho.joint[rows], np.mean),
            "coverage_model_envelope": float(np.mean(inside_model)),
            "halfwidth_mean_per_joint": _per_joint(0.5 * (hi_p - lo_p), eq_ho.joint[rows], np.mean),
            "wls_prediction_inside": float(np.mean((pred >= lo_p) & (pred <= hi_p))),
            "max_excess_per_joint": _per_joint(np.maximum(0.0, np.maximum(lo_p - bb - yb, yb - hi_p - bb)),
                                               eq_ho.joint[rows], np.max),
            "lp_solves": pinfo["lp_solves"], "lp_failures": pinfo["lp_failures"],
            "seconds": time.perf_counter() - t0}
        seconds["polytope_envelope"] = time.perf_counter() - t0

    progress("q-relaxed hull", 6, stages)
    t0 = time.perf_counter()
    kq, qq = cfg["outlier_factor"], int(cfg["outlier_q"])
    relaxed = {"factor": kq, "q": qq, "groups": qq + 1}
    try:
        rbox = ident.relaxed_hull(eq.W, eq.y, eq.bound(kq * b_joint / gain), prior, qq, method=cfg["relaxed_method"],
                                  groups=(qq + 1,))
        certain = np.asarray(rbox.info["certain_rows"], dtype=int)
        relaxed.update({
            "status": "ok", "lower": rbox.lower.tolist(), "upper": rbox.upper.tolist(),
            "certain_rows": certain.tolist(), "suspected_rows": rbox.info["suspected_rows"],
            "certain": [{"row": int(i), "joint": int(eq.joint[i]) + 1, "sample": int(eq.sample[i]),
                         "time": float(eq.sample[i] * log.dt), "wls_residual": float(res_id[i]),
                         "bound": float(eq.bound(kq * b_joint / gain)[i])} for i in certain],
            "exact": bool(rbox.info["exact"])})
    except OutlierBudgetError as exc:
        relaxed.update({"status": "budget exceeded", "message": str(exc),
                        "certain_rows": list(exc.certain_rows)})
    plain_needed = float(np.max(np.abs(res_id) / b_joint[eq.joint]))
    relaxed["rows_over_bound_at_wls"] = int(np.sum(np.abs(res_id) > kq * b_joint[eq.joint]))
    relaxed["wls_max_scaled_residual"] = plain_needed
    relaxed["seconds"] = time.perf_counter() - t0
    seconds["relaxed"] = relaxed["seconds"]

    progress("result", 7, stages)
    noise_share = np.clip(spec["white_rms_processed"] ** 2 / np.array(_per_joint(res_id, eq.joint, _rms)) ** 2, 0, 1)
    result = {
        "scenario": "tx40", "seed": int(seed), "robot": "Staubli TX40 (real log, data/tx40)",
        "parameters": list(base.names), "parameter_expressions": list(base.expressions),
        "parameter_units": list(base.units), "true": None, "oracle_residual": None,
        "bound": b_joint.tolist(),  # joint-shaped processed-row bound at 1x [N m]; boxes use factors x it
        "bound_info": {"kind": "joint-shaped, processed rows [N m]", "per_joint_at_1x": b_joint.tolist(),
                  "raw_per_joint_at_1x": (b_joint / gain).tolist(), "factors": list(cfg["factors"]),
                  "filter_l1_norm": gain, "rounding_max": float(eq.rounding.max())},
        "min_consistent_bound": float(t_all),
        "min_consistent_bound_per_joint": t_j.tolist(),
        "joint_shape_scale": scale,
        "min_consistent_bound_rich_friction": float(t_all_rich),
        "min_consistent_bound_per_joint_rich_friction": t_j_rich.tolist(),
        "prior": {"lower": blo.tolist(), "upper": bhi.tolist(), "source": "ident.robots.tx40.standard_prior mapped by B"},
        "data": {"samples": int(n), "identify_samples": int(n1), "heldout_samples": int(n - n1),
                 "rows_identify": len(eq), "rows_heldout": len(eq_ho), "dt": log.dt, **{
                     k: v for k, v in eq.info.items() if isinstance(v, (int, float, bool))}},
        "wls": {**w.to_dict(), "identify_rms_per_joint": _per_joint(res_id, eq.joint, _rms),
                "heldout_rms_per_joint": _per_joint(res_ho, eq_ho.joint, _rms),
                "heldout_rms": float(_rms(res_ho)),
                "heldout_torque_rms_per_joint": _per_joint(eq_ho.y, eq_ho.joint, _rms),
                "heldout_max_abs_error_per_joint": _per_joint(np.abs(res_ho), eq_ho.joint, np.max),
                "heldout_rms_per_joint_rich_friction": _per_joint(res_ho_rich, eq_ho_rich.joint, _rms)},
        "friction_vs_noise": {
            "residual_psd_floor_per_joint": spec["floor"].tolist(),
            "residual_psd_inband_per_joint": spec["inband"].tolist(),
            "inband_over_floor": spec["ratio"].tolist(),
            "white_noise_rms_processed_per_joint": spec["white_rms_processed"].tolist(),
            "noise_share_of_processed_residual_variance": noise_share.tolist(),
            "raw_residual_rms_per_joint": spec["raw_rms"].tolist(),
            "passband_hz": pass_hz, "noise_band_hz": list(cfg["noise_band_hz"]),
            "min_bound_reduction_rich_friction_per_joint": (1.0 - t_j_rich / t_j).tolist()},
        "methods": methods,
        "relaxed": relaxed,
        "base_parameters": {"count": r, "standard_count": robot.n_parameters, "singular_gap": base.singular_gap},
        "seconds": {**seconds, "total": time.perf_counter() - t_start, "cpu_total": time.process_time() - cpu_start},
    }
    artefacts = {"eq": eq, "eq_ho": eq_ho, "wls_theta": w.theta, "res_ho": res_ho, "boxes": boxes,
                 "envelope": envelope, "spectrum": spec, "prior": (blo, bhi), "dt": log.dt}
    return _jsonable(result), artefacts


def _jsonable(x):
    """numpy scalars and arrays inside dicts and lists -> Python floats, ints, bools and lists."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    return x


# ------------------------------------------------------------------------------------------- files, report
def _plots(result: dict, art: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = result["parameters"]
    p = len(names)
    ok = [m for m in result["methods"].values() if m["status"] == "ok"]
    if ok:
        ref = max(ok, key=lambda m: m["factor"])
        mid = 0.5 * (np.array(ref["lower"]) + np.array(ref["upper"]))
        half = np.maximum(0.5 * np.array(ref["width"]), 1e-300)
        fig, ax = plt.subplots(figsize=(8, 0.18 * p + 1.5))
        for i, m in enumerate(sorted(ok, key=lambda m: -m["factor"])):
            lo_ = (np.array(m["lower"]) - mid) / half
            hi_ = (np.array(m["upper"]) - mid) / half
            ax.barh(np.arange(p), hi_ - lo_, left=lo_, height=0.7 - 0.18 * i, label=f"hull at {m['factor']:g}x")
        ax.plot((art["wls_theta"] - mid) / half, np.arange(p), "k|", label="WLS")
        ax.set_yticks(np.arange(p), names, fontsize=6)
        ax.invert_yaxis()
        ax.set_xlabel(f"(theta - centre) / half-width of the {ref['factor']:g}x box")
        ax.legend(fontsize=7, loc="lower right")
        ax.set_title("TX40 base parameters: guaranteed boxes (normalised) and WLS")
        fig.tight_layout()
        fig.savefig(out / "boxes.png", dpi=110)
        plt.close(fig)
    env, eq_ho = art["envelope"], art["eq_ho"]
    if env is not None:
        fig, axes = plt.subplots(6, 1, figsize=(10, 12), sharex=True)
        pred = eq_ho.W @ art["wls_theta"]
        rows = env["rows"]
        for j, ax in enumerate(axes):
            sel = eq_ho.joint[rows] == j
            rj = rows[sel]
            t = eq_ho.sample[rj] * art["dt"]
            lo_p, hi_p, bb = env["poly_lower"][sel], env["poly_upper"][sel], env["bound"][rj]
            ax.fill_between(t, lo_p - bb, hi_p + bb, color="tab:orange", alpha=0.3, lw=0, label="envelope + bound")
            ax.fill_between(t, lo_p, hi_p, color="tab:orange", alpha=0.7, lw=0, label="model envelope")
            s = eq_ho.joint == j
            ax.plot(eq_ho.sample[s] * art["dt"], eq_ho.y[s], ".", ms=2, color="k", label="measured (processed)")
            ax.plot(eq_ho.sample[s] * art["dt"], pred[s], ".", ms=1.5, color="tab:blue", label="WLS prediction")
            ax.set_ylabel(f"joint {j + 1} [N m]")
        axes[0].legend(fontsize=7, ncol=4)
        axes[-1].set_xlabel("time [s] (held-out part of the log)")
        fig.suptitle(f"held-out torques and the guaranteed envelope over the feasible set at {env['factor']:g}x the "
                     "bound (every other row)")
        fig.tight_layout()
        fig.savefig(out / "envelope.png", dpi=100)
        plt.close(fig)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    j = np.arange(1, 7)
    a1.bar(j - 0.2, result["min_consistent_bound_per_joint"], 0.4, label="standard friction")
    a1.bar(j + 0.2, result["min_consistent_bound_per_joint_rich_friction"], 0.4, label="richer friction")
    a1.plot(j, result["friction_vs_noise"]["white_noise_rms_processed_per_joint"], "k_", ms=14,
            label="white-noise RMS in a processed row")
    a1.set_xlabel("joint")
    a1.set_ylabel("min consistent bound, joint alone [N m]")
    a1.legend(fontsize=7)
    if ok:
        f = [m["factor"] for m in ok]
        a2.plot(f, [np.median(m["relative_width_to_prior"]) for m in ok], "o-", label="median width / prior width")
        a2.plot(f, [m["heldout_coverage"] for m in ok], "s-", label="held-out coverage (envelope + bound)")
        a2.plot(f, [m["heldout_coverage_model_envelope"] for m in ok], "^-", label="held-out coverage (model only)")
        a2.set_xlabel("bound / joint-shaped min consistent bound")
        a2.set_yscale("log")
        a2.legend(fontsize=7)
    fig.suptitle("min consistent bound per joint, and the sweep over the assumed bound")
    fig.tight_layout()
    fig.savefig(out / "sweep.png", dpi=110)
    plt.close(fig)


def _fmt(v, d=3):
    return "nan" if v is None or not np.isfinite(v) else f"{v:.{d}g}"


def report_text(result: dict) -> str:
    """report.md of a tx40 run."""
    j6 = range(6)
    w, fn = result["wls"], result["friction_vs_noise"]
    row = lambda label, xs, d=3: f"| {label} | " + " | ".join(_fmt(x, d) for x in xs) + " |"
    lines = [
        f"# Scenario `tx40`: real Staubli TX40 log (seed {result['seed']})", "",
        (f"{result['data']['samples']} samples at {1 / result['data']['dt']:g} Hz; first "
        f"{result['data']['identify_samples']} identify ({result['data']['rows_identify']} processed rows), the "
        f"other {result['data']['heldout_samples']} validate ({result['data']['rows_heldout']} rows). "
        f"{len(result['parameters'])} base parameters (of {result['base_parameters']['standard_count']} standard). "
        f"Parallel filter ||h||_1 = {result['bound_info']['filter_l1_norm']:.4f}. No truth exists: the bound is derived "
        "from the identification rows (below), the held-out part tests it."), "",
        "## Torques per joint [N m]", "",
        "| | " + " | ".join(f"J{j + 1}" for j in j6) + " |", "|---|" + "---|" * 6,
        row("held-out torque RMS", w["heldout_torque_rms_per_joint"]),
        row("WLS held-out RMS error", w["heldout_rms_per_joint"]),
        row("WLS held-out max error", w["heldout_max_abs_error_per_joint"]),
        row("WLS held-out RMS, richer friction", w["heldout_rms_per_joint_rich_friction"]),
        row("min consistent bound, joint alone", result["min_consistent_bound_per_joint"]),
        row("same, richer friction", result["min_consistent_bound_per_joint_rich_friction"]),
        row("joint-shaped bound (1x)", result["bound"]),
        row("white-noise RMS in a processed row", fn["white_noise_rms_processed_per_joint"]),
        row("noise share of residual variance", fn["noise_share_of_processed_residual_variance"], 2),
        row("residual PSD in band / HF floor", fn["inband_over_floor"], 3), "",
        (f"- WLS held-out RMS error (all joints): {w['heldout_rms']:.4g} N m; min consistent bound over all rows "
        f"{result['min_consistent_bound']:.4g} N m (richer friction {result['min_consistent_bound_rich_friction']:.4g});"
        f" joint-shaped scale s = {result['joint_shape_scale']:.4g}."),
        (f"- Friction-model error against noise: the residual's PSD below {fn['passband_hz']:.3g} Hz (what the "
        f"processed rows keep) is the ratio above times the high-frequency noise floor "
        f"({fn['noise_band_hz'][0]:g}-{fn['noise_band_hz'][1]:g} Hz); white noise at that floor explains the "
        "'noise share' of the processed residual's variance, the rest is model error (friction law, "
        "unmodelled dynamics, derivative estimation). The richer friction law lowers the per-joint minimum by "
        + ", ".join(f"{100 * x:.0f} %" for x in fn["min_bound_reduction_rich_friction_per_joint"]) + "."), "",
        "## Hull boxes and held-out envelope", "",
        ("| bound | status | median width / prior | WLS inside | held-out coverage (envelope + bound) | model "
         "envelope only | seconds |"), "|---|---|---|---|---|---|---|",
    ]
    for name, m in result["methods"].items():
        if m["status"] == "ok":
            lines.append(f"| {m['factor']:g}x | ok | {np.median(m['relative_width_to_prior']):.3g} | {m['wls_inside']} | "
                         f"{m['heldout_coverage']:.4f} | {m['heldout_coverage_model_envelope']:.4f} | "
                         f"{m['seconds']:.3g} |")
        else:
            lines.append(f"| {name} | {m['status']} | | | | | {m['seconds']:.3g} |")
    ok = {n: m for n, m in result["methods"].items() if m["status"] == "ok"}
    for name, m in ok.items():
        pe = m.get("heldout_polytope_envelope")
        if pe:
            lines += ["", f"Envelope over the feasible set itself at {m['factor']:g}x ({pe['rows']} held-out rows, "
                      f"every {pe['stride']} per joint, {pe['lp_solves']} LPs with safe bounds, {pe['seconds']:.3g} s): "
                      f"coverage {pe['coverage']:.4f} (model envelope alone {pe['coverage_model_envelope']:.4f}); "
                      "mean half-width per joint " + ", ".join(_fmt(x) for x in pe["halfwidth_mean_per_joint"])
                      + " N m; max excess over envelope + bound per joint "
                      + ", ".join(_fmt(x) for x in pe["max_excess_per_joint"]) + " N m. The interval evaluation "
                      "over the box (table above) ignores the parameters' correlations: its mean half-widths are "
                      + ", ".join(_fmt(x) for x in m["heldout_envelope_halfwidth_mean_per_joint"]) + " N m."]
    if ok:
        lines += ["", "Box widths per parameter:", "", "| parameter | WLS | %sigma | " + " | ".join(ok) + " |",
                  "|---|---|---|" + "---|" * len(ok)]
        for i, nm in enumerate(result["parameters"]):
            lines.append(f"| {nm} | {w['theta'][i]:.4g} | {w['rel_std_percent'][i]:.3g} | "
                         + " | ".join(f"[{m['lower'][i]:.4g}, {m['upper'][i]:.4g}] ({m['width'][i]:.3g})"
                                      for m in ok.values()) + " |")
    rl = result["relaxed"]
    lines += ["", f"## q-relaxed hull at {rl['factor']:g}x the bound, q = {rl['q']}", ""]
    if rl.get("status") == "ok":
        lines.append(f"- certain outliers (rows proven to break the bound for every theta of the relaxed box): "
                     f"{len(rl['certain_rows'])}")
        for c in rl["certain"]:
            lines.append(f"  - row {c['row']}: joint {c['joint']}, t = {c['time']:.3f} s, WLS residual "
                         f"{c['wls_residual']:+.3g} N m against the bound {c['bound']:.3g}")
        lines.append(f"- suspected (violated at the reference point): {len(rl['suspected_rows'])}")
    else:
        lines.append(f"- {rl.get('status')}: {rl.get('message', '')}")
    lines.append(f"- rows over {rl['factor']:g}x the bound at the WLS estimate: {rl['rows_over_bound_at_wls']}; "
                 f"{rl['seconds']:.3g} s")
    lines += ["", "## Runtime [s]", "", ", ".join(f"{k} {v:.3g}" for k, v in result["seconds"].items()), "",
              ("Plots: `boxes.png` (boxes normalised to the widest, WLS marked), `envelope.png` (held-out torques "
               "in the guaranteed envelope), `sweep.png` (min consistent bound per joint; widths and coverage "
               "against the assumed bound)."), "",
              "Base parameters (base <- standard):", ""]
    lines += [f"- `{n}` = {e}" for n, e in zip(result["parameters"], result["parameter_expressions"])]
    return "\n".join(lines) + "\n"


USES_MODEL = False  # the TX40 comes from its URDF and logs: an H4 --model does not apply


def judge_estimators(methods, result: dict, art: dict) -> dict | None:
    """The spec's estimators (``[estimators] methods`` or ``--methods``) side by side at the envelope's bound
    factor (else the first hull's), the exact hull as reference (:mod:`scenarios.judging`): no truth, so
    ``enclosed`` is null; the narrower-than-hull check runs. None when no hull box was obtained."""
    from ident import Box
    from scenarios import judging

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
    return _jsonable({"factor": m["factor"], "methods": judging.judge(outcomes, ref, None, result["parameters"]),
                      "hull_reference": None if ref is None else ref.describe()})


def judged_text(result: dict) -> str:
    """The report's side-by-side section of :func:`judge_estimators`."""
    from scenarios.judging import judged_table

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
    """Registry entry point: the study, then result files (report.md, PNG plots) in ``out``."""
    result, art = run_tx40(spec["tx40"], seed, progress)
    result["quick"] = bool(spec.get("quick_applied", False))
    result["estimators"] = judge_estimators(spec["estimators"]["methods"], result, art)
    out = Path(out)
    _plots(result, art, out)
    (out / "report.md").write_text(report_text(result) + judged_text(result))
    json.dumps(result)  # JSON-ready check (the runner writes result.json)
    return result
