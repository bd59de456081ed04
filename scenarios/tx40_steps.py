"""The stages of the TX40 study (scenario kind ``tx40``), one function each, on a shared :class:`Study` record.

:func:`scenarios.kinds.tx40.run_tx40` calls them in order: :func:`load` (the log, the URDF robot, its base
parameters and their prior), :func:`process_log` (the paper's processing of the identification and held-out
parts), :func:`fit_wls`, :func:`consistent_bounds` (minimum consistent bounds, the joint-shaped bound, the
richer friction law, the residual spectrum), :func:`hull_boxes` (hull boxes at ``factors`` times that bound and
their held-out interval envelopes), :func:`polytope_envelope` (the envelope over the feasible set itself on some
held-out rows), :func:`relaxed` (the q-relaxed hull) and :func:`result_dict` (the JSON-ready result).
Each stage reads the fields earlier stages set on the record and adds its own; ``study.seconds`` collects
each stage's wall time [s].

Units: torques and bounds in N m (joint side); a "processed-row" bound is the bound on ``|y - W theta|`` of a
filtered, decimated row, a "raw" bound that of a logged sample (processed = raw x the filter's gain
``||h||_1``); times in s.
"""

from __future__ import annotations

import dataclasses
import time
from types import SimpleNamespace

import numpy as np

__all__ = ["N_JOINTS", "Study", "consistent_bounds", "fit_wls", "hull_boxes", "jsonable", "load", "per_joint",
           "polytope_envelope", "process_log", "relaxed", "result_dict", "rms", "select_columns", "spectrum"]

N_JOINTS = 6  # the TX40's actuated joints


class Study(SimpleNamespace):
    """The record the stages fill: ``cfg`` (the ``[tx40]`` spec section), ``seed``, ``seconds`` (stage -> wall
    time [s]) and what each stage adds (its docstring lists the fields)."""


def select_columns(eq, cols):
    """The equation restricted to some columns (the rounding term, computed for all columns, stays: outer).

    Parameters
    ----------
    eq : the processed equation (:func:`ident.robots.serial.process`)
    cols : (c,) column indices

    Returns
    -------
    The equation with ``W`` (N, c) and the names of those columns; everything else unchanged.
    """
    return dataclasses.replace(eq, W=eq.W[:, cols], names=tuple(eq.names[c] for c in cols), info=dict(eq.info))


def per_joint(x, joint, fn, nj: int = N_JOINTS) -> list[float]:
    """``fn`` of the entries of ``x`` per joint.

    Parameters
    ----------
    x : (N,) values; joint : (N,) their joints, 0-based; fn : callable on a 1-D array -> number;
    nj : number of joints

    Returns
    -------
    (nj,) list of floats, NaN for a joint with no entry.
    """
    return [float(fn(x[joint == j])) if np.any(joint == j) else float("nan") for j in range(nj)]


def rms(x):
    """Root mean square of ``x`` (array-like; the result in x's units)."""
    return np.sqrt(np.mean(np.square(x)))


def spectrum(raw: dict, theta: np.ndarray, r: int, dt: float, band, pass_hz: float, taps) -> dict:
    """Residual spectrum of the unfiltered rows at theta (WLS): per joint the noise floor (median PSD in
    ``band`` [Hz]), the in-band (below ``pass_hz``) mean PSD and their ratio, and the white-noise RMS the
    parallel filter lets into a processed row, ``sqrt(S fs/2) ||h||_2`` [N m].

    Parameters
    ----------
    raw : ``{"W": (n, 6, c), "y": (n, 6)}`` the unfiltered regressor and torques [N m]
    theta : (r,) parameters of the first r columns; r : int
    dt : sample step [s]; band : (2,) [Hz]; pass_hz : [Hz]; taps : (L,) the parallel filter's FIR taps

    Returns
    -------
    dict of ``freq`` (F,) [Hz], ``psd`` (F, 6) [N^2 m^2 / Hz] and per joint (6,): ``floor``, ``inband``, ``ratio``,
    ``white_rms_processed`` [N m], ``raw_rms`` [N m].
    """
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


