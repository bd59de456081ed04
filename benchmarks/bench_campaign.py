"""Campaign speed against the physics: the ``enclosure`` campaign's wall time over bare MuJoCo stepping of the
same simulated time, and its runs per minute with every estimator, measured in one run.

    python benchmarks/bench_campaign.py [--runs 8] [--all-runs 32] [--all-workers 2] [--repeats 3]
                                        [--campaign-repeats 1] [--skip-all] [--out DIR] [--json]
                                        [--base-python OTHER_VENV/bin/python]

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
   wall, pool start-up and report included). The default, 32 runs, visits each of the 8 designed trajectories
   four times, as a campaign does (200 runs: 25 times); with 8 runs every run is its trajectory's first in its
   worker and the command's fixed costs (interpreter, pool, report and plots: about 2.5 s) weigh as much as
   three runs.

5. ``--base-python``: the same campaigns with another checkout's interpreter (``python -m h4bench``; e.g. a venv
   of the base commit), interleaved with this checkout's, after warming that checkout's own design cache entries:
   its ratio to the same bare-stepping reference and the speed-ups, measured in the same run.

Every campaign figure is one wall-clock measurement on a possibly shared machine, or with ``--campaign-repeats N``
the median of N (each campaign of this checkout measured right after the base's; the stage timings are the last
measurement's): compare the ratios of one run, not the absolute seconds, and repeat for the spread.

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

After (the same profile, same machine, load about 4.5 on the 2 cores; a worker's second run of a trajectory),
1.10 s in all: simulation 0.66 s (the loop 0.83 s under the profiler's overhead), the H4 regressor 2 evaluations
(processed equation and error budget share one; the budget's other is on the true states) 0.25 s, hull 0.16 s,
error budget 0.11 s, processing 0.12 s, min consistent bound 0.013 s, WLS 0.007 s, trajectory 0.005 s (recalled),
controller 0.002 s (cached). Removed: the design computed once per process and stored on disk by its inputs
(``sim.design_cache``), the checked trajectory design kept per process and not re-checked when its stored content
hash matches, the feed-forward kept per trajectory, one regressor evaluation shared by the equation and the
budget, the width analysis on demand (``--only INDEX``) rather than in every campaign run, one BLAS thread per
campaign worker (a trajectory design keeps the process's count), the simulation loop on floats through the noise
stream (``at_list``).

Measured (2026-12-02, 2 cores shared with other engineers' campaigns, load 7-9; one run of this script with
``--base-python`` on the base commit's venv): bare stepping of 8 x 10 s median 5.44 s; ``--methods hull``, 8 runs,
1 worker: the command 37.7 s (6.9x; base 57.0 s, 10.5x), the campaign 21.0 s (3.9x), its pool 16.6 s (3.05x;
base 43.9 s), overhead 21.5 % (setup 3.3 s: the provenance's code hash imports every package; report 1.05 s);
``--methods all``, 8 runs, 2 workers: 9.9 runs/min against the base's 6.6 (1.52x), overhead 28 % (report and
plots 7.0 s). The command's time outside the campaign (interpreter, imports of every scenario kind) was 16.7 s
of the 37.7 s under that load. A second run of the final code (load about 4): bare 4.41 s; hull: the command
17.8 s (4.03x; base 41.3 s, 9.38x: 2.33x faster), the campaign 14.3 s (3.23x), its pool 12.7 s (2.87x; base
35.3 s), overhead 11.8 % (5.8 % without the parent's package imports, 0.86 s, that the forked worker inherits);
all: 21.0 runs/min against 10.7 (1.97x; pools 15.3 s against 38.3 s), overhead 23.9 % (report 3.4 s).

Start-up and report (cProfile of the command's own process, 2 shared cores, commit f537d8e): before the pool,
``h4bench run enclosure`` imported every scenario kind (``registry.load_spec``: the certified kind's
``scenarios.certificate`` -> scipy.signal), ``scenarios.identify`` for one exit code (the processing chain,
scipy.signal: 1.37 s under the profiler) and every sub-package for the provenance's code hash
(``trajectories.timing`` -> toppra: 1.23 s); measured without the profiler, the parent's start-up up to the pool
(CLI import, spec, kind, provenance) took 1.67-2.38 s and 1238 modules. After the runs: the Clopper-Pearson
quantiles imported scipy.stats (1.25 s), ``widths.png`` spent 1.65 s in ``tight_layout`` and 2.0 s in
``savefig`` (``--methods all``: ten panels of 14 boxes, seven Line2D each), matplotlib.pyplot 0.7 s. And with
``--methods all`` the provenance's ``name in BUILTINS`` imported every estimator (Mapping's ``__contains__``
looks the name up): 1.5 s of set-up.

After (branch ``speed``): the kind registry lists kinds from their files and imports only the one run
(``SPEC_DEFAULTS`` read as literals); the code hash reads the source files found on disk; toppra is imported on
first use; the exit codes live in ``scenarios.exit_codes``; ``BUILTINS`` answers ``in`` from its names; the
Clopper-Pearson quantiles come from ``scipy.special.betaincinv`` (bit for bit ``beta.ppf``); the plots use fixed
margins and draw each panel's boxes as three artists; the report's imports are made by a thread of the parent
while it waits for the forked pool. The parent's start-up up to the pool: 0.41-0.57 s, 385 modules. The report of
``--methods all``: 1.2-2.0 s under load 2-3 (was 4.9 s under the profiler, about 3.4 s without).

Profile of one full-size run with ``--methods all`` (a worker's second run, warm caches, cProfile, load about 2),
1.88 s: simulation 0.70 (the loop 0.61), the methods 0.77 (zonotope 0.27: every one of the 12 295 rows cuts, a
sequential update per row; hull 0.18: 106 HiGHS runs; ellipsoid 0.12; contractor 0.09: 7 Jacobi sweeps;
parallelotope 0.08; cgsp 0.02), the IV instruments 0.12, the error budget 0.12, processing 0.12, the H4 regressor
3 evaluations 0.24. The parallelotope now leaves out, in blocks, the rows its step would skip (978 of 12 295 rows
cut; ``ident.estimators._common.RowScan``, one matrix product per block with a margin far above the rounding
difference): 0.10 -> 0.05 s alone, the same boxes bit for bit. The same idea does not pay for the ellipsoid (a
cut every 3.6 rows: a block test after each costs more than the rows it saves) nor the zonotope (every row
cuts); the contractor is already vectorised over rows. The width analysis' LPs no longer run in campaigns
(``explain = false`` in both campaign specs; on demand with ``--only``), so there is nothing left to warm-start.

Measured (2026-12-02, branch ``speed``, one run of this script with ``--base-python`` on a venv of d6155bc; the
2 cores shared with another engineer's 200-run campaign on one core, load about 3): bare stepping 8 x 10 s
median 2.75 s; ``--methods hull``, 8 runs, 1 worker: the command 10.8 s (3.94x; base 28.6 s, 10.4x: 2.64x
faster), the campaign 10.2 s (3.70x), its pool 9.8 s (3.57x), median run 1.00 s (simulation 0.52), overhead
6.5 % (setup 0.11 s, report 0.25 s); ``--methods all``, 8 runs, 2 workers: 22.5 runs/min against the base's 12.2
(1.85x), overhead 11.5 % (report 1.56 s); its runs took 4.06 s each (median; 36.2 s together, the two workers
sharing about one free core), methods 1.79 s of it (zonotope 0.59, hull 0.41, ellipsoid 0.30, contractor 0.20, parallelotope 0.11). An
earlier run the same hour (load 2-3): hull 4.51x (base 10.0x), overhead 8.6 %; all 1.89x, overhead 12.6 %.

Profile of one full-size ``--methods hull`` run after that (a worker's second run of a trajectory, cProfile, quiet
machine), 0.96 s: the simulation 0.54 s, of which the sample loop's Python (the law on floats, the error stream's
``at_list``, the recording) 0.15 s above MuJoCo's own calls (``mj_forward`` 0.11 s, RK4 about 0.26 s); the
feed-forward's inverse dynamics 0.07 s in every run that is its trajectory's first in its worker (every run of an
8-run campaign); the hull 0.15 s (85 HiGHS runs); processing 0.11 s; the error budget 0.11 s (four parallel filters);
the package versions read from the installed metadata in every run 0.02 s; with ``--methods all`` the IV
instruments' reference equation 0.12 s in every run.

After (this commit's benchmark): the sample loop in compiled code (``sim/_loop.cpp``, the Python loop operation for
operation: the same bits, tested), 0.36 s for the 10 s against 0.35 s of bare stepping; the feed-forward kept in the
design cache on disk by its inputs; the instruments' reference rows kept per worker; the versions read once per
process; the budget's parts filtered in one call. Every quick scenario's ``result.json`` and run files are unchanged
(``compare_results.py`` against the previous commit). Measured (2026-12-02, one run of this script with
``--campaign-repeats 3`` and ``--base-python`` on a venv of d6155bc, 2 shared cores): bare stepping of 8 x 10 s
median 3.03 s; ``--methods hull``, 8 runs, 1 worker: the command 8.68 s (median of 16.6, 8.5, 8.7 s), **2.86x**
(base 21.4 s median, 7.06x: 2.47x faster), median run 0.82 s (simulation 0.37 s, processing 0.11 s, hull and the
others 0.17 s, error budget 0.10 s), overhead 8.4 %; ``--methods all``, 32 runs, 2 workers: 69.2 runs/min against
the base's 27.4, **2.52x**, overhead 6.7 % (zonotope 0.23 s, hull 0.17 s, contractor 0.11 s, ellipsoid 0.11 s per
run). A second run half an hour later: bare 2.96 s; hull 9.01 s, 3.04x (base 6.77x), overhead 7.3 %; all 68.2
runs/min against 26.1, 2.61x, overhead 7.6 %. Single measurements the same hour spread widely with the machine's
load: hull 2.87x, 2.95x, 3.34x, 3.43x;
all 2.52x, 2.48x, 2.01x, 2.05x (8-run all campaigns, whose fixed costs weigh three runs: 2.14x). What is left per
hull run is computation whose every bit the results carry (the hull's LPs, the forward kinematics of three
regressor evaluations, the filters).
"""

