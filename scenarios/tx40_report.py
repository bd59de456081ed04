"""The files of a TX40 run (scenario kind ``tx40``): the plots (:func:`plots`) and ``report.md``
(:func:`report_text`), from the result dict and the study's arrays (:func:`scenarios.kinds.tx40.run_tx40`).

Plots: ``boxes.png`` (the hull boxes normalised to the widest, WLS marked), ``envelope.png`` (held-out torques
in the guaranteed envelope over the feasible set, per joint) and ``sweep.png`` (minimum consistent bound per
joint; widths and held-out coverage against the assumed bound). Torques in N m, times in s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plots", "report_text"]


def _ok(result: dict) -> list[dict]:
    return [m for m in result["methods"].values() if m["status"] == "ok"]


def _boxes_plot(plt, result: dict, art: dict, out: Path) -> None:
    names = result["parameters"]
    p = len(names)
    ok = _ok(result)
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


def _envelope_plot(plt, art: dict, out: Path) -> None:
    env, eq_ho = art["envelope"], art["eq_ho"]
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


def _sweep_plot(plt, result: dict, out: Path) -> None:
    ok = _ok(result)
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


def plots(result: dict, art: dict, out: Path) -> None:
    """Write ``boxes.png`` (if a box exists), ``envelope.png`` (if an envelope exists) and ``sweep.png``.

    Parameters
    ----------
    result : the study's result dict (:func:`scenarios.kinds.tx40.run_tx40`)
    art : its arrays (``wls_theta``, ``eq_ho``, ``envelope``, ``dt``)
    out : the folder (a ``pathlib.Path``)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if _ok(result):
        _boxes_plot(plt, result, art, out)
    if art["envelope"] is not None:
        _envelope_plot(plt, art, out)
    _sweep_plot(plt, result, out)


def _fmt(v, d=3):
    return "nan" if v is None or not np.isfinite(v) else f"{v:.{d}g}"


def _row(label, xs, d=3) -> str:
    return f"| {label} | " + " | ".join(_fmt(x, d) for x in xs) + " |"


def _torque_section(result: dict) -> list[str]:
    w, fn = result["wls"], result["friction_vs_noise"]
    data = result["data"]
    return [
        f"# Scenario `tx40`: real Staubli TX40 log (seed {result['seed']})", "",
        (f"{data['samples']} samples at {1 / data['dt']:g} Hz; first "
         f"{data['identify_samples']} identify ({data['rows_identify']} processed rows), the "
         f"other {data['heldout_samples']} validate ({data['rows_heldout']} rows). "
         f"{len(result['parameters'])} base parameters (of {result['base_parameters']['standard_count']} standard). "
         f"Parallel filter ||h||_1 = {result['bound_info']['filter_l1_norm']:.4f}. No truth exists: the bound is "
         "derived from the identification rows (below), the held-out part tests it."), "",
        "## Torques per joint [N m]", "",
        "| | " + " | ".join(f"J{j + 1}" for j in range(6)) + " |", "|---|" + "---|" * 6,
        _row("held-out torque RMS", w["heldout_torque_rms_per_joint"]),
        _row("WLS held-out RMS error", w["heldout_rms_per_joint"]),
        _row("WLS held-out max error", w["heldout_max_abs_error_per_joint"]),
        _row("WLS held-out RMS, richer friction", w["heldout_rms_per_joint_rich_friction"]),
        _row("min consistent bound, joint alone", result["min_consistent_bound_per_joint"]),
        _row("same, richer friction", result["min_consistent_bound_per_joint_rich_friction"]),
        _row("joint-shaped bound (1x)", result["bound"]),
        _row("white-noise RMS in a processed row", fn["white_noise_rms_processed_per_joint"]),
        _row("noise share of residual variance", fn["noise_share_of_processed_residual_variance"], 2),
        _row("residual PSD in band / HF floor", fn["inband_over_floor"], 3), "",
        (f"- WLS held-out RMS error (all joints): {w['heldout_rms']:.4g} N m; min consistent bound over all rows "
         f"{result['min_consistent_bound']:.4g} N m (richer friction "
         f"{result['min_consistent_bound_rich_friction']:.4g}); joint-shaped scale s = "
         f"{result['joint_shape_scale']:.4g}."),
        (f"- Friction-model error against noise: the residual's PSD below {fn['passband_hz']:.3g} Hz (what the "
         f"processed rows keep) is the ratio above times the high-frequency noise floor "
         f"({fn['noise_band_hz'][0]:g}-{fn['noise_band_hz'][1]:g} Hz); white noise at that floor explains the "
         "'noise share' of the processed residual's variance, the rest is model error (friction law, "
         "unmodelled dynamics, derivative estimation). The richer friction law lowers the per-joint minimum by "
         + ", ".join(f"{100 * x:.0f} %" for x in fn["min_bound_reduction_rich_friction_per_joint"]) + "."), "",
    ]


