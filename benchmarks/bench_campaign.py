"""Campaign speed against the physics: the ``enclosure`` campaign's wall time over bare MuJoCo stepping of the
same simulated time, and its runs per minute with every estimator, measured in one run.

    python benchmarks/bench_campaign.py [--runs 8] [--all-runs 8] [--all-workers 2] [--repeats 3] [--skip-all]
                                        [--out DIR] [--json]

1. The campaign's designed trajectories (``campaign.trajectories`` of them, full size) are looked up in the
   design cache first (a cold cache designs them now: the time is printed, not counted below).
2. Reference: bare ``mj_step`` of the default H4 for ``runs x duration`` seconds of simulated time (one 10 s
   closed-loop run's applied torques replayed open-loop, as ``bench_sim.py``), the median of ``--repeats``
   measurements taken before and after the campaigns.
3. ``h4bench run enclosure --methods hull --runs N --workers 1 --fresh`` (full size, the command itself: its
   interpreter start-up and imports count): wall time, the ratio to the reference (goal: within 3x), and the
   campaign's own timings (``result.json`` ``campaign.timings``: per stage, overhead outside the runs; goal:
   under 10 % of the wall time).
4. ``--methods all`` with ``--all-runs`` runs on ``--all-workers`` workers: runs per minute (the campaign's
   wall, pool start-up and report included).

Every figure is one wall-clock measurement on a possibly shared machine: compare the ratios of one run, not
the absolute seconds, and repeat the command for the spread.

Profile (cProfile, one full-size ``enclosure`` run with ``--methods hull`` in ``campaign_job``, warm design
cache; 2 shared cores, before this benchmark's changes, commit e1fa711), 4.27 s in all:

    controller design (sim.control_design, 8 python-control step responses)   1.49 s
    simulation loop (sim.simulate._loop: mj_forward + RK4 + law + noise)     0.86 s  (bare mj_step 10 s: 0.38)
    explain.width_analysis (14 half-width LPs on the full equation)           0.46 s
    design-cache load: check_trajectory again on a stored design              0.31 s
    H4 regressor, 5 evaluations (equation, budget x2, feed-forward, check)    0.61 s
    feed-forward inverse dynamics of the reference (nominal parameters)       0.25 s  (1 of the 5 above)
    error budget (scenarios.budget)                                           0.26 s
    hull 0.17 s; min consistent bound 0.02 s; processing 0.14 s

After (same run, same machine; see the report for the figures): the design cached per process by its inputs,
the checked design kept per process and not re-checked when its stored content hash matches, the feed-forward
kept per trajectory, one regressor evaluation shared by the equation and the budget, the width analysis on
demand (``--only INDEX``) rather than in every campaign run, one BLAS thread per campaign worker.
"""

from __future__ import annotations

import _setup  # noqa: F401  (threads, sys.path; before numpy)

import argparse
import json
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

from h4bench import ident
from h4bench import sim
from h4bench.scenarios import registry
from h4bench.scenarios.experiment import feedforward, make_noise, make_reference
from h4bench.trajectories.excitation import cache_stats


def warm_designs(spec: dict) -> tuple[float, dict]:
    """Look up (or design) the campaign's trajectories; returns (seconds, how the lookups were served)."""
    model = sim.load_model()
    geometry = sim.H4Geometry.from_model(model)
    before = cache_stats()
    t0 = time.perf_counter()
    for i in range(spec["campaign"]["trajectories"]):
        make_reference(spec, geometry, spec["seed"] + i)
    after = cache_stats()
    return time.perf_counter() - t0, {k: after[k] - before[k] for k in ("memory", "disk", "computed")}


def applied_torques(spec: dict) -> np.ndarray:
    """One closed-loop run's applied torques (n, 4) on the default model (trajectory of the spec's seed)."""
    model = sim.load_model()
    geometry = sim.H4Geometry.from_model(model)
    reference = make_reference(spec, geometry, spec["seed"])
    nominal = np.asarray(ident.NOMINAL_PARAMETERS, dtype=float)
    _, controller = sim.default_controller(geometry, nominal, bandwidth_hz=spec["controller"]["bandwidth_hz"])
    _, truth = sim.simulate(model, reference, noise=make_noise(spec), controller=controller,
                            feedforward=feedforward(geometry, nominal, reference), seed=spec["seed"])
    return truth.tau_applied, reference


