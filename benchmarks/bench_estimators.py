"""Speed and tightness of the estimators, as ratios to numpy.linalg.lstsq on the same data in the same run.

    python benchmarks/bench_estimators.py [--sizes 4000 40000 400000] [--big 1000000] [--repeats 3] [--threads 1]
    python benchmarks/bench_estimators.py --quick      (sizes 4000 40000, no big run)

Synthetic, well-conditioned data: W (N, 14) standard normal, theta_true uniform in [0.5, 1.5], noise uniform
in [-1, 1], bound 1, prior [0, 2]^14. For each N: the median time of each method over ``--repeats`` runs
divided by the median time of ``numpy.linalg.lstsq(W, y)``; the mean widths of the cgsp and hull boxes and
their ratio. Then the hull alone at ``--big`` rows (time, and peak traced memory relative to ``W.nbytes``).
Then, at the first size, the hull in other units (rows times 1e9, parameter j in units 10^-c_j with c_j from -6
to 6) and at a bound of 1e-12 relative (data with noise of that size): time against the SI run and the largest
endpoint difference in widths of the SI box (converted back; the stated tolerance is 1e-6 width plus the
rounding of the converted data, tests/ident/test_units.py).
Targets: hull within 10x of lstsq at N = 40 000; hull at 10^6 rows under 10 s with peak memory under 3x W.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
import tracemalloc

import _setup  # noqa: F401  (BLAS threads, repository root; before numpy)
import numpy as np  # noqa: E402

import ident  # noqa: E402

P = 14


def make_data(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((n, P))
    theta = rng.uniform(0.5, 1.5, P)
    y = W @ theta + rng.uniform(-1.0, 1.0, n)
    return W, y, theta


def median_time(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def bench_size(n: int, repeats: int) -> dict:
    """Interleaved repeats (lstsq, hull, cgsp, wls, lstsq, ...) so that all see the same machine load."""
    W, y, theta = make_data(n)
    prior = (np.zeros(P), 2.0 * np.ones(P))
    runs = {
        "lstsq": lambda: np.linalg.lstsq(W, y, rcond=None),
        "hull": lambda: ident.estimate(W, y, 1.0, prior, method="hull"),
        "cgsp": lambda: ident.estimate(W, y, 1.0, prior, method="cgsp"),
        "wls": lambda: ident.wls(W, y, joints=2),
    }
    times = {k: [] for k in runs}
    out = {}
    runs["lstsq"]()  # warm-up (BLAS threads, first-touch pages)
    for _ in range(repeats):
        for name, fn in runs.items():
            t, out[name] = median_time(fn, 1)
            times[name].append(t)
    t_lstsq = statistics.median(times["lstsq"])
    row = {"N": n, "lstsq_s": t_lstsq}
    for name in ("hull", "cgsp", "wls"):
        row[f"{name}_s"] = statistics.median(times[name])
        row[f"{name}_ratio"] = row[f"{name}_s"] / t_lstsq
    for method in ("hull", "cgsp"):
        row[f"{method}_width"] = float(out[method].width.mean())
        row[f"{method}_encloses"] = bool(out[method].contains(theta).all())
    row["width_ratio_cgsp_over_hull"] = row["cgsp_width"] / row["hull_width"]
    return row


def bench_units(n: int, repeats: int) -> dict:
    """The hull in SI units, in other units, and at a tight bound; times and endpoint differences."""
    W, y, theta = make_data(n)
    prior = (np.zeros(P), 2.0 * np.ones(P))
    c = 10.0 ** np.round(np.linspace(-6, 6, P))
    f = 1e9
    t_si, box = median_time(lambda: ident.estimate(W, y, 1.0, prior), repeats)
    Wu, yu, pu = W * f / c, y * f, (prior[0] * c, prior[1] * c)
    t_units, box_u = median_time(lambda: ident.estimate(Wu, yu, f, pu), repeats)
    rng = np.random.default_rng(2)
    rel = 1e-12
    b = rel * float(np.abs(W @ theta).max())
    yt = W @ theta + rng.uniform(-1.0, 1.0, n) * b
    t_tight, box_t = median_time(lambda: ident.estimate(W, yt, b, prior), repeats)
    w = box.upper - box.lower
    diff = np.maximum(np.abs(box_u.lower / c - box.lower), np.abs(box_u.upper / c - box.upper))
    return {"N": n, "si_s": t_si, "units_s": t_units, "units_ratio": t_units / t_si,
            "units_max_diff_over_width": float(np.max(diff / w)), "tight_s": t_tight, "tight_ratio": t_tight / t_si,
            "tight_width_over_bound": float(np.mean(box_t.upper - box_t.lower) / b),
            "tight_encloses": bool(box_t.contains(theta).all())}


def bench_big(n: int) -> dict:
    W, y, theta = make_data(n, seed=1)
    prior = (np.zeros(P), 2.0 * np.ones(P))
    t_lstsq, _ = median_time(lambda: np.linalg.lstsq(W, y, rcond=None), 3)
    tracemalloc.start()
    t0 = time.perf_counter()
    box = ident.estimate(W, y, 1.0, prior, method="hull")
    seconds = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        "N": n,
        "hull_s": seconds,
        "lstsq_s": t_lstsq,
        "hull_ratio": seconds / t_lstsq,
        "peak_over_W": peak / W.nbytes,
        "W_MB": W.nbytes / 2**20,
        "hull_width": float(box.width.mean()),
        "hull_encloses": bool(box.contains(theta).all()),
        "working_rows": box.info["working_rows"],
        "lp_iterations": box.info["lp_iterations"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[4000, 40000, 400000])
    ap.add_argument("--big", type=int, default=1_000_000, help="rows for the hull-only run (0 to skip)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="sizes 4000 40000 and no big run")
    ap.add_argument("--json", action="store_true", help="print the results as JSON instead of a table")
    ap.add_argument("--threads", type=int, default=None,
                    help="BLAS threads (default: the library's own choice); 1 gives steadier timings on a busy machine")
    args = ap.parse_args(argv)

    if args.quick:
        args.sizes, args.big = [4000, 40000], 0
    load_before = os.getloadavg()[0]
    rows = [bench_size(n, args.repeats) for n in args.sizes]
    units = bench_units(args.sizes[0], args.repeats)
    big = bench_big(args.big) if args.big else None
    load_after = os.getloadavg()[0]
    if args.json:
        print(json.dumps({"sizes": rows, "units": units, "big": big, "load_average": [load_before, load_after]}, indent=2))
        return 0
    print(f"p = {P}, noise U[-1, 1], bound 1, prior [0, 2]^{P}; times are medians of {args.repeats} runs, "
          f"ratios to numpy.linalg.lstsq in the same run (load average {load_before:.2f} -> {load_after:.2f} on "
          f"{os.cpu_count()} cores: other processes distort timings)")
    head = f"{'N':>9} {'lstsq s':>9} {'hull x':>8} {'cgsp x':>8} {'wls x':>7} {'hull width':>11} {'cgsp width':>11} {'cgsp/hull':>10}  enclosed"
    print(head)
    for r in rows:
        print(f"{r['N']:>9} {r['lstsq_s']:>9.4f} {r['hull_ratio']:>8.2f} {r['cgsp_ratio']:>8.2f} {r['wls_ratio']:>7.2f} "
              f"{r['hull_width']:>11.3e} {r['cgsp_width']:>11.3e} {r['width_ratio_cgsp_over_hull']:>10.0f}  "
              f"{r['hull_encloses'] and r['cgsp_encloses']}")
    u = units
    print(f"hull at N = {u['N']} in other units: {u['units_ratio']:.2f}x the SI time, endpoints differ by at most "
          f"{u['units_max_diff_over_width']:.1e} widths; at a 1e-12 relative bound: {u['tight_ratio']:.2f}x the SI time, "
          f"mean width {u['tight_width_over_bound']:.2f} bounds, encloses truth: {u['tight_encloses']}")
    if big:
        print(f"hull at N = {big['N']}: {big['hull_s']:.2f} s ({big['hull_ratio']:.2f}x lstsq = {big['lstsq_s']:.2f} s), "
              f"peak traced memory {big['peak_over_W']:.2f}x W ({big['W_MB']:.0f} MB), mean width {big['hull_width']:.3e}, "
              f"{big['working_rows']} working rows, {big['lp_iterations']} LP iterations, encloses truth: {big['hull_encloses']}")
        forty = [r for r in rows if r["N"] == 40000]
        verdict = [
            ("hull at 40 000 within 10x lstsq", forty[0]["hull_ratio"] <= 10 if forty else None),
            ("hull at 10^6 under 10 s", big["hull_s"] < 10),
            ("peak memory under 3x W", big["peak_over_W"] < 3),
        ]
        print("targets: " + "; ".join(f"{k}: {'n/a' if v is None else ('met' if v else 'MISSED')}" for k, v in verdict))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