def load(cfg: dict, seed: int) -> Study:
    """The log (its first ``samples``, 0: all), the robot and its base parameters (QR on ``base_samples`` random
    states drawn from ``seed``), the base-parameter prior ``blo, bhi`` (the standard prior mapped exactly) and
    the richer friction law's prior ``flo, fhi``; ``t_abs`` bounds |theta| of every column (for the rounding).

    Parameters
    ----------
    cfg : the ``[tx40]`` spec section; seed : int

    Returns
    -------
    A new :class:`Study` with ``log``, ``n``, ``q``, ``tau``, ``robot``, ``base``, ``r``, ``blo``, ``bhi``,
    ``flo``, ``fhi``, ``t_abs`` and ``seconds["base_parameters"]``.
    """
    from h4bench.ident.robots import tx40

    s = Study(cfg=cfg, seed=seed, seconds={})
    s.log = tx40.load_log()
    s.n = s.log.q.shape[0] if not cfg["samples"] else min(int(cfg["samples"]), s.log.q.shape[0])
    s.q, s.tau = s.log.q[:s.n], s.log.tau[:s.n]
    s.robot = tx40.robot()
    t0 = time.perf_counter()
    s.base = s.robot.base(int(cfg["base_samples"]), seed)
    s.r = len(s.base)
    lo_s, hi_s = tx40.standard_prior(s.robot)
    s.blo, s.bhi = s.base.box_from_standard(lo_s, hi_s)
    s.flo, s.fhi = tx40.rich_friction_prior(s.robot)
    s.t_abs = np.maximum(np.abs(np.r_[s.blo, s.flo]), np.abs(np.r_[s.bhi, s.fhi]))
    s.seconds["base_parameters"] = time.perf_counter() - t0
    return s


def process_log(s: Study) -> None:
    """The first ``identify_fraction`` of the log identifies (``eq``, ``eq_rich`` with the richer friction
    columns, ``raw``: its unfiltered rows), the rest validates (``eq_ho``, ``eq_ho_rich``; processed separately,
    no sample shared); sets ``n1`` (identification samples), ``prior`` (a Box), ``gain`` (||h||_1), ``taps``.

    Parameters
    ----------
    s : :class:`Study`, filled by the earlier stages; this stage sets the fields above on it (returns None).
    """
    from h4bench import ident
    from h4bench.ident.processing.filtering import decimation_fir
    from h4bench.ident.robots.serial import process

    cfg = s.cfg
    t0 = time.perf_counter()
    s.n1 = round(cfg["identify_fraction"] * s.n)
    kw = {"cutoff_hz": cfg["cutoff_hz"], "decimation": int(cfg["decimation"]), "numtaps": int(cfg["numtaps"]) or None,
          "fir_cutoff": cfg["fir_cutoff"], "speed_threshold": cfg["speed_threshold"], "theta_abs_max": s.t_abs,
          "butter_order": int(cfg["butter_order"]), "rich_friction": cfg["stribeck_velocity"],
          "torque_timing": "sample"}  # the regressor at the sampling instants (a measured torque log)
    s.eq_rich = process(s.robot, s.base, s.q[:s.n1], s.tau[:s.n1], s.log.dt, keep_raw=True, **kw)
    s.eq_ho_rich = process(s.robot, s.base, s.q[s.n1:], s.tau[s.n1:], s.log.dt, first_sample=s.n1, **kw)
    s.raw = s.eq_rich.info.pop("raw")
    s.eq, s.eq_ho = select_columns(s.eq_rich, np.arange(s.r)), select_columns(s.eq_ho_rich, np.arange(s.r))
    s.prior = ident.Box(s.blo, s.bhi, names=s.base.names)
    s.gain = s.eq.gain
    s.taps = decimation_fir(int(cfg["decimation"]), int(cfg["numtaps"]) or None, cfg["fir_cutoff"])
    s.seconds["processing"] = time.perf_counter() - t0