def bare_stepping(torques: np.ndarray, reference, copies: int) -> float:
    """Seconds of ``copies`` x len(torques) bare ``mj_step`` calls (the torques replayed, state reset each time)."""
    model = sim.load_model()
    geometry = sim.H4Geometry.from_model(model)
    data = mujoco.MjData(model)
    qpos0 = geometry.qpos(reference.q[0], sim.forward_kinematics(geometry, reference.q[0]))
    substeps = int(round(float(reference.t[1] - reference.t[0]) / model.opt.timestep))
    ctrl, step = data.ctrl, mujoco.mj_step
    total = 0.0
    for _ in range(copies):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos0
        mujoco.mj_forward(model, data)
        t0 = time.perf_counter()
        for row in torques:
            ctrl[:] = row
            step(model, data, substeps)
        total += time.perf_counter() - t0
    return total


def campaign(methods: str, runs: int, workers: int, out: Path) -> tuple[float, dict]:
    """The command a user runs (a fresh interpreter: imports and pool start-up count); (wall seconds, result)."""
    cmd = ["h4bench", "run", "enclosure", "--methods", methods, "--runs", str(runs), "--workers", str(workers),
           "--fresh", "--json", "--out", str(out)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr[-2000:]}")
    return wall, json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=8, help="runs of the hull campaign (one worker)")
    parser.add_argument("--all-runs", type=int, default=8, help="runs of the --methods all campaign")
    parser.add_argument("--all-workers", type=int, default=2, help="workers of the --methods all campaign")
    parser.add_argument("--repeats", type=int, default=3, help="bare-stepping measurements (median)")
    parser.add_argument("--skip-all", action="store_true", help="only the hull campaign")
    parser.add_argument("--out", type=Path, default=None, help="keep the campaigns' folders here")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON document")
    parser.add_argument("--threads", default=None, help="BLAS threads of this process (see _setup.py)")
    args = parser.parse_args()

    spec = registry.load_spec("enclosure")
    duration = float(spec["trajectory"]["duration"])
    design_s, served = warm_designs(spec)
    torques, reference = applied_torques(spec)
    bare = [bare_stepping(torques, reference, args.runs)]
    figures: dict = {"runs": args.runs, "simulated_seconds": args.runs * duration, "design_lookup_seconds": design_s,
                     "designs_served": served}
    with tempfile.TemporaryDirectory(prefix="bench_campaign_") as tmp:
        root = args.out or Path(tmp)
        wall, result = campaign("hull", args.runs, 1, root / "hull")
        for _ in range(max(1, args.repeats) - 1):
            bare.append(bare_stepping(torques, reference, args.runs))
        t = result["campaign"]["timings"]
        figures["hull"] = {"wall": wall, "campaign_wall": t["wall"], "overhead": t["overhead"],
                           "overhead_share": t["overhead_share"],
                           "stage_medians": {k: v["median"] for k, v in t["stages"].items()},
                           "run_median": t["run_seconds"]["median"]}
        if not args.skip_all:
            wall_all, result_all = campaign("all", args.all_runs, args.all_workers, root / "all")
            ta = result_all["campaign"]["timings"]
            figures["all"] = {"wall": wall_all, "runs": args.all_runs, "workers": args.all_workers,
                              "runs_per_minute": 60.0 * args.all_runs / wall_all,
                              "overhead_share": ta["overhead_share"],
                              "method_medians": {k: v["median"] for k, v in ta["methods"].items()}}
            bare.append(bare_stepping(torques, reference, args.runs))
    figures["bare_seconds"] = statistics.median(bare)
    figures["bare_all"] = bare
    figures["ratio"] = figures["hull"]["wall"] / figures["bare_seconds"]
    if args.json:
        print(json.dumps(figures, indent=1))
        return
    h = figures["hull"]
    print(f"design lookups: {design_s:.2f} s ({served})")
    print(f"bare mj_step of {args.runs} x {duration:g} s: median {figures['bare_seconds']:.3f} s "
          f"(measurements {', '.join(f'{b:.3f}' for b in bare)})")
    print(f"h4bench run enclosure --methods hull --runs {args.runs} --workers 1: {h['wall']:.3f} s wall "
          f"(campaign {h['campaign_wall']:.3f} s) -> "
          f"{figures['ratio']:.2f}x bare stepping (goal <= 3x); median run {h['run_median']:.3f} s; overhead "
          f"outside the runs {h['overhead']:.3f} s = {100 * h['overhead_share']:.1f} % of the campaign's wall "
          "(goal < 10 %)")
    print("  stage medians per run [s]: " + ", ".join(f"{k} {v:.3f}" for k, v in h["stage_medians"].items()))
    if "all" in figures:
        a = figures["all"]
        print(f"enclosure --methods all --runs {a['runs']} --workers {a['workers']}: {a['wall']:.2f} s -> "
              f"{a['runs_per_minute']:.1f} runs/min; overhead {100 * a['overhead_share']:.1f} %")
        print("  method medians per run [s]: " + ", ".join(f"{k} {v:.3f}" for k, v in a["method_medians"].items()))


if __name__ == "__main__":
    main()
