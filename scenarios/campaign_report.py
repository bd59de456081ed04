"""A campaign's reports: the summary over the runs (:func:`summarise`), ``report.md``, ``result.json`` and the
plots (:func:`write_outputs`), the throughput line. The engine that runs the campaign is :mod:`scenarios.campaign`."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from h4bench.scenarios.timings import campaign_timings, timing_lines

__all__ = ["REPORT_IMPORTS", "plot_relative_widths", "summarise", "summarise_methods", "throughput_lines",
           "write_outputs"]

#: What :func:`write_outputs` imports (plots, the Clopper-Pearson quantiles): ``run_many(report_imports=...)``
REPORT_IMPORTS = ("matplotlib.pyplot", "scipy.special")


def write_outputs(result: dict, runs: list[dict], out: Path, title: str, facts: list[str], method_line,
                  tail: list[str] = (), head: list[str] = ()) -> None:
    """A campaign kind's files: ``widths.png`` (relative widths over the runs), ``report.md`` (``head``: the
    kind's verdict lines first, if any; ``# Scenario `name`: title``, the kind's ``facts``, the throughput, one
    line per method from ``method_line(name, m)``, the median relative width table, ``tail``) and
    ``result.json``, atomically each."""
    from h4bench.scenarios.judging import judged_table, plot_coverage
    from h4bench.scenarios.report import relative_width_table
    from h4bench.scenarios.rundir import write_json
    from h4bench.sim.dataset import atomic_write_bytes

    out = Path(out)
    t_report = time.perf_counter()
    plot_relative_widths(result, runs, out / "widths.png")
    plot_coverage(result["methods"], out / "coverage.png")
    info = result["campaign"]
    staged = info.get("timings") or {}
    if "started" in staged:  # the engine's staging dict -> the campaign's timings (docs/results.md)
        workers = 0 if info.get("scheduler") else info["workers"]
        sections = {**staged["sections"], "report": time.perf_counter() - t_report}
        info["timings"] = campaign_timings(runs, staged["computed"], workers, staged["started"], sections)
    lines = [*head, f"# Scenario `{result['scenario']}`: {title}", "", *facts, *throughput_lines(result["campaign"])]
    lines += [f"- {name}: {method_line(name, m)}" for name, m in result["methods"].items()]
    lines += ["", "## Every method side by side", "",
              "Coverage: runs whose box encloses the truth / runs (a run without a box does not cover), with its exact "
              "Clopper-Pearson 95 % interval; level: a statistical method's stated confidence; unsound runs: the "
              "guaranteed box was narrower than the exact hull beyond the hull's tolerance (see "
              "`scenarios/judging/verification.py`); width vs hull: per parameter the median over the runs of width / hull "
              "width, then the median over the parameters.", "", judged_table(result["methods"], campaign=True), "",
              "Plot: `coverage.png` (coverage against median width vs hull, one point per method).", ""]
    failing = {n: m["failure_messages"] for n, m in result["methods"].items() if m.get("failure_messages")}
    for name, msgs in failing.items():
        lines += [f"- {name} failed on {len(result['methods'][name]['failed_runs'])} run(s): {msgs[0]}"]
    if failing:
        lines += [""]
    lines += ["", "## Median relative width (width / |true value|) per parameter", "", relative_width_table(result),
              "", *tail, "Plot: `widths.png`.", *timing_lines(info.get("timings"))]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())
    write_json(out / "result.json", result)


def throughput_lines(info: dict) -> list[str]:
    """The report's line on campaign throughput (none when every run was reused)."""
    if not info["runs_per_minute"]:
        return []
    where = info["scheduler"] or f"{info['workers']} local worker(s)"
    return [f"- throughput: {info['runs_per_minute']:.3g} runs per minute ({info['computed']} runs in "
            f"{info['seconds']:.4g} s on {where})"]


def summarise(spec: dict, seed: int, runs: list[dict], info: dict) -> dict:
    """A campaign's result: the common keys of every result (docs/results.md) over all runs (worst min consistent
    bound and oracle residual), how many runs the bound covered, the per-method summary and the engine's
    ``info``."""
    first = runs[0]
    return {
        "scenario": spec["name"], "kind": spec["kind"], "seed": seed, "quick": spec.get("quick_applied", False),
        "model": first["model"], "parameters": first["parameters"], "true": first["true"],
        "bound": first["bound"], "runs": len(runs),
        "min_consistent_bound": float(max(r["min_consistent_bound"] for r in runs)),
        "oracle_residual": float(max(r["oracle_residual"] for r in runs)),
        "runs_bound_covers_residual": int(sum(r["bound_covers_residual"] for r in runs)),
        "noise_shapes": spec["campaign"]["noise_shapes"], "parameter_spread": spec["campaign"]["parameter_spread"],
        "methods": summarise_methods(runs), "campaign": info,
    }


