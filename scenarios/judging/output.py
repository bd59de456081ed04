"""Tables and plots of the judged methods (a room of :mod:`scenarios.judging`)."""

from __future__ import annotations

import numpy as np

__all__ = ["judged_table", "plot_coverage"]


def _g(v) -> str:
    return "-" if v is None else f"{v:.3g}"


def judged_table(methods: dict, campaign: bool = False) -> str:
    """The side-by-side table (markdown): one row per method. ``campaign``: coverage [CI], level, unsound runs,
    median width vs hull (median over the parameters of the per-parameter medians), median seconds; else the
    status, enclosed, unsound (narrower_than_hull), width vs hull (median, max over the parameters), seconds."""
    if campaign:
        lines = ["| method | kind | rigorous | coverage [95 % CI] | level | misses | unsound runs | "
                 "median width vs hull | median s |", "|---|---|---|---|---:|---:|---:|---:|---:|"]
        for name, m in methods.items():
            w = [v for v in m.get("width_vs_hull_median") or [] if v is not None]
            ci = m.get("coverage_ci") or [None, None]
            cov = "-" if m.get("coverage") is None else f"{m['coverage']:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]"
            lines.append(f"| {name} | {m.get('kind')} | {m.get('rigorous')} | {cov} | {_g(m.get('level'))} | "
                         f"{m['misses']} | {m.get('unsound_runs', '-')} | {_g(float(np.median(w)) if w else None)} | "
                         f"{_g(m.get('seconds'))} |")
        return "\n".join(lines)
    lines = ["| method | kind | rigorous | status | encloses truth | unsound (narrower than hull) | "
             "width vs hull median / min | seconds |", "|---|---|---|---|---|---|---:|---:|"]
    for name, m in methods.items():
        w = [v for v in m.get("width_vs_hull") or [] if v is not None]
        wtxt = f"{np.median(w):.3g} / {min(w):.3g}" if w else "-"
        uns = "-" if m.get("unsound") is None else (
            f"**yes** {', '.join(m['narrower_than_hull'])}" if m["unsound"] else "no")
        enc = "-" if m.get("all_enclosed") is None or m.get("status") != "ok" else (
            "yes" if m["all_enclosed"] else "**no**")
        lines.append(f"| {name} | {m.get('kind')} | {m.get('rigorous')} | {m['status']} | {enc} | {uns} | {wtxt} | "
                     f"{_g(m.get('seconds'))} |")
    return "\n".join(lines)


def plot_coverage(methods: dict, path) -> None:
    """``coverage.png``: per method its coverage with the Clopper-Pearson interval against the median (over the
    parameters) of its median width vs hull, log x; a statistical method's stated level as a marker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    colours = plt.get_cmap("tab20").colors
    for i, (name, m) in enumerate(methods.items()):
        w = [v for v in m.get("width_vs_hull_median") or [] if v is not None and v > 0]
        if not w or m.get("coverage") is None:
            continue
        x = float(np.median(w))
        lo, hi = m["coverage_ci"]
        c = m["coverage"]
        ax.errorbar([x], [c], yerr=[[c - lo], [hi - c]], fmt="o" if m.get("kind") == "guaranteed" else "s",
                    capsize=4, color=colours[(2 * i) % 20 if i < 10 else (2 * i + 1) % 20],
                    label=f"{name} ({m.get('kind')})")
        if m.get("level") is not None:
            ax.plot([x], [m["level"]], "k_", markersize=14)
    ax.set_xscale("log")
    ax.set_xlabel("median width / exact hull width (median over parameters)")
    ax.set_ylabel("coverage (runs enclosing the truth), 95 % CI")
    ax.set_ylim(-0.05, 1.05)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("coverage against width (black bar: a statistical method's stated level)", y=1.0)
    fig.subplots_adjust(left=0.8 / 8, right=1.0 - 0.2 / 8, bottom=0.6 / 5, top=1.0 - 0.4 / 5)  # inches (no tight_layout)
    fig.savefig(path, dpi=110)
    plt.close(fig)