def fit_wls(s: Study) -> None:
    """Gautier's per-joint WLS (``w``: :class:`ident.WLSResult`) and its residuals ``res_id``, ``res_ho`` [N m].

    Parameters
    ----------
    s : :class:`Study`, filled by the earlier stages; this stage sets the fields above on it (returns None).
    """
    from h4bench import ident

    t0 = time.perf_counter()
    s.w = ident.wls(s.eq.W, s.eq.y, joints=N_JOINTS, names=s.base.names, joint_of_row=s.eq.joint)
    s.res_id = s.eq.y - s.eq.W @ s.w.theta
    s.res_ho = s.eq_ho.y - s.eq_ho.W @ s.w.theta
    s.seconds["wls"] = time.perf_counter() - t0


def consistent_bounds(s: Study) -> None:
    """Minimum consistent bounds: ``t_all`` (all rows), ``t_j`` (6,) (each joint alone), ``scale`` and the
    joint-shaped processed-row bound ``b_joint = scale t_j`` (the smallest common scale that makes all rows
    consistent); the same with the richer friction law (``t_all_rich``, ``t_j_rich``, ``w_rich``,
    ``res_ho_rich``); ``pass_hz`` and the residual spectrum ``spec`` (:func:`spectrum`).

    Parameters
    ----------
    s : :class:`Study`, filled by the earlier stages; this stage sets the fields above on it (returns None).
    """
    from h4bench import ident
    from h4bench.ident.estimators import min_consistent_scale

    eq, eq_rich, prior = s.eq, s.eq_rich, s.prior
    t0 = time.perf_counter()
    s.t_all = ident.min_consistent_bound(eq.W, eq.y, prior)
    s.t_j = np.array(per_joint(np.arange(len(eq)), eq.joint,
                               lambda rows: ident.min_consistent_bound(eq.W[rows], eq.y[rows], prior)))
    s.scale = min_consistent_scale(eq.W, eq.y, s.t_j[eq.joint], (s.blo, s.bhi))
    s.b_joint = s.scale * s.t_j  # processed-row bound per joint that makes all identification rows consistent
    rich_prior = (np.r_[s.blo, s.flo], np.r_[s.bhi, s.fhi])
    s.t_all_rich = ident.min_consistent_bound(eq_rich.W, eq_rich.y, rich_prior)
    s.t_j_rich = np.array(per_joint(np.arange(len(eq)), eq.joint,
                                    lambda rows: ident.min_consistent_bound(eq_rich.W[rows], eq_rich.y[rows],
                                                                            rich_prior)))
    s.w_rich = ident.wls(eq_rich.W, eq_rich.y, joints=N_JOINTS, names=eq_rich.names, joint_of_row=eq_rich.joint)
    s.res_ho_rich = s.eq_ho_rich.y - s.eq_ho_rich.W @ s.w_rich.theta
    s.pass_hz = s.cfg["fir_cutoff"] * 0.5 / (s.log.dt * s.cfg["decimation"])
    s.spec = spectrum(s.raw, s.w.theta, s.r, s.log.dt, s.cfg["noise_band_hz"], s.pass_hz, s.taps)
    s.seconds["min_consistent_bound"] = time.perf_counter() - t0


