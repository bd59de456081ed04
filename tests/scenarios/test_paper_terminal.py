"""``h4bench run paper`` prints the paper's Table 1 beside h4bench's boxes.

Oracles: the run's result.json (truth, hull box) and the paper's Table 1 (``scenarios/report.py``'s PAPER_TABLE1,
checked here against two values copied from the paper, Poignet, Ramdani & Vivas 2003, section 4.2).
"""

from __future__ import annotations

import json

from h4bench.scenarios.cli_output import num as _num


def test_run_paper_prints_table1_beside_the_boxes(paper_quick_cli):
    """The terminal output holds a Table 1 row per parameter: truth, hull box, the paper's box."""
    from h4bench.scenarios.report import PAPER_TABLE1

    run_dir, output = paper_quick_cli
    assert PAPER_TABLE1["Mnac"] == (0.7650, 1.2338) and PAPER_TABLE1["Fv2"] == (0.1733, 0.2554)  # the paper's
    result = json.loads((run_dir / "result.json").read_text())
    assert "Table 1" in output and "paper Table 1" in output
    lines = output.splitlines()
    hull = result["methods"]["hull"]
    for j, name in enumerate(result["parameters"]):
        paper = PAPER_TABLE1[name]
        row = [ln for ln in lines if ln.strip().startswith(name + " ") and f"[{paper[0]}, {paper[1]}]" in ln]
        assert len(row) == 1, (name, output)
        assert f"[{_num(hull['lower'][j])}, {_num(hull['upper'][j])}]" in row[0]
        assert _num(result["true"][j]) in row[0]



def test_table1_fits_80_columns(paper_quick_cli):
    """In an 80-column terminal every row keeps its parameter, its box and the paper's box whole."""
    from rich.console import Console

    from h4bench.scenarios.cli_output import table1 as _table1
    from h4bench.scenarios.report import PAPER_TABLE1

    run_dir, _ = paper_quick_cli
    result = json.loads((run_dir / "result.json").read_text())
    console = Console(width=80, record=True, file=open("/dev/null", "w"))
    console.print(_table1(result))
    text = console.export_text()
    assert "\u2026" not in text  # no ellipsis
    hull = result["methods"]["hull"]
    for j, name in enumerate(result["parameters"]):
        paper = PAPER_TABLE1[name]
        row = [ln for ln in text.splitlines() if ln.strip().startswith(name + " ")]
        assert len(row) == 1 and f"[{paper[0]}, {paper[1]}]" in row[0], (name, text)
        assert f"[{_num(hull['lower'][j])}, {_num(hull['upper'][j])}]" in row[0], (name, text)
