"""Reports of scenario runs: Markdown tables in the form of the paper's Tables 1 and 2, and PNG plots.

matplotlib is imported lazily, inside the plotting functions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from h4bench.scenarios.judging import judged_table

# The paper's Table 1 (CGSP boxes on the real H4) and Table 2 (WLS, %sigma): Poignet, Ramdani & Vivas,
# CDC 2003, section 4.2. Fc there is Fs here.
PAPER_TABLE1 = {
    "Imot1": (0.0009, 0.0238), "Imot2": (0.0044, 0.0257), "Imot3": (0.0096, 0.0320), "Imot4": (0.0098, 0.0319),
    "Mnac": (0.7650, 1.2338), "Ibc": (0.0000, 0.0071), "Fv1": (0.0000, 0.4690), "Fv2": (0.1733, 0.2554),
    "Fv3": (0.0000, 0.2856), "Fv4": (0.0000, 0.2664), "Fs1": (0.0000, 1.6068), "Fs2": (0.0000, 1.6300),
    "Fs3": (0.2245, 1.0952), "Fs4": (0.2264, 1.1014),
}
PAPER_TABLE2 = {
    "Imot1": (0.0141, 2.6286), "Imot2": (0.0120, 3.0444), "Imot3": (0.0153, 1.6939), "Imot4": (0.0213, 1.1933),
    "Mnac": (1.0492, 0.4236), "Ibc": (0.0030, 3.5049), "Fv1": (0.1636, 5.6781), "Fv2": (0.0560, 15.5674),
    "Fv3": (0.0930, 6.5734), "Fv4": (0.0917, 6.4301), "Fs1": (1.1453, 2.0450), "Fs2": (1.0950, 2.0563),
    "Fs3": (0.7222, 2.8366), "Fs4": (0.9932, 2.0451),
}


def _fmt(v: float) -> str:
    return f"{v:.4g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.3e}"


def _box_cell(m: dict, j: int) -> str:
    return f"[{_fmt(m['lower'][j])}, {_fmt(m['upper'][j])}]"


def table1(result: dict) -> str:
    """Boxes beside the truth: one row per parameter, hull and cgsp side by side, widths and their ratio."""
    names, true = result["parameters"], result["true"]
    methods = {k: v for k, v in result["methods"].items() if v.get("status") == "ok"}
    head = ["parameter", "true"]
    for k in methods:
        head += [f"{k} box", f"{k} width", f"{k} encl."]
    if "hull" in methods and "cgsp" in methods:
        head.append("cgsp/hull width")
    head.append("paper Table 1")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for j, name in enumerate(names):
        row = [f"`{name}`", _fmt(true[j])]
        for m in methods.values():
            row += [_box_cell(m, j), _fmt(m["width"][j]), "yes" if m["enclosed"][j] else "**NO**"]
        if "hull" in methods and "cgsp" in methods:
            hw, cw = methods["hull"]["width"][j], methods["cgsp"]["width"][j]
            row.append(f"{cw / hw:.3g}" if hw > 0 else "inf")
        paper = PAPER_TABLE1.get(name)
        row.append(f"[{paper[0]}, {paper[1]}]" if paper else "-")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def table2(result: dict) -> str:
    """Weighted least squares with %sigma beside the truth and the paper's Table 2."""
    if "wls" not in result:
        return "(no WLS)"
    names, true, w = result["parameters"], result["true"], result["wls"]
    lines = ["| parameter | true | WLS | error % | %sigma | paper WLS | paper %sigma |", "|---|---|---|---|---|---|---|"]
    for j, name in enumerate(names):
        paper = PAPER_TABLE2.get(name, ("-", "-"))
        err = 100 * (w["theta"][j] - true[j]) / true[j] if true[j] else float("nan")
        lines.append(f"| `{name}` | {_fmt(true[j])} | {_fmt(w['theta'][j])} | {err:+.2f} | "
                     f"{w['rel_std_percent'][j]:.3g} | {paper[0]} | {paper[1]} |")
    return "\n".join(lines)


def budget_table(result: dict) -> str:
    b = result.get("budget") or {}
    if not b:
        return "(no budget)"
    lines = ["| part | raw max [N m] | raw p99 | processed max | processed p99 |", "|---|---|---|---|---|"]
    for part in ("noise", "derivatives", "model"):
        r, p = b["raw"][part], b["processed"][part]
        lines.append(f"| {part} | {r['max']:.4g} | {r['p99']:.4g} | {p['max']:.4g} | {p['p99']:.4g} |")
    lines.append(f"| **total** | {b['total_raw_max']:.4g} | | {b['total_processed_max']:.4g} | |")
    parts = result.get("bound_parts")
    if parts:
        used = b["processed"]["derivatives"]["max"] + b["processed"]["model"]["max"]
        budget = parts["allowance"] * result.get("filter_l1_norm", 1.0)
        lines += ["", f"Allowance check: derivatives + model after processing take at most {used:.4g} N m of the "
                  f"allowance {parts['allowance']:.4g} x ||h||_1 = {budget:.4g} N m: "
                  + ("covered." if used <= budget else "**exceeded**: the allowance is too small for this run."),
                  "The raw rows' derivative error is larger; the parallel filter smooths it (its purpose in the "
                  "paper), so the allowance is a claim about the processed rows, propagated like the noise bound."]
    return "\n".join(lines)


