"""The ``h4bench`` command line's terminal output: numbers in tables, the summary tables fitted to the terminal's
width, the paper's Table 1 beside the boxes, and the progress bar (rich)."""

from __future__ import annotations

import math

__all__ = ["Progress", "num", "print_summary", "summary_tables", "table1"]


def num(x) -> str:
    """A number in at most 9 characters, 4 significant digits: 0.06074, 12.35, 3.770e-4, 0; ``-`` for None,
    ``nan``/``inf``/``-inf`` for non-finite numbers, a text (e.g. a bound named by its rule) as it is."""
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    x = float(x)
    if not math.isfinite(x):
        return str(x)
    if x == 0 or 1e-2 <= abs(x) < 1e4:
        return f"{x:.4g}"
    mant, exp = f"{x:.3e}".split("e")
    return f"{mant}e{int(exp)}"


def summary_tables(result: dict, width: int) -> list:
    """The summary as rich Tables each fitting ``width`` columns: column groups (truth, each method's box,
    WLS) are packed greedily into tables, each repeating the parameter column."""
    from rich import box as rbox
    from rich.measure import Measurement
    from rich.console import Console
    from rich.table import Table

    from rich.markup import escape

    names = [escape(str(n)) for n in result["parameters"]]
    true = result.get("true")
    groups = []  # each: list of (header, cells)
    if true is not None:
        groups.append([("true", [num(v) for v in true])])
    methods = {k: v for k, v in result.get("methods", {}).items() if v.get("status") == "ok" and v.get("lower")}
    for name, m in methods.items():
        cols = [(f"{escape(name)} lower", [num(v) for v in m["lower"]]),
                (f"{escape(name)} upper", [num(v) for v in m["upper"]])]
        enc = m.get("enclosed")
        if enc:
            cols.append(("in", ["yes" if e else "[red]NO[/red]" for e in enc]))
        groups.append(cols)
    if "wls" in result:
        groups.append([("WLS", [num(v) for v in result["wls"]["theta"]]),
                       ("%sigma", [f"{v:.3g}" for v in result["wls"]["rel_std_percent"]])])

    seed = result.get("seed")
    title = escape(str(result["scenario"])) + (f" (seed {seed})" if seed is not None else "")
    probe = Console(width=10_000, file=open(__import__("os").devnull, "w"))

    def make(gs, first):
        table = Table(title=title if first else None, box=rbox.SIMPLE_HEAD, pad_edge=False)
        table.add_column("parameter")
        for g in gs:
            for header, _ in g:
                table.add_column(header, justify="center" if header == "in" else "right", no_wrap=True)
        for j, pname in enumerate(names):
            table.add_row(pname, *[cells[j] for g in gs for _, cells in g])
        return table

    def fits(gs):
        return Measurement.get(probe, probe.options, make(gs, False)).maximum <= width

    tables, current = [], []
    for g in groups:
        if current and not fits(current + [g]):
            tables.append(make(current, not tables))
            current = []
        current.append(g)
    tables.append(make(current, not tables))
    return tables


def print_summary(result: dict) -> None:
    """The result as tables fitting the terminal's width (rich; ``COLUMNS`` forces it), then the bounds."""
    from rich.console import Console

    console = Console(stderr=False)
    for table in summary_tables(result, console.width):
        console.print(table)
    bound = result.get("bound")
    if isinstance(bound, str):  # a bound named by its rule (e.g. the critical bound, per row)
        console.print(f"bound: {bound}", markup=False)
    elif isinstance(bound, list):
        console.print("bound per joint: " + ", ".join(num(b) for b in bound) + " N m")
    elif bound is not None:
        console.print(f"bound: {num(bound)} N m")
    for key in ("bound_processed", "oracle_residual", "min_consistent_bound"):
        if result.get(key) is not None:
            console.print(f"{key}: {num(result[key])} N m")
    for name, m in result.get("methods", {}).items():
        if m.get("status") != "ok" and "runs" not in m:
            console.print(f"{name}: {m['status']}: {m.get('message')}", style="red", markup=False)
        elif "misses" in m:
            cov = "" if m.get("coverage") is None else (
                f"; coverage {m['coverage']:.3g} [{m['coverage_ci'][0]:.3g}, {m['coverage_ci'][1]:.3g}]")
            console.print(f"{name}: {m['misses']} miss(es) in {result['runs']} runs; with the bound covering the "
                          f"residual: {len(m['misses_with_bound_covering_residual'])}; unsound runs "
                          f"{m.get('unsound_runs')}; failed runs {len(m.get('failed_runs', []))}{cov}", markup=False)
        elif m.get("unsound"):
            console.print(f"{name}: UNSOUND: narrower than the exact hull in {', '.join(m['narrower_than_hull'])}",
                          style="red", markup=False)


def table1(result: dict):
    """The paper's Table 1 beside h4bench's box (rich Table, fits 80 columns): parameter, truth, the exact hull's
    box (``in``: it holds the truth; another guaranteed method's when the run has no hull), the paper's box
    (Poignet, Ramdani & Vivas 2003, Table 1, the real H4, as printed there) and the width ratio box / paper
    (``w/paper``);
    None when the run has no box to show."""
    from rich import box as rbox
    from rich.markup import escape
    from rich.table import Table

    from h4bench.scenarios.report import PAPER_TABLE1

    boxes = {k: m for k, m in result.get("methods", {}).items()
             if m.get("status") == "ok" and m.get("lower") and m.get("kind", "guaranteed") == "guaranteed"}
    if not boxes or not result.get("parameters"):
        return None
    name = "hull" if "hull" in boxes else next(iter(boxes))
    m = boxes[name]
    true = result.get("true") or [None] * len(result["parameters"])
    enc = m.get("enclosed")
    table = Table(title=f"Table 1: the {escape(name)} box beside the paper's (Poignet, Ramdani & Vivas 2003)",
                  box=rbox.SIMPLE_HEAD, pad_edge=False)
    table.add_column("parameter", no_wrap=True)
    table.add_column("true", justify="right", no_wrap=True)
    table.add_column(f"{escape(name)} box", justify="right", overflow="fold")
    table.add_column("in", justify="center", no_wrap=True)
    table.add_column("paper Table 1", justify="right", overflow="fold")
    table.add_column("w/paper", justify="right", no_wrap=True)  # width over the paper box's
    for j, pname in enumerate(result["parameters"]):
        paper = PAPER_TABLE1.get(pname)
        width = m["upper"][j] - m["lower"][j]
        table.add_row(escape(str(pname)), num(true[j]), f"[{num(m['lower'][j])}, {num(m['upper'][j])}]",
                      "-" if not enc else ("yes" if enc[j] else "[red]NO[/red]"),
                      f"[{paper[0]}, {paper[1]}]" if paper else "-",  # as printed in the paper
                      num(width / (paper[1] - paper[0])) if paper and paper[1] > paper[0] else "-")
    return table


class Progress:
    """A rich progress bar fed by the runner's progress(stage, done, total) calls."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.bar = None
        self.tasks = {}

    def __enter__(self):
        if self.enabled:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                                TimeElapsedColumn(), transient=False, console=None)
            self.bar.__enter__()
        return self

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.__exit__(*exc)

    def __call__(self, stage: str, done: int = 0, total: int = 0) -> None:
        if self.bar is None:
            return
        if stage not in self.tasks:
            self.tasks[stage] = self.bar.add_task(stage, total=max(total, 1))
        self.bar.update(self.tasks[stage], completed=done, total=max(total, 1))
