"""Per-stage run timings and a campaign's overhead (scenarios.timings): the arithmetic against hand sums, and
the engine's measurements on a campaign of timed stand-in jobs."""

from __future__ import annotations

import sys
import time

import pytest

from h4bench.scenarios import campaign as camp
from h4bench.scenarios.registry import load_spec
from h4bench.scenarios.timings import STAGES, TimedJob, campaign_timings, run_stages, timing_lines


def test_run_stages_group_the_sections():
    t = {"model": 0.01, "trajectory": 0.02, "controller": 0.03, "simulation": 0.5, "processing": 0.1,
         "budget": 0.07, "judging": 0.004, "io": 0.006, "trajectory_source": "memory",
         "methods": {"hull": 0.2, "min_consistent_bound": 0.02, "width_analysis": 0.3}, "run": 1.5}
    s = run_stages(t)
    assert set(s) == set(STAGES)
    assert s["design"] == pytest.approx(0.06) and s["methods"] == pytest.approx(0.22)
    assert s["analysis"] == pytest.approx(0.37) and s["io"] == 0.006
    assert s["other"] == pytest.approx(1.5 - (0.06 + 0.5 + 0.1 + 0.22 + 0.004 + 0.37 + 0.006))
    assert run_stages({})["other"] == 0.0 and run_stages({"simulation": 2.0, "run": 1.0})["other"] == 0.0


def test_campaign_timings_overhead_is_wall_minus_run_time_per_worker():
    runs = [{"timings": {"simulation": 1.0, "run": 2.0, "methods": {"hull": 0.5}, "trajectory_source": "disk"}},
            {"timings": {"simulation": 3.0, "run": 4.0, "methods": {"hull": 0.7}, "trajectory_source": "memory"}},
            {"index": 2}]  # a reused run: not counted
    t = campaign_timings(runs, [0, 1], 2, time.time() - 10.0, {"setup": 0.5})
    assert t["wall"] == pytest.approx(10.0, abs=0.5)
    assert t["overhead"] == pytest.approx(t["wall"] - 3.0) and t["overhead_share"] == pytest.approx(t["overhead"] / t["wall"])
    assert t["stages"]["simulation"] == {"total": 4.0, "median": 2.0}
    assert t["methods"]["hull"]["total"] == pytest.approx(1.2) and t["trajectory_sources"] == {"disk": 1, "memory": 1}
    assert any("Where the time went" in line for line in timing_lines(t))
    assert campaign_timings(runs, [0, 1], 0, time.time(), {})["overhead"] is None  # Dask: pool size unknown


def sleepy_job(spec: dict, index: int, base_seed: int) -> dict:
    """A stand-in run of about 50 ms whose 'simulation' took 30 ms (picklable: module level)."""
    time.sleep(0.05)
    return {"index": index, "seed": base_seed + index, "timings": {"simulation": 0.03}}


def test_the_engine_times_runs_and_its_own_sections(tmp_path):
    spec = load_spec("enclosure", quick=True)
    spec["campaign"].update(runs=3, workers=1)
    sys.modules.pop("colorsys", None)
    # the report's imports are made by a thread while the pool runs; a module that cannot be imported is left to
    # its user (no error here)
    runs, info = camp.run_many(spec, 1000, tmp_path / "c", sleepy_job, lambda *a: None,
                               report_imports=("colorsys", "no_such_module_of_the_report"))
    assert "colorsys" in sys.modules  # the thread was joined before the runs came back
    staged = info["timings"]
    assert staged["computed"] == [0, 1, 2] and set(staged["sections"]) >= {"setup", "io", "pool"}
    assert all(0.05 <= r["timings"]["run"] < 5.0 and r["timings"]["io"] > 0 for r in runs)
    t = campaign_timings(runs, staged["computed"], 1, staged["started"], staged["sections"])
    assert t["run_seconds"]["total"] == pytest.approx(sum(r["timings"]["run"] for r in runs))
    assert t["wall"] >= t["run_seconds"]["total"] and t["overhead"] >= 0.0
    assert t["stages"]["io"]["total"] > 0 and t["stages"]["other"]["total"] >= 0.0
    assert TimedJob(sleepy_job)(spec, 0, 1)["timings"]["run"] >= 0.05


def test_single_blas_thread_and_the_original_counts_in_a_fresh_process():
    """The worker's thread limit, and the design caches' keys, which do not depend on the counts: a design is
    the same bits under any thread count (tests/test_blas_independence.py), so one computed under other counts
    is reused (both keys equal at 2 threads, at 1 and at 2 again)."""
    import json
    import os
    import subprocess
    import sys

    code = ("import json, numpy as np\n"
            "from h4bench.scenarios import threads\n"
            "from h4bench import blas, sim\n"
            "from h4bench.sim.design_cache import design_key\n"
            "from h4bench.trajectories import excitation as ex\n"
            "import scipy.linalg\n"
            "counts = lambda: [g() for _, _, g in blas.openblas_libraries()]\n"
            "g = sim.H4Geometry.from_model(sim.load_model())\n"
            "keys = lambda: [design_key(np.ones(4), np.ones(4), 10.0, 1e-3, 60.0, None), ex.cache_key(ex.cache_inputs("
            "g, 10.0, 0, ex.Limits(), 'h', ex.as_processing(None, 1e-3), None, ex.as_theta(None), ex.DEFAULT_OPTIONS))]\n"
            "before, k2 = counts(), keys()\n"
            "n = len(threads.single_blas_thread())\n"
            "one, k1 = counts(), keys()\n"
            "with threads.original_blas_threads():\n"
            "    inside, k2_again = counts(), keys()\n"
            "a = np.arange(9.0).reshape(3, 3)\n"
            "print(json.dumps([n, before, one, inside, counts(), float((a @ a)[0, 0]), k2, k1, k2_again]))\n")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout
    n, before, one, inside, after, check, k2, k1, k2_again = json.loads(out)
    assert n >= 1 and before == [2] * n and one == after == [1] * n and inside == before and check == 15.0
    assert k2 == k2_again == k1 and all(len(k) == 64 for k in k1)
