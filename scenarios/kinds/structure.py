"""Kind ``structure``: a robot that breaks the paper's hypotheses (unbalanced arms, heavy forearm rods); the bound
the paper's 14-parameter structure then needs, and what the extended structure recovers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from h4bench import sim
from h4bench.scenarios import report
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.rundir import save_run_files, sim_progress
from h4bench.sim.dataset import atomic_write_bytes

DESCRIPTION = "unbalanced arms and heavy forearms: the paper's structure against the extended one"


def run(spec: dict, seed: int, out: Path, progress) -> dict:
    """The robot breaks the paper's hypotheses (unbalanced arms, heavy forearm rods): the bound the paper's
    structure then needs, and what the extended structure recovers."""
    offsets = np.full(4, spec["structure"]["arm_com_offset"])
    forearm_mass = spec["structure"]["forearm_mass"]
    model, theta22 = sim.broken_hypotheses_model(offsets, forearm_mass, spec["model"] or None)
    theta14 = theta22[:14]
    progress("experiment (paper structure)", 0, 2)
    paper_spec = {**spec, "structure": {**spec["structure"], "regressor": "paper"}}
    run14 = run_experiment(paper_spec, seed, model=model, theta_true=theta14, progress=sim_progress(progress))
    progress("experiment (extended structure)", 1, 2)
    ext_spec = {**spec, "structure": {**spec["structure"], "regressor": "extended"}}
    run22 = run_experiment(ext_spec, seed, model=model, theta_true=theta22, reference=run14.reference)
    r14, r22 = run14.result(), run22.result()
    result = dict(r22)
    result["arm_com_offset"] = offsets.tolist()
    result["forearm_mass"] = forearm_mass
    result["paper_structure"] = r14
    save_run_files(run22, out, progress)
    report.plot_boxes(r22, out / "boxes_extended.png", title="extended structure: boxes against the truth")
    report.plot_boxes(r14, out / "boxes_paper.png", title="paper structure on unbalanced arms")
    text = "\n".join([
        f"# Scenario `{result['scenario']}`: arms unbalanced by {offsets[0]} m, forearms as {forearm_mass} kg rods",
        "", "True values of the extended structure: the paper's 14 hold the rods' lumped halves; MXa = "
        f"{theta22[14]:.4g} kg m (arm offset and the rod half at the arm tip), mf = {forearm_mass} kg.", "",
        "## The paper's 14-parameter structure", "", *report.summary_lines(r14),
        f"- the bound this structure needs for the guarantee: {r14['oracle_residual']:.4g} N m on processed rows "
        f"(assumed {r14['bound_processed']:.4g})", "", report.table1(r14), "",
        "## The extended structure (arm gravity MXa, forearm rods mf)", "", *report.summary_lines(r22), "",
        report.table1(r22),
    ])
    atomic_write_bytes(out / "report.md", text.encode())
    return result