def summarise_methods(runs: list[dict]) -> dict:
    """Per method over the runs (:func:`scenarios.judging.summarise_methods`): the claims, misses (and those where
    the bound covered the residual), failed runs, unsound runs, coverage with its Clopper-Pearson interval,
    median width vs hull, median and p90 relative widths (width / |true|), median seconds."""
    from h4bench.scenarios.judging import summarise_methods as judged

    return judged(runs)


def plot_relative_widths(result: dict, runs: list[dict], path: Path) -> None:
    """Box plots of the relative widths per parameter and method over the runs (log scale); one panel per method
    with a box in some run (a method without any, e.g. every run failed, is named in the figure's title).

    The panels' margins are fixed in inches (the rotated parameter names below, the title above) rather than
    measured by ``tight_layout``, which drew every panel's text an extra time (over a second with ten methods),
    and each panel's boxes are three artists (:func:`_boxes`) rather than seven per box."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = result["parameters"]
    panels, empty = [], []
    for name, m in result["methods"].items():
        rel = [np.asarray(r["methods"][name]["width"]) / np.abs(np.asarray(r["true"])) for r in runs
               if r["methods"][name].get("status") == "ok"]
        (panels.append((name, m, rel)) if rel else empty.append(name))
    k = max(1, len(panels))
    cols = min(k, 3)
    rows = -(-k // cols)
    width, height = 7.0 * cols, 5.0 * rows
    fig, axes = plt.subplots(rows, cols, figsize=(width, height), squeeze=False)
    fig.subplots_adjust(left=0.6 / width, right=1.0 - 0.15 / width, bottom=0.75 / height,
                        top=1.0 - (0.65 if empty else 0.35) / height, wspace=0.9 / 7.0, hspace=1.1 / 5.0)
    if empty:
        fig.suptitle(f"no box in any run: {', '.join(empty)}", y=1.0 - 0.1 / height, va="top")
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax, (name, m, rel) in zip(axes.flat, panels):
        _boxes(ax, np.array(rel), names)
        ax.set_yscale("log")
        ax.set_title(f"{name}: relative widths over {len(rel)} runs, {m['misses']} miss(es)", y=1.0)  # placed, not searched
        ax.tick_params(axis="x", rotation=60)
        ax.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _boxes(ax, data: np.ndarray, labels: list[str]) -> None:
    """Box plots of the columns of ``data`` (runs, k) at x = 1..k, as ``Axes.boxplot`` draws them (its statistics,
    ``matplotlib.cbook.boxplot_stats``: quartiles, whiskers at 1.5 IQR, fliers), in three artists: the boxes,
    whiskers and caps as one line collection, the medians as another, the fliers as one marker line."""
    from matplotlib import cbook
    from matplotlib.collections import LineCollection

    stats = cbook.boxplot_stats(data)
    segments, medians, fx, fy = [], [], [], []
    for x, st in enumerate(stats, start=1):
        lo, hi = x - 0.25, x + 0.25
        q1, q3 = st["q1"], st["q3"]
        segments += [[(lo, q1), (hi, q1), (hi, q3), (lo, q3), (lo, q1)],  # the box
                     [(x, q1), (x, st["whislo"])], [(x, q3), (x, st["whishi"])],  # whiskers
                     [(x - 0.125, st["whislo"]), (x + 0.125, st["whislo"])],  # caps
                     [(x - 0.125, st["whishi"]), (x + 0.125, st["whishi"])]]
        medians.append([(lo, st["med"]), (hi, st["med"])])
        fx += [x] * len(st["fliers"])
        fy += list(st["fliers"])
    ax.add_collection(LineCollection(segments, colors="black", linewidths=1.0))
    ax.add_collection(LineCollection(medians, colors="C1", linewidths=1.0))
    if fx:
        ax.plot(fx, fy, linestyle="none", marker="o", markerfacecolor="none", markeredgecolor="black")
    ax.set_xlim(0.5, len(stats) + 0.5)
    ax.set_xticks(range(1, len(stats) + 1), labels)
    ax.autoscale_view(scalex=False)