from __future__ import annotations

import _setup  # noqa: F401  (threads, sys.path; before numpy)

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

from h4bench import ident
from h4bench import sim
from h4bench.scenarios import registry
from h4bench.scenarios.experiment import make_noise, make_reference

try:  # this checkout's helpers; the benchmark also measures an older checkout (--base) without them
    from h4bench.scenarios.experiment import feedforward
    from h4bench.trajectories.excitation import cache_stats
except ImportError:  # pragma: no cover - an older checkout
    def feedforward(geometry, theta, reference):
        return ident.inverse_dynamics(geometry, theta, reference.q, reference.qd, reference.qdd)

    def cache_stats():
        return {"memory": 0, "disk": 0, "computed": 0}


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


# an older checkout (before the h4bench namespace) has the same modules at the top level
_WARM = ("try:\n    from h4bench import sim\n    from h4bench.scenarios import registry\n"
         "    from h4bench.scenarios.experiment import make_reference\n"
         "except ImportError:\n    import sim\n    from scenarios import registry\n"
         "    from scenarios.experiment import make_reference\n"
         "spec = registry.load_spec('enclosure')\ng = sim.H4Geometry.from_model(sim.load_model())\n"
         "for i in range(spec['campaign']['trajectories']):\n    make_reference(spec, g, spec['seed'] + i)\n")
