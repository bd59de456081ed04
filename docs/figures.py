"""The figures the README and the documentation state, made by running the commands that give them.

    python docs/figures.py              # the quick group: run paper --quick, export + identify --spec, the arm
                                        # example on a 2.5 s log (about 3-5 minutes on 2 cores)
    python docs/figures.py --full       # also the full-size group, by hand: run paper (10 s), the arm example's
                                        # 12 s log (about 10-15 minutes)
    python docs/figures.py --tables     # only rewrite the tables from docs/figures.json (no run)

Writes ``docs/figures.json`` (every figure, stamped with the git commit it was measured at, whether the tree had
uncommitted changes, the machine and the date), the Markdown tables the pages include (``docs/_generated/*.md``,
through ``<!-- include: ... -->``), the README's block between ``<!-- figures:begin -->`` and ``<!-- figures:end -->``
and one picture (``docs/_generated/paper-quick-boxes.png``, the run's own ``boxes.png``). A group not run keeps its
previous entry. ``tests/test_docs_site.py`` checks that the committed tables and README block are
:func:`tables` of the committed JSON (no simulation in the default tests).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
JSON = DOCS / "figures.json"
GENERATED = DOCS / "_generated"
README = ROOT / "README.md"
BEGIN, END = "<!-- figures:begin -->", "<!-- figures:end -->"


# ------------------------------------------------------------------------------------------------- running commands
def _h4bench(*args: str) -> tuple[dict | None, float]:
    """``python -m h4bench ARGS --json`` (the installed command); its result.json and the wall seconds."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "h4bench", *args, "--json"], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"h4bench {' '.join(args)} failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    return json.loads(done.stdout), seconds


def _paper_figures(result: dict, seconds: float) -> dict:
    """Table 1 figures of a paper run: per parameter truth, hull and cgsp boxes, the paper's box, hull / paper."""
    from h4bench.scenarios.report import PAPER_TABLE1

    names = result["parameters"]
    hull, cgsp = result["methods"]["hull"], result["methods"].get("cgsp", {})
    rows, ratios = [], []
    for j, name in enumerate(names):
        paper = PAPER_TABLE1[name]
        w = hull["upper"][j] - hull["lower"][j]
        ratio = w / (paper[1] - paper[0])
        ratios.append(ratio)
        rows.append({"parameter": name, "true": result["true"][j], "hull": [hull["lower"][j], hull["upper"][j]],
                     "cgsp": [cgsp["lower"][j], cgsp["upper"][j]] if cgsp.get("lower") else None,
                     "paper": list(paper), "hull_over_paper": ratio, "hull_encloses": bool(hull["enclosed"][j])})
    return {"command": "h4bench run paper" + (" --quick" if result.get("quick") else ""), "seed": result["seed"],
            "seconds": round(seconds, 1), "rows": rows,
            "hull_over_paper_geomean": math.exp(sum(math.log(r) for r in ratios) / len(ratios)),
            "hull_not_wider_than_paper": sum(r <= 1 for r in ratios),
            "hull_enclosed": sum(r["hull_encloses"] for r in rows), "parameters": len(names)}


