"""Kind ``paper``: the paper's setting (Table 1 boxes and Table 2 WLS) on a simulated H4, beside the truth."""

from __future__ import annotations

from pathlib import Path

from scenarios import report
from scenarios.experiment import run_experiment
from scenarios.rundir import save_run_files, sim_progress

DESCRIPTION = "the paper's Table 1 (boxes) and Table 2 (WLS) beside the truth"


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    progress("experiment", 0, 1)
    run_ = run_experiment(spec, seed, progress=sim_progress(progress))
    save_run_files(run_, out, progress)
    result = run_.result()
    report.plot_boxes(result, out / "boxes.png")
    report.write_paper_report(result, out, extra="## Controller design\n\n```\n" + run_.controller_report + "\n```\n")
    return result