def _box_entry(s: Study, k: float, box, t0: float) -> tuple[dict, tuple]:
    """The result entry of the hull box at ``k`` x the bound, its held-out interval envelope (rigorous, exact for
    a linear function over a box) widened by the bound, and that envelope's arrays ``(lower, upper, bound)``."""
    from h4bench.ident.estimators.residuals import box_envelope, covered

    eq_ho = s.eq_ho
    lo_e, hi_e = box_envelope(eq_ho.W, box.lower, box.upper)
    b_ho = eq_ho.bound(k * s.b_joint / s.gain)
    inside_model = covered(eq_ho.y, lo_e, hi_e, 0.0)
    inside = covered(eq_ho.y, lo_e, hi_e, b_ho)  # the widened envelope rounded outward
    excess = np.maximum(0.0, np.maximum(lo_e - b_ho - eq_ho.y, eq_ho.y - hi_e - b_ho))
    entry = {
        "status": "ok", "factor": k, "lower": box.lower.tolist(), "upper": box.upper.tolist(),
        "width": box.width.tolist(), "relative_width_to_prior": (box.width / (s.bhi - s.blo)).tolist(),
        "wls_inside": bool(box.contains(s.w.theta).all()),
        "seconds": time.perf_counter() - t0,
        "bound_processed_per_joint": (k * s.b_joint).tolist(),
        "bound_raw_per_joint": (k * s.b_joint / s.gain).tolist(),
        "heldout_coverage": float(np.mean(inside)),
        "heldout_coverage_per_joint": per_joint(inside, eq_ho.joint, np.mean),
        "heldout_coverage_model_envelope": float(np.mean(inside_model)),
        "heldout_envelope_halfwidth_mean_per_joint": per_joint(0.5 * (hi_e - lo_e), eq_ho.joint, np.mean),
        "heldout_max_excess_per_joint": per_joint(excess, eq_ho.joint, np.max),
        "info": {kk: box.info.get(kk) for kk in ("cond", "nonempty_proven", "lp_solves", "working_rows")},
    }
    return entry, (lo_e, hi_e, b_ho)


def hull_boxes(s: Study) -> None:
    """Hull boxes (:func:`ident.estimate`) at each of ``factors`` x the joint-shaped bound: ``methods`` (name ->
    result entry; ``hull_<k>x``), ``boxes`` (name -> (k, Box)) and ``envelope`` (the arrays of the box at
    ``envelope_factor``, else of the first consistent one; None if none).

    Parameters
    ----------
    s : :class:`Study`, filled by the earlier stages; this stage sets the fields above on it (returns None).
    """
    from h4bench import ident

    s.methods, s.boxes, s.envelope = {}, {}, None
    for k in s.cfg["factors"]:
        name = f"hull_{k:g}x"
        t0 = time.perf_counter()
        b = s.eq.bound(k * s.b_joint / s.gain)
        try:
            box = ident.estimate(s.eq.W, s.eq.y, b, s.prior, method="hull")
        except ident.InconsistentDataError as exc:
            s.methods[name] = {"status": "inconsistent", "message": str(exc), "seconds": time.perf_counter() - t0}
            continue
        s.boxes[name] = (k, box)
        s.methods[name], (lo_e, hi_e, b_ho) = _box_entry(s, k, box, t0)
        if s.envelope is None or k == s.cfg["envelope_factor"]:
            s.envelope = {"factor": k, "lower": lo_e, "upper": hi_e, "bound": b_ho, "name": name}
    s.seconds["hulls"] = sum(m["seconds"] for m in s.methods.values())