def _certified_figures(run_dir: Path, work: Path) -> dict:
    """``h4bench export`` of the run, then ``identify --spec``: the certified box against the run's truth."""
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "h4bench", "export", str(run_dir), str(work / "log.csv")],
                          capture_output=True, text=True)
    t_export = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"h4bench export failed (exit {done.returncode}): {done.stderr.strip()}")
    result, seconds = _h4bench("identify", str(work / "log.csv"), "--spec", str(work / "spec.toml"), "--out",
                               str(work / "identify"))
    run = json.loads((run_dir / "result.json").read_text())
    box = result["methods"]["certified"]
    hull = run["methods"]["hull"]
    true = run["true"]
    enclosed = sum(lo <= t <= hi for lo, t, hi in zip(box["lower"], true, box["upper"]))
    ratios = [(bh - bl) / (hh - hl) for bl, bh, hl, hh in zip(box["lower"], box["upper"], hull["lower"],
                                                              hull["upper"])]
    return {"command": "h4bench export RUN log.csv && h4bench identify log.csv --spec spec.toml",
            "seconds_export": round(t_export, 1), "seconds_identify": round(seconds, 1), "rows": result["rows"],
            "enclosed": int(enclosed), "parameters": len(true),
            "certified_over_hull_geomean": math.exp(sum(math.log(r) for r in ratios) / len(ratios)),
            "width_over_prior_median": sorted((h - lo) / 2.0 for lo, h in zip(box["lower"], box["upper"]))[
                len(true) // 2]}


def _arm_figures(seconds_log: float, work: Path) -> dict:
    """The own-arm example (examples/own_arm/run.py) on a log of ``seconds_log``."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "own_arm" / "run.py"), "--seconds",
                           str(seconds_log), "--out", str(work / f"arm-{seconds_log:g}")], capture_output=True,
                          text=True)
    if done.returncode != 0:
        raise SystemExit(f"examples/own_arm/run.py failed:\n{done.stderr[-2000:]}")
    read = json.loads(done.stdout)
    read.update(command=f"python examples/own_arm/run.py --seconds {seconds_log:g}", log_seconds=seconds_log,
                seconds=round(time.perf_counter() - t0, 1))
    return read


def run_quick(work: Path) -> dict:
    result, seconds = _h4bench("run", "paper", "--quick", "--out", str(work / "paper"))
    GENERATED.mkdir(exist_ok=True)
    shutil.copyfile(work / "paper" / "boxes.png", GENERATED / "paper-quick-boxes.png")
    return {"paper": _paper_figures(result, seconds), "certified": _certified_figures(work / "paper", work / "h4"),
            "arm": _arm_figures(2.5, work)}


def run_full(work: Path) -> dict:
    result, seconds = _h4bench("run", "paper", "--out", str(work / "paper-full"))
    return {"paper": _paper_figures(result, seconds), "arm": _arm_figures(12.0, work)}


# ------------------------------------------------------------------------------------------------- the tables
def _n(x) -> str:
    if x is None:
        return "-"
    x = float(x)
    return f"{x:.4g}" if x == 0 or 1e-3 <= abs(x) < 1e4 else f"{x:.3e}"


def _box(b) -> str:
    return "-" if b is None else f"[{_n(b[0])}, {_n(b[1])}]"


def _stamp(data: dict, group: str) -> str:
    g = data["groups"][group]
    return (f"*generated* by `python docs/figures.py{' --full' if group == 'full' else ''}` at commit "
            f"`{g['commit'][:10]}`{' (with uncommitted changes)' if g['dirty'] else ''}, {g['date']}, on "
            f"{g['machine']}.")


def table1_md(data: dict) -> str:
    out = []
    for group in ("full", "quick"):
        g = data["groups"].get(group)
        if not g:
            continue
        p = g["figures"]["paper"]
        out += [f"### Table 1 beside `{p['command']}` (seed {p['seed']})", "",
                "| parameter | true | hull box | cgsp box | paper Table 1 | hull / paper width |", "|---|---|---|---|---|---|"]
        out += [f"| `{r['parameter']}` | {_n(r['true'])} | {_box(r['hull'])}{'' if r['hull_encloses'] else ' **NO**'} | "
                f"{_box(r['cgsp'])} | [{r['paper'][0]}, {r['paper'][1]}] | {r['hull_over_paper']:.3g} |"
                for r in p["rows"]]
        out += ["", f"Hull boxes enclosing the truth: {p['hull_enclosed']} of {p['parameters']}; at most as wide as the "
                f"paper's: {p['hull_not_wider_than_paper']} of {p['parameters']}; geometric mean of hull / paper "
                f"width {p['hull_over_paper_geomean']:.3g}; {p['seconds']:g} s.", "", _stamp(data, group), ""]
    return "\n".join(out)


def certified_md(data: dict) -> str:
    c = data["groups"]["quick"]["figures"]["certified"]
    return "\n".join([
        "| figure | value |", "|---|---|",
        f"| true parameters in the certified box | {c['enclosed']} of {c['parameters']} |",
        f"| certified / tuned hull width (geometric mean) | {c['certified_over_hull_geomean']:.3g} |",
        f"| median width / prior width | {c['width_over_prior_median']:.3g} |",
        f"| rows of the interval equation | {c['rows']} |",
        f"| seconds: export, identify --spec | {c['seconds_export']:g}, {c['seconds_identify']:g} |", "",
        _stamp(data, "quick"), ""])


def arm_md(data: dict) -> str:
    out = ["| log | base parameters | enclosed | median width / prior | narrowed | dominant term (share) | "
           "contradicted | seconds |", "|---|---|---|---|---|---|---|---|"]
    stamps = []
    for group in ("quick", "full"):
        g = data["groups"].get(group)
        a = g and g["figures"].get("arm")
        if not a:
            continue
        out.append(f"| {a['log_seconds']:g} s | {a['base_parameters']} | {a['enclosed']} | "
                   f"{a['width_over_prior_median']:.3g} | {a['narrowed']} | {a['dominant']} "
                   f"({a['shares'][a['dominant']]:.2f}) | {len(a['contradicted'])} | {a['seconds']:g} |")
        stamps.append(_stamp(data, group))
    return "\n".join(out + [""] + stamps + [""])


def readme_block(data: dict) -> str:
    q = data["groups"]["quick"]["figures"]
    p, c, a = q["paper"], q["certified"], q.get("arm")
    lines = [f"Measured by `python docs/figures.py` at commit `{data['groups']['quick']['commit'][:10]}` on "
             f"{data['groups']['quick']['machine']}:",
             f"`run paper --quick` {p['seconds']:g} s, hull boxes hold the truth on {p['hull_enclosed']} of "
             f"{p['parameters']} parameters (hull / paper width, geometric mean {p['hull_over_paper_geomean']:.2f}); "
             f"`export` + `identify --spec` {c['seconds_export'] + c['seconds_identify']:.0f} s, certified box holds "
             f"{c['enclosed']} of {c['parameters']}"
             + (f"; the arm example on a {a['log_seconds']:g} s log {a['seconds']:g} s, {a['enclosed']} of "
                f"{a['base_parameters']} base parameters enclosed." if a else ".")]
    full = data["groups"].get("full")
    if full:
        fp = full["figures"]["paper"]
        lines.append(f"Full size (`run paper`, `--full`, commit `{full['commit'][:10]}`): {fp['seconds']:g} s, "
                     f"{fp['hull_enclosed']} of {fp['parameters']} enclosed, hull / paper width "
                     f"{fp['hull_over_paper_geomean']:.2f}.")
    return "\n".join(lines)


def tables(data: dict) -> dict[str, str]:
    """``{path relative to the checkout: text}`` of every generated file (the README's block included, as the
    text between the markers)."""
    out = {"docs/_generated/table1.md": table1_md(data), "docs/_generated/certified-h4.md": certified_md(data),
           "docs/_generated/own-arm.md": arm_md(data), "README.md": readme_block(data)}
    return out


def readme_with_block(text: str, block: str) -> str:
    a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
    return text[:a] + "\n" + block + "\n" + text[b:]


def write_tables(data: dict) -> None:
    for rel, text in tables(data).items():
        path = ROOT / rel
        if rel == "README.md":
            path.write_text(readme_with_block(path.read_text(), text))
        else:
            path.parent.mkdir(exist_ok=True)
            path.write_text(text)


# ------------------------------------------------------------------------------------------------- main
def _stamp_now() -> dict:
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                                capture_output=True, text=True).stdout.strip())
    cpu = platform.processor() or platform.machine()
    return {"commit": commit or "unknown", "dirty": dirty,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "machine": f"{os.cpu_count()} cores ({cpu}), Python {platform.python_version()}, {platform.system()}"}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="also the full-size group (by hand, about 10-15 minutes)")
    ap.add_argument("--tables", action="store_true", help="only rewrite the tables from docs/figures.json")
    args = ap.parse_args(argv)
    data = json.loads(JSON.read_text()) if JSON.is_file() else {"groups": {}}
    if not args.tables:
        with tempfile.TemporaryDirectory(prefix="h4bench-figures-") as tmp:
            work = Path(tmp)
            data["groups"]["quick"] = {**_stamp_now(), "figures": run_quick(work)}
            if args.full:
                data["groups"]["full"] = {**_stamp_now(), "figures": run_full(work)}
        JSON.write_text(json.dumps(data, indent=1) + "\n")
    write_tables(data)


if __name__ == "__main__":
    main()