def width_table(result: dict) -> str:
    """Markdown: per parameter h_j, predicted width 2 (b - rho) h_j (and the upper 2 (b + rho) h_j), the hull's
    width, its relative width and the ratio to the paper's Table 1 relative width."""
    a = result.get("width_analysis")
    if not a:
        return "(no width analysis)"
    lines = [f"Slack b - rho = {a['reference_bound']:.4g} - {a['rho']:.4g} = {a['slack']:.4g} N m "
             "(reference bound minus oracle residual, rows scaled to the reference bound).", "",
             "| parameter | h_j | predicted width 2(b-rho)h_j (prior-cut) | upper 2(b+rho)h_j | slice width | hull width | "
             "relative width | paper relative width | ratio to paper |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    slice_w = a.get("slice_width")
    for j, name in enumerate(result["parameters"]):
        cells = [f"`{name}`", f"{a['h'][j]:.4g}", f"{a['predicted_width'][j]:.4g}", f"{a['predicted_width_upper'][j]:.4g}",
                 f"{slice_w[j]:.4g}" if slice_w is not None else "-"]
        if "width" in a:
            ratio = a["ratio_to_paper"][j]
            cells += [f"{a['width'][j]:.4g}", f"{a['relative_width'][j]:.3g}", f"{a['paper_relative_width'][j]:.3g}",
                      f"{ratio:.3g}" + (" (tighter)" if ratio <= 1 else "")]
        else:
            cells += ["-"] * 4
        lines.append("| " + " | ".join(cells) + " |")
    if a.get("compared"):
        lines += ["", f"Hull at most the paper's relative width on {a['at_most_paper']} of {a['compared']} parameters; "
                  f"geometric mean of the ratios {a['geometric_mean_ratio']:.3g}."]
        if a.get("slice_geometric_mean_ratio") is not None:
            lines += ["", "Slice width: the feasible set through the truth along one parameter, the others fixed to "
                      "their true values; no box from these data is narrower. Slices at most the paper's relative "
                      f"width: {a['slice_at_most_paper']} of {a['compared']}; geometric mean of their ratios "
                      f"{a['slice_geometric_mean_ratio']:.3g} (what the coupling between parameters costs is the "
                      "rest)."]
    return "\n".join(lines)


def summary_lines(result: dict) -> list[str]:
    lines = [
        f"- assumed bound on raw rows: {result['bound']:.4g} N m = injected noise {result['bound_parts']['noise']:.4g} "
        f"+ allowance {result['bound_parts']['allowance']:.4g} (derivatives, model); after the parallel filter "
        f"(||h||_1 = {result['filter_l1_norm']:.4g}): {result['bound_processed']:.4g} N m on {result['rows']} rows",
        f"- oracle residual max|y - W theta_true| = {result['oracle_residual']:.4g} N m "
        f"({'covered' if result['bound_covers_residual'] else '**NOT covered**'} by the bound)",
        f"- min consistent bound (Chebyshev fit over the prior) = {result['min_consistent_bound']:.4g} N m",
    ]
    for name, m in result["methods"].items():
        claims = _claims(m)
        if m.get("status") == "ok":
            lines.append(f"- {name}{claims}: all enclosed = {m['all_enclosed']}, mean width {np.mean(m['width']):.4g}, "
                         f"{m['seconds']:.3g} s{_verdict(m)}")
        else:
            lines.append(f"- {name}{claims}: {m.get('status')}: {m.get('message')}{_verdict(m)}")
    return lines


def _claims(m: dict) -> str:
    if m.get("kind") is None:
        return ""
    level = f", level {m['level']:g}" if m.get("level") is not None else ""
    return f" ({m['kind']}, {'rigorous' if m.get('rigorous') else 'not rigorous'}{level})"


def _verdict(m: dict) -> str:
    """A method's width against the exact hull and, for a guaranteed box, the narrower-than-hull verdict."""
    w = [v for v in m.get("width_vs_hull") or [] if v is not None]
    text = f"; width vs hull median {np.median(w):.3g} (min {min(w):.3g})" if w else ""
    if m.get("unsound"):
        text += f"; **UNSOUND: narrower than the exact hull in {', '.join(m['narrower_than_hull'])}**"
    elif m.get("unsound") is False:
        text += "; not narrower than the hull"
    return text


def hull_tolerance_line(result: dict) -> str:
    """How the narrower-than-hull check's tolerance was obtained on this run (scenarios.judging)."""
    ref = result.get("hull_reference")
    if not ref:
        return "No hull box (the exact hull failed or proved the set empty): no narrower-than-hull check."
    if ref["source"] == "proven points":
        return (f"Narrower-than-hull check: {ref['proven_points']} of the hull's LP points proven feasible (rigorous "
                "residuals); a guaranteed box excluding one of them is unsound (a proof).")
    return (f"Narrower-than-hull check: no hull LP point proven feasible; tolerance {ref['rtol']:g} x the hull's "
            "endpoint magnitudes (a flag there is not a proof).")


def heading(result: dict, what: str = "") -> str:
    """The first line of a run's report: ``# Scenario `name`: what (seed S, quick)``."""
    quick = ", quick" if result.get("quick") else ""
    return f"# Scenario `{result['scenario']}`{': ' + what if what else ''} (seed {result['seed']}{quick})"


def write_paper_report(result: dict, out: Path, extra: str = "") -> None:
    from h4bench.sim.dataset import atomic_write_bytes

    text = "\n".join([
        heading(result), "",
        *summary_lines(result), "",
        "## Every method side by side (the exact hull as reference)", "", judged_table(result["methods"]), "",
        hull_tolerance_line(result), "",
        "## Table 1: guaranteed boxes (prior [" + f"{result['prior']['lower'][0]}, {result['prior']['upper'][0]}])",
        "", table1(result), "", "## Table 2: weighted least squares", "", table2(result), "",
        "## Why the boxes are this wide (slack x geometry)", "", width_table(result), "",
        "## Error budget (oracle residual split by source)", "", budget_table(result), "",
        "Plots: `boxes.png` (boxes against the truth).", "", extra,
    ])
    atomic_write_bytes(out / "report.md", text.encode())


def hull_verdict(result: dict) -> str:
    """What the plain hull did on a run built to make it fail (proven empty, a miss, or enclosed)."""
    m = result["methods"]["hull"]
    if m["status"] != "ok":
        return "fails: the feasible set is proven empty (InconsistentDataError)"
    if not m["all_enclosed"]:
        missed = [n for n, e in zip(result["parameters"], m["enclosed"]) if not e]
        return f"fails: its box misses the true value of {missed}"
    return "encloses the truth (the failure this scenario is built to show did not happen)"


def relative_width_table(result: dict) -> str:
    """Markdown table: median (and p90) relative width per parameter and method of a campaign result."""
    methods = {k: m for k, m in result["methods"].items() if m.get("relative_width_median")}
    head = "| parameter | " + " | ".join(f"{k} median | {k} p90" for k in methods) + " |"
    sep = "|---|" + "---:|---:|" * len(methods)
    rows = [head, sep]
    for j, name in enumerate(result["parameters"]):
        cells = [f"{m['relative_width_median'][j]:.3g} | {m['relative_width_p90'][j]:.3g}" for m in methods.values()]
        rows.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def plot_beside_plain_hull(result: dict, out: Path, what: str, shown: dict | None = None) -> None:
    """``boxes.png`` of a scenario built to make the plain hull fail: ``what`` (the method that should hold)
    and the plain hull's status in the title; ``shown`` replaces the methods drawn (e.g. with a reference box)."""
    plot_boxes({**result, "methods": shown if shown is not None else result["methods"]}, out / "boxes.png",
               title=f"{result['scenario']}: {what}; plain hull: {result['methods']['hull']['status']}")


def plot_boxes(result: dict, path: Path, title: str | None = None) -> None:
    """One row per parameter: each method's box divided by the true value, the truth at 1."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, true = result["parameters"], np.asarray(result["true"])
    methods = {k: v for k, v in result["methods"].items() if v.get("status") == "ok"}
    colours = {"hull": "tab:blue", "cgsp": "tab:orange", "relaxed": "tab:green", "interval": "tab:purple"}
    # each row in units of its true value; a parameter whose truth is 0 in units of its prior's upper end
    prior_hi = np.asarray(result.get("prior", {}).get("upper", np.ones_like(true)))
    scale = np.where(true != 0, np.abs(true), np.where(prior_hi > 0, prior_hi, 1.0))
    labels = [n if t != 0 else f"{n} (/prior)" for n, t in zip(names, true)]
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(names) + 1.5))
    y = np.arange(len(names))[::-1]
    offsets = np.linspace(-0.2, 0.2, max(len(methods), 1))
    for (name, m), off in zip(methods.items(), offsets):
        lo, hi = np.asarray(m["lower"]) / scale, np.asarray(m["upper"]) / scale
        ax.hlines(y + off, lo, hi, colors=colours.get(name, "tab:gray"), lw=4, label=name)
    if "wls" in result:
        ax.plot(np.asarray(result["wls"]["theta"]) / scale, y, "k|", ms=12, label="WLS")
    ax.plot(true / scale, y, "d", color="crimson", ms=6, label="truth")
    ax.axvline(1.0, color="crimson", lw=0.8, alpha=0.5)
    ax.set_yticks(y, labels)
    ax.set_xscale("symlog", linthresh=0.1)
    ax.set_xlim(left=0.0)
    ax.set_xlabel("box / true value (symlog); rows marked /prior: box / prior upper bound")
    ax.set_title(title or f"{result['scenario']}: boxes against the truth")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