def polytope_envelope(s: Study) -> None:
    """The envelope over the feasible polytope itself (safe LP bounds, :func:`ident.robots.serial.
    prediction_envelope`) on every ``envelope_stride``-th held-out row per joint, for the box of ``envelope``:
    adds ``rows``, ``poly_lower``, ``poly_upper`` to ``envelope`` and ``heldout_polytope_envelope`` to its
    method's entry. Nothing without a consistent box.

    Parameters
    ----------
    s : :class:`Study`, filled by the earlier stages; this stage sets the fields above on it (returns None).
    """
    from h4bench.ident.robots.serial import prediction_envelope

    if s.envelope is None:
        return
    eq, eq_ho, envelope = s.eq, s.eq_ho, s.envelope
    t0 = time.perf_counter()
    k, box = s.boxes[envelope["name"]]
    stride = max(1, int(s.cfg["envelope_stride"]))
    rows = np.concatenate([np.flatnonzero(eq_ho.joint == j)[::stride] for j in range(N_JOINTS)])
    lo_p, hi_p, pinfo = prediction_envelope(eq.W, eq.y, eq.bound(k * s.b_joint / s.gain), box.lower, box.upper,
                                            eq_ho.W[rows], center=s.w.theta)
    yb, bb = eq_ho.y[rows], envelope["bound"][rows]
    inside = (yb >= lo_p - bb) & (yb <= hi_p + bb)
    inside_model = (yb >= lo_p) & (yb <= hi_p)
    pred = eq_ho.W[rows] @ s.w.theta
    envelope.update({"rows": rows, "poly_lower": lo_p, "poly_upper": hi_p})
    s.methods[envelope["name"]]["heldout_polytope_envelope"] = {
        "rows": int(rows.size), "stride": stride, "coverage": float(np.mean(inside)),
        "coverage_per_joint": per_joint(inside, eq_ho.joint[rows], np.mean),
        "coverage_model_envelope": float(np.mean(inside_model)),
        "halfwidth_mean_per_joint": per_joint(0.5 * (hi_p - lo_p), eq_ho.joint[rows], np.mean),
        "wls_prediction_inside": float(np.mean((pred >= lo_p) & (pred <= hi_p))),
        "max_excess_per_joint": per_joint(np.maximum(0.0, np.maximum(lo_p - bb - yb, yb - hi_p - bb)),
                                          eq_ho.joint[rows], np.max),
        "lp_solves": pinfo["lp_solves"], "lp_failures": pinfo["lp_failures"],
        "seconds": time.perf_counter() - t0}
    s.seconds["polytope_envelope"] = time.perf_counter() - t0


def relaxed(s: Study) -> None:
    """The q-relaxed hull (:func:`ident.relaxed_hull`) at ``outlier_factor`` (< 1) x the bound: ``relaxed`` (the
    result entry: the box, the rows proven outliers whatever theta in it, the suspected rows).

    Parameters
    ----------
    s : :class:`Study`, filled by the earlier stages; this stage sets the fields above on it (returns None).
    """
    from h4bench import ident
    from h4bench.ident.estimators.outliers import OutlierBudgetError

    eq, cfg = s.eq, s.cfg
    t0 = time.perf_counter()
    kq, qq = cfg["outlier_factor"], int(cfg["outlier_q"])
    b = eq.bound(kq * s.b_joint / s.gain)
    out = {"factor": kq, "q": qq, "groups": qq + 1}
    try:
        rbox = ident.relaxed_hull(eq.W, eq.y, b, s.prior, qq, method=cfg["relaxed_method"], groups=(qq + 1,))
        certain = np.asarray(rbox.info["certain_rows"], dtype=int)
        out.update({
            "status": "ok", "lower": rbox.lower.tolist(), "upper": rbox.upper.tolist(),
            "certain_rows": certain.tolist(), "suspected_rows": rbox.info["suspected_rows"],
            "certain": [{"row": int(i), "joint": int(eq.joint[i]) + 1, "sample": int(eq.sample[i]),
                         "time": float(eq.sample[i] * s.log.dt), "wls_residual": float(s.res_id[i]),
                         "bound": float(b[i])} for i in certain],
            "exact": bool(rbox.info["exact"])})
    except OutlierBudgetError as exc:
        out.update({"status": "budget exceeded", "message": str(exc), "certain_rows": list(exc.certain_rows)})
    out["rows_over_bound_at_wls"] = int(np.sum(np.abs(s.res_id) > kq * s.b_joint[eq.joint]))
    out["wls_max_scaled_residual"] = float(np.max(np.abs(s.res_id) / s.b_joint[eq.joint]))
    out["seconds"] = time.perf_counter() - t0
    s.relaxed = out
    s.seconds["relaxed"] = out["seconds"]