def _polytope_lines(m: dict) -> list[str]:
    pe = m.get("heldout_polytope_envelope")
    if not pe:
        return []
    return ["", f"Envelope over the feasible set itself at {m['factor']:g}x ({pe['rows']} held-out rows, "
            f"every {pe['stride']} per joint, {pe['lp_solves']} LPs with safe bounds, {pe['seconds']:.3g} s): "
            f"coverage {pe['coverage']:.4f} (model envelope alone {pe['coverage_model_envelope']:.4f}); "
            "mean half-width per joint " + ", ".join(_fmt(x) for x in pe["halfwidth_mean_per_joint"])
            + " N m; max excess over envelope + bound per joint "
            + ", ".join(_fmt(x) for x in pe["max_excess_per_joint"]) + " N m. The interval evaluation "
            "over the box (table above) ignores the parameters' correlations: its mean half-widths are "
            + ", ".join(_fmt(x) for x in m["heldout_envelope_halfwidth_mean_per_joint"]) + " N m."]


def _hull_section(result: dict) -> list[str]:
    w = result["wls"]
    lines = ["## Hull boxes and held-out envelope", "",
             ("| bound | status | median width / prior | WLS inside | held-out coverage (envelope + bound) | model "
              "envelope only | seconds |"), "|---|---|---|---|---|---|---|"]
    for name, m in result["methods"].items():
        if m["status"] == "ok":
            lines.append(f"| {m['factor']:g}x | ok | {np.median(m['relative_width_to_prior']):.3g} | "
                         f"{m['wls_inside']} | {m['heldout_coverage']:.4f} | "
                         f"{m['heldout_coverage_model_envelope']:.4f} | {m['seconds']:.3g} |")
        else:
            lines.append(f"| {name} | {m['status']} | | | | | {m['seconds']:.3g} |")
    ok = {n: m for n, m in result["methods"].items() if m["status"] == "ok"}
    for m in ok.values():
        lines += _polytope_lines(m)
    if ok:
        lines += ["", "Box widths per parameter:", "", "| parameter | WLS | %sigma | " + " | ".join(ok) + " |",
                  "|---|---|---|" + "---|" * len(ok)]
        for i, nm in enumerate(result["parameters"]):
            lines.append(f"| {nm} | {w['theta'][i]:.4g} | {w['rel_std_percent'][i]:.3g} | "
                         + " | ".join(f"[{m['lower'][i]:.4g}, {m['upper'][i]:.4g}] ({m['width'][i]:.3g})"
                                      for m in ok.values()) + " |")
    return lines


def _relaxed_section(result: dict) -> list[str]:
    rl = result["relaxed"]
    lines = ["", f"## q-relaxed hull at {rl['factor']:g}x the bound, q = {rl['q']}", ""]
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
    return lines


def report_text(result: dict) -> str:
    """The text of ``report.md`` of a tx40 run.

    Parameters
    ----------
    result : the run's result dict (the schema in ``docs/results.md``)

    Returns
    -------
    str, markdown ending with a newline.
    """
    lines = _torque_section(result) + _hull_section(result) + _relaxed_section(result)
    lines += ["", "## Runtime [s]", "", ", ".join(f"{k} {v:.3g}" for k, v in result["seconds"].items()), "",
              ("Plots: `boxes.png` (boxes normalised to the widest, WLS marked), `envelope.png` (held-out torques "
               "in the guaranteed envelope), `sweep.png` (min consistent bound per joint; widths and coverage "
               "against the assumed bound)."), "",
              "Base parameters (base <- standard):", ""]
    lines += [f"- `{n}` = {e}" for n, e in zip(result["parameters"], result["parameter_expressions"])]
    return "\n".join(lines) + "\n"
