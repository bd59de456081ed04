"""Trajectory design: conditioning gained by the optimisation and what it costs, as ratios against references
measured in the same run (the seeded unoptimised start; one full-resolution check of the result).

    python benchmarks/bench_trajectories.py [--seeds 5] [--duration 10] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from h4bench import sim
from h4bench import trajectories as tj

PICK_PLACE = np.array([
    [0.0, 0.0, -0.55, 0.0], [0.08, 0.06, -0.52, 0.3], [0.08, 0.06, -0.64, 0.3], [0.08, 0.06, -0.52, 0.3],
    [-0.08, -0.05, -0.52, -0.3], [-0.08, -0.05, -0.64, -0.3], [0.0, 0.0, -0.55, 0.0]])


def _timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    geometry = sim.H4Geometry.from_model(sim.load_model())
    rows = []
    for seed in range(args.seeds):
        start, t_start = _timed(tj.fourier_excitation, geometry, args.duration, seed=seed, optimise=False)
        opt, t_opt = _timed(tj.fourier_excitation, geometry, args.duration, seed=seed)
        _, t_check = _timed(tj.check_trajectory, geometry, opt)
        rows.append({
            "seed": seed, "cond_start": start.checks["cond_W_scaled"], "cond_optimised": opt.checks["cond_W_scaled"],
            "cond_ratio": start.checks["cond_W_scaled"] / opt.checks["cond_W_scaled"],
            "cond_normalised_start": start.checks["cond_W_normalised"],
            "cond_normalised_optimised": opt.checks["cond_W_normalised"],
            "design_seconds": t_opt, "start_seconds": t_start, "check_seconds": t_check,
            "design_over_check": t_opt / t_check, "usage": opt.checks["usage"],
            "iterations": opt.parameters["optimisation"].get("nit"),
            "final_scale": opt.parameters["optimisation"]["final_scale"],
        })
    wp, t_wp = _timed(tj.waypoint_trajectory, geometry, PICK_PLACE)
    fast = tj.fourier_trajectory(geometry, opt.parameters, duration=args.duration / 2)
    uni, t_uni = _timed(tj.slow_down, geometry, fast, method="uniform")
    top, t_top = _timed(tj.slow_down, geometry, fast, method="toppra")
    result = {
        "duration_s": args.duration, "fourier": rows,
        "median_cond_ratio": float(np.median([r["cond_ratio"] for r in rows])),
        "median_design_seconds": float(np.median([r["design_seconds"] for r in rows])),
        "waypoints": {"seconds": t_wp, "duration_s": wp.duration, "usage": wp.checks["usage"]},
        "slow_down": {m: {"seconds": s, "factor": tr.parameters["slow_down"]["factor"],
                          "cond_W_scaled": tr.checks["cond_W_scaled"]}
                      for m, s, tr in (("uniform", t_uni, uni), ("toppra", t_top, top))},
    }
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        for r in rows:
            print(f"seed {r['seed']}: cond(W diag(theta)) {r['cond_start']:7.1f} -> {r['cond_optimised']:5.1f} "
                  f"(x{r['cond_ratio']:.1f}), normalised {r['cond_normalised_start']:.2f} -> "
                  f"{r['cond_normalised_optimised']:.2f}; design {r['design_seconds']:.2f} s "
                  f"= {r['design_over_check']:.0f} full checks; usage "
                  + ", ".join(f"{k} {v:.2f}" for k, v in r["usage"].items()))
        print(f"median cond ratio {result['median_cond_ratio']:.1f}, median design time "
              f"{result['median_design_seconds']:.2f} s for {args.duration:g} s")
        print(f"pick-and-place: timed in {t_wp * 1e3:.0f} ms, {wp.duration:.3f} s long, usage {wp.checks['usage']}")
        for m, v in result["slow_down"].items():
            print(f"slow-down {m}: factor {v['factor']:.3f} in {v['seconds']:.2f} s, cond {v['cond_W_scaled']:.1f}")
    return result


if __name__ == "__main__":
    main()