def _wls_entry(s: Study) -> dict:
    eq, eq_ho = s.eq, s.eq_ho
    return {**s.w.to_dict(), "identify_rms_per_joint": per_joint(s.res_id, eq.joint, rms),
            "heldout_rms_per_joint": per_joint(s.res_ho, eq_ho.joint, rms),
            "heldout_rms": float(rms(s.res_ho)),
            "heldout_torque_rms_per_joint": per_joint(eq_ho.y, eq_ho.joint, rms),
            "heldout_max_abs_error_per_joint": per_joint(np.abs(s.res_ho), eq_ho.joint, np.max),
            "heldout_rms_per_joint_rich_friction": per_joint(s.res_ho_rich, s.eq_ho_rich.joint, rms)}


def _friction_vs_noise(s: Study) -> dict:
    spec = s.spec
    noise_share = np.clip(spec["white_rms_processed"] ** 2 / np.array(per_joint(s.res_id, s.eq.joint, rms)) ** 2,
                          0, 1)
    return {
        "residual_psd_floor_per_joint": spec["floor"].tolist(),
        "residual_psd_inband_per_joint": spec["inband"].tolist(),
        "inband_over_floor": spec["ratio"].tolist(),
        "white_noise_rms_processed_per_joint": spec["white_rms_processed"].tolist(),
        "noise_share_of_processed_residual_variance": noise_share.tolist(),
        "raw_residual_rms_per_joint": spec["raw_rms"].tolist(),
        "passband_hz": s.pass_hz, "noise_band_hz": list(s.cfg["noise_band_hz"]),
        "min_bound_reduction_rich_friction_per_joint": (1.0 - s.t_j_rich / s.t_j).tolist()}


def result_dict(s: Study, seconds_total: dict) -> dict:
    """The JSON-ready result of the study (the schema is in ``docs/results.md``).

    Parameters
    ----------
    s : the study after every stage
    seconds_total : ``{"total": ..., "cpu_total": ...}`` [s], added to the stages' times

    Returns
    -------
    dict of plain Python values (:func:`jsonable`).
    """
    eq, b_joint = s.eq, s.b_joint
    result = {
        "scenario": "tx40", "seed": int(s.seed), "robot": "Staubli TX40 (real log, data/tx40)",
        "parameters": list(s.base.names), "parameter_expressions": list(s.base.expressions),
        "parameter_units": list(s.base.units), "true": None, "oracle_residual": None,
        "bound": b_joint.tolist(),  # joint-shaped processed-row bound at 1x [N m]; boxes use factors x it
        "bound_info": {"kind": "joint-shaped, processed rows [N m]", "per_joint_at_1x": b_joint.tolist(),
                       "raw_per_joint_at_1x": (b_joint / s.gain).tolist(), "factors": list(s.cfg["factors"]),
                       "filter_l1_norm": s.gain, "rounding_max": float(eq.rounding.max())},
        "min_consistent_bound": float(s.t_all),
        "min_consistent_bound_per_joint": s.t_j.tolist(),
        "joint_shape_scale": s.scale,
        "min_consistent_bound_rich_friction": float(s.t_all_rich),
        "min_consistent_bound_per_joint_rich_friction": s.t_j_rich.tolist(),
        "prior": {"lower": s.blo.tolist(), "upper": s.bhi.tolist(),
                  "source": "h4bench.ident.robots.tx40.standard_prior mapped by B"},
        "data": {"samples": int(s.n), "identify_samples": int(s.n1), "heldout_samples": int(s.n - s.n1),
                 "rows_identify": len(eq), "rows_heldout": len(s.eq_ho), "dt": s.log.dt, **{
                     k: v for k, v in eq.info.items() if isinstance(v, (int, float, bool))}},
        "wls": _wls_entry(s),
        "friction_vs_noise": _friction_vs_noise(s),
        "methods": s.methods,
        "relaxed": s.relaxed,
        "base_parameters": {"count": s.r, "standard_count": s.robot.n_parameters,
                            "singular_gap": s.base.singular_gap},
        "seconds": {**s.seconds, **seconds_total},
    }
    return jsonable(result)


def jsonable(x):
    """numpy scalars and arrays inside dicts and lists -> Python floats, ints, bools and lists."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    return x