_CLI = ("try:\n    from h4bench.scenarios.cli import app\n"
        "except ImportError:\n    from scenarios.cli import app\napp()\n")


def warm_base(python: str) -> float:
    """The other checkout's designs of the campaign, in its own design cache entries (seconds)."""
    t0 = time.perf_counter()
    subprocess.run([python, "-c", _WARM], check=True, capture_output=True, cwd=tempfile.gettempdir())
    return time.perf_counter() - t0


def campaign(methods: str, runs: int, workers: int, out: Path, python: str = sys.executable) -> tuple[float, dict]:
    """The command a user runs (a fresh interpreter: imports and pool start-up count); (wall seconds, result).
    Run from a neutral folder (``python -c`` puts the working directory first on ``sys.path``)."""
    cmd = [python, "-c", _CLI, "run", "enclosure", "--methods", methods, "--runs", str(runs), "--workers",
           str(workers), "--fresh", "--json", "--out", str(out)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t0
    if done.returncode not in (0, 4):  # 4: some method gave no box in some run (recorded in the result)
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr[-2000:]}")
    result = json.loads(done.stdout)
    result["exit_code"] = done.returncode
    return wall, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=8, help="runs of the hull campaign (one worker)")
    parser.add_argument("--all-runs", type=int, default=32,
                        help="runs of the --methods all campaign (default 32: four per designed trajectory, so that "
                             "the runs per minute are a campaign's, not its fixed start-up and report)")
    parser.add_argument("--all-workers", type=int, default=2, help="workers of the --methods all campaign")
    parser.add_argument("--repeats", type=int, default=3, help="bare-stepping measurements (median)")
    parser.add_argument("--campaign-repeats", type=int, default=1,
                        help="measure each campaign this many times (interleaved with the base's): the medians are "
                             "printed, every measurement kept in the JSON")
    parser.add_argument("--skip-all", action="store_true", help="only the hull campaign")
    parser.add_argument("--out", type=Path, default=None, help="keep the campaigns' folders here")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON document")
    parser.add_argument("--threads", default=None, help="BLAS threads of this process (see _setup.py)")
    parser.add_argument("--base-python", default=None,
                        help="the interpreter of another checkout (e.g. the base commit's venv): its campaigns are "
                             "run too, interleaved, and the ratios printed side by side")
    args = parser.parse_args()

    spec = registry.load_spec("enclosure")
    duration = float(spec["trajectory"]["duration"])
    design_s, served = warm_designs(spec)
    torques, reference = applied_torques(spec)
    bare = [bare_stepping(torques, reference, args.runs)]
    figures: dict = {"runs": args.runs, "simulated_seconds": args.runs * duration, "design_lookup_seconds": design_s,
                     "designs_served": served}
    if args.base_python:
        figures["base_design_lookup_seconds"] = warm_base(args.base_python)
    with tempfile.TemporaryDirectory(prefix="bench_campaign_") as tmp:
        root = args.out or Path(tmp)
        reps = max(1, args.campaign_repeats)
        base_walls, walls = [], []
        for _ in range(reps):
            if args.base_python:
                base_walls.append(campaign("hull", args.runs, 1, root / "base-hull", args.base_python)[0])
                bare.append(bare_stepping(torques, reference, args.runs))
            w, result = campaign("hull", args.runs, 1, root / "hull")
            walls.append(w)
        if base_walls:
            figures["base_hull"] = {"wall": statistics.median(base_walls), "walls": base_walls}
        wall = statistics.median(walls)
        for _ in range(max(1, args.repeats) - 1):
            bare.append(bare_stepping(torques, reference, args.runs))
        t = result["campaign"].get("timings") or {}  # absent in an older checkout
        figures["hull"] = {"wall": wall, "walls": walls, "campaign_wall": t.get("wall", result["campaign"]["seconds"]),
                           "overhead": t.get("overhead"), "overhead_share": t.get("overhead_share"),
                           "stage_medians": {k: v["median"] for k, v in t.get("stages", {}).items()},
                           "run_median": (t.get("run_seconds") or {}).get("median")}
        if not args.skip_all:
            base_alls, alls = [], []
            for _ in range(reps):
                if args.base_python:
                    base_alls.append(campaign("all", args.all_runs, args.all_workers, root / "base-all",
                                              args.base_python)[0])
                w, result_all = campaign("all", args.all_runs, args.all_workers, root / "all")
                alls.append(w)
            if base_alls:
                base_all = statistics.median(base_alls)
                figures["base_all"] = {"wall": base_all, "walls": base_alls,
                                       "runs_per_minute": 60.0 * args.all_runs / base_all}
            wall_all = statistics.median(alls)
            ta = result_all["campaign"].get("timings") or {}
            figures["all"] = {"wall": wall_all, "walls": alls, "runs": args.all_runs, "workers": args.all_workers,
                              "runs_per_minute": 60.0 * args.all_runs / wall_all,
                              "overhead_share": ta.get("overhead_share"), "exit_code": result_all["exit_code"],
                              "methods_without_box": sorted(k for k, m in result_all["methods"].items()
                                                            if m.get("failed_runs")),
                              "method_medians": {k: v["median"] for k, v in ta.get("methods", {}).items()}}
            bare.append(bare_stepping(torques, reference, args.runs))
    figures["bare_seconds"] = statistics.median(bare)
    figures["bare_all"] = bare
    figures["ratio"] = figures["hull"]["wall"] / figures["bare_seconds"]
    if "base_hull" in figures:
        figures["base_ratio"] = figures["base_hull"]["wall"] / figures["bare_seconds"]
    if args.json:
        print(json.dumps(figures, indent=1))
        return
    h = figures["hull"]
    print(f"design lookups: {design_s:.2f} s ({served})")
    print(f"bare mj_step of {args.runs} x {duration:g} s: median {figures['bare_seconds']:.3f} s "
          f"(measurements {', '.join(f'{b:.3f}' for b in bare)})")
    print(f"h4bench run enclosure --methods hull --runs {args.runs} --workers 1: {h['wall']:.3f} s wall "
          f"(campaign {h['campaign_wall']:.3f} s) -> {figures['ratio']:.2f}x bare stepping (goal <= 3x)")
    if h["overhead"] is not None:
        print(f"  median run {h['run_median']:.3f} s; overhead outside the runs {h['overhead']:.3f} s = "
              f"{100 * h['overhead_share']:.1f} % of the campaign's wall (goal < 10 %)")
    print("  stage medians per run [s]: " + ", ".join(f"{k} {v:.3f}" for k, v in h["stage_medians"].items()))
    if "base_hull" in figures:
        print(f"  base checkout ({args.base_python}): {figures['base_hull']['wall']:.3f} s -> "
              f"{figures['base_ratio']:.2f}x bare stepping; this checkout is "
              f"{figures['base_hull']['wall'] / h['wall']:.2f}x faster")
    if "all" in figures:
        a = figures["all"]
        share = "n/a" if a["overhead_share"] is None else f"{100 * a['overhead_share']:.1f} %"
        print(f"enclosure --methods all --runs {a['runs']} --workers {a['workers']}: {a['wall']:.2f} s -> "
              f"{a['runs_per_minute']:.1f} runs/min; overhead {share}")
        print("  method medians per run [s]: " + ", ".join(f"{k} {v:.3f}" for k, v in a["method_medians"].items()))
        if a["methods_without_box"]:
            print(f"  exit code {a['exit_code']}: no box in some run from {', '.join(a['methods_without_box'])}")
        if "base_all" in figures:
            b = figures["base_all"]
            print(f"  base checkout: {b['wall']:.2f} s -> {b['runs_per_minute']:.1f} runs/min; this checkout "
                  f"{a['runs_per_minute'] / b['runs_per_minute']:.2f}x the runs per minute (goal >= 2.5x)")


if __name__ == "__main__":
    main()
