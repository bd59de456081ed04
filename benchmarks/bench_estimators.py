"""Cost of every registered estimator, as ratios to numpy.linalg.lstsq on the same data in the same run.

    python benchmarks/bench_estimators.py [--sizes 4000 40000 400000] [--repeats 5] [--threads 1] [--cap 30]
                                          [--data h4|gauss] [--methods all|a,b] [--campaign-runs 2] [--big N]
                                          [--json]
    python benchmarks/bench_estimators.py --quick      (sizes 4000 40000, 3 repeats, no campaign)

BLAS threads: pinned to ``--threads`` (default 1) through OPENBLAS_NUM_THREADS, OMP_NUM_THREADS and
MKL_NUM_THREADS before numpy loads; printed with the run. On a shared 2-core machine a multi-threaded BLAS
competing with other processes makes the timings (and the hull's blocked passes over W) erratic, so the
default is one thread for every method and for lstsq alike.

Data (``--data h4``, the default): the H4 regressor (paper eqs. 14-18, :func:`ident.regressor`) on a smooth
multi-sine nacelle motion in the workspace (five harmonics per axis, 1 kHz samples, N / 4 samples), the
truth the nominal parameters, torque errors uniform in [-1, 1] N m, bound 1 N m, prior [0, 3 x nominal].
``--data gauss``: W (N, 14) standard normal, truth uniform in [0.5, 1.5], errors uniform in [-1, 1], bound 1,
prior [0, 2]^14. Rows carry their joint (``groups``, row 4k + i -> i) and the noise-free regressor is the
instrument matrix (``instruments``), so every method receives its context.

For each N: every estimator of :func:`ident.estimators.registry.available` and lstsq, interleaved repeats
(so that all see the same machine load), median time of each over ``--repeats`` runs and its ratio to the
median lstsq time; the box's mean width and whether it encloses the truth; also the hull's 2p LPs alone
(``interval_hull`` from the least-squares centre, row "hull LPs"). A method whose first run at a
size, or whose time extrapolated linearly from the previous size, exceeds ``--cap`` seconds is skipped at
that size and above (and said so). Then the campaign throughput: runs of the ``enclosure`` campaign
(``--quick`` spec: 3 s trajectories; the job function timed directly) with each built-in method alone and
with all of them, runs per minute (the run's simulation and processing included). ``--big N``: the hull
alone at N rows, its time and peak traced memory relative to W.
Target: the exact hull at N = 40 000 at most 3x lstsq.
"""

from __future__ import annotations

import os
import sys

if __name__ == "__main__":  # BLAS threads: fixed before numpy is imported (default one thread)
    _threads = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "1"
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_var] = _threads

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402

import _setup  # noqa: E402,F401  (repository root on sys.path)
import numpy as np  # noqa: E402

from h4bench import ident  # noqa: E402
from h4bench.ident.estimators import registry  # noqa: E402
from h4bench.ident.estimators.estimate import least_squares_center  # noqa: E402
from h4bench.ident.estimators.hull import interval_hull, strip_bounds  # noqa: E402

P = 14
HULL_LPS = "hull LPs"  # the row of interval_hull alone: the 2p LPs from the least-squares centre


def h4_data(n_rows: int, seed: int = 0):
    """The H4 equation on a multi-sine motion: ``(W, y, truth, prior, instruments)`` with ``n_rows // 4`` samples."""
    from h4bench import sim
    from h4bench.ident.robots.h4 import NOMINAL_PARAMETERS
    from h4bench.trajectories.fourier import joint_motion

    geometry = sim.H4Geometry.from_model(sim.load_model())
    n = n_rows // 4
    t = np.arange(n) * 1e-3
    rng = np.random.default_rng(seed)
    amp = np.array([0.06, 0.06, 0.08, 0.25])  # [m, m, m, rad]: within the H4's workspace around home
    x = np.tile(geometry.x_home, (n, 1))
    xd, xdd = np.zeros((n, 4)), np.zeros((n, 4))
    for k in range(1, 6):
        w = 2 * np.pi * 0.2 * k * (1 + 0.1 * np.arange(4))
        phase = rng.uniform(0, 2 * np.pi, 4)
        a = amp / k / 2
        s, c = np.sin(w * t[:, None] + phase), np.cos(w * t[:, None] + phase)
        x, xd, xdd = x + a * s, xd + a * w * c, xdd - a * w**2 * s
    m = joint_motion(geometry, x, xd, xdd)
    W = ident.regressor(geometry, m["q"], m["qd"], m["qdd"])
    theta = np.array(NOMINAL_PARAMETERS)
    y = W @ theta + rng.uniform(-1.0, 1.0, W.shape[0])
    return W, y, theta, (np.zeros(P), 3.0 * theta), W


def gauss_data(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((n, P))
    theta = rng.uniform(0.5, 1.5, P)
    y = W @ theta + rng.uniform(-1.0, 1.0, n)
    return W, y, theta, (np.zeros(P), 2.0 * np.ones(P)), W


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def bench_size(n: int, data: str, estimators, repeats: int, cap: float, skipped: dict, last: dict) -> dict:
    """One size: lstsq and every estimator not skipped, interleaved repeats; medians, ratios, widths."""
    W, y, theta, (lo, hi), Z = (h4_data if data == "h4" else gauss_data)(n)
    prior = ident.Box(lo, hi, tuple(f"theta{j + 1}" for j in range(P)))
    groups = np.arange(W.shape[0]) % 4
    n = W.shape[0]
    runs = {"lstsq": lambda: np.linalg.lstsq(W, y, rcond=None)}
    if HULL_LPS not in skipped and any(e.name == "hull" for e in estimators):  # the 2p LPs alone (no checks)
        bl, bu = strip_bounds(y, np.ones(n))
        center = least_squares_center(W.T @ W, W, y, lo, hi)
        runs[HULL_LPS] = lambda: interval_hull(W, bl, bu, lo, hi, scale=np.ones(n), center=center)
    for est in estimators:
        if est.name in skipped:
            continue
        if est.name in last and last[est.name][1] * n / last[est.name][0] > cap:
            skipped[est.name] = f"skipped from N = {n}: {last[est.name][1]:.1f} s at N = {last[est.name][0]}, " \
                                f"extrapolated {last[est.name][1] * n / last[est.name][0]:.0f} s > cap {cap:g} s"
            continue
        runs[est.name] = (lambda e=est: registry.call(e, W, y, 1.0, prior, groups=groups, instruments=Z))
    times = {k: [] for k in runs}
    out, errors = {}, {}
    runs["lstsq"]()  # warm-up (first-touch pages, BLAS initialisation)
    for r in range(repeats):
        for name, fn in list(runs.items()):
            if name in errors:
                continue
            try:
                t, out[name] = _timed(fn)
            except Exception as exc:  # a method that fails is reported, never costs the others
                errors[name] = f"{type(exc).__name__}: {exc}"
                continue
            times[name].append(t)
            if r == 0 and name != "lstsq" and t > cap:
                skipped[name] = f"skipped after one run at N = {n}: {t:.1f} s > cap {cap:g} s"
                runs.pop(name)
    t_lstsq = statistics.median(times["lstsq"])
    row = {"N": n, "lstsq_s": t_lstsq, "methods": {}}
    for name in runs:
        if name == "lstsq":
            continue
        if name in errors:
            row["methods"][name] = {"error": errors[name]}
            continue
        box = out[name]
        med = statistics.median(times[name])
        if name == HULL_LPS:  # a HullResult, not a Box
            row["methods"][name] = {"seconds": med, "ratio": med / t_lstsq, "runs": len(times[name]),
                                    "mean_width": float(np.mean(box.upper - box.lower)),
                                    "encloses": bool(np.all((box.lower <= theta) & (theta <= box.upper))),
                                    "lp_iterations": box.info["lp_iterations"], "lp_solves": box.info["lp_solves"]}
            continue
        last[name] = (n, med)
        row["methods"][name] = {"seconds": med, "ratio": med / t_lstsq, "runs": len(times[name]),
                                "mean_width": float(np.mean(box.upper - box.lower)),
                                "encloses": bool(np.all((box.lower <= theta) & (theta <= box.upper)))}
    for name, m in row["methods"].items():
        if "mean_width" in m and "hull" in row["methods"] and "mean_width" in row["methods"]["hull"]:
            m["width_vs_hull"] = m["mean_width"] / row["methods"]["hull"]["mean_width"]
    return row


def bench_big(n: int, data: str) -> dict:
    """The hull alone at ``n`` rows: time against lstsq, peak traced memory relative to ``W.nbytes``."""
    W, y, theta, (lo, hi), _ = (h4_data if data == "h4" else gauss_data)(n, seed=1)
    t_lstsq = statistics.median(_timed(lambda: np.linalg.lstsq(W, y, rcond=None))[0] for _ in range(3))
    tracemalloc.start()
    seconds, box = _timed(lambda: ident.estimate(W, y, 1.0, (lo, hi), method="hull"))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"N": W.shape[0], "hull_s": seconds, "lstsq_s": t_lstsq, "hull_ratio": seconds / t_lstsq,
            "peak_over_W": peak / W.nbytes, "W_MB": W.nbytes / 2**20, "working_rows": box.info["working_rows"],
            "lp_iterations": box.info["lp_iterations"],
            "encloses": bool(np.all((box.lower <= theta) & (theta <= box.upper)))}


def bench_campaign(runs: int, names) -> dict:
    """Runs per minute of the ``enclosure`` campaign (``--quick`` spec) with each method alone and all together
    (all those that ran alone: a method the campaign cannot feed, e.g. one that needs instruments, is reported)."""
    from h4bench.scenarios.kinds.enclosure import campaign_job
    from h4bench.scenarios.registry import load_spec

    spec = load_spec("enclosure", quick=True)
    campaign_job({**spec, "estimators": {**spec["estimators"], "methods": ["hull"]}}, 0, spec["seed"])  # designs cached
    out = {}
    for label in list(names) + ["all"]:
        methods = [label] if label != "all" else [m for m in names if "error" not in out[m]]  # all that ran alone
        s = {**spec, "estimators": {**spec["estimators"], "methods": methods}}
        total, per_method = 0.0, {}
        try:
            for i in range(runs):
                t, res = _timed(lambda: campaign_job(s, i, spec["seed"]))
                total += t
                for k, v in res["methods"].items():
                    per_method.setdefault(k, []).append(v.get("seconds") or 0.0)
        except Exception as exc:
            out[label] = {"error": f"{type(exc).__name__}: {exc}"}
            continue
        out[label] = {"runs_per_minute": 60.0 * runs / total, "seconds_per_run": total / runs,
                      "method_seconds": {k: statistics.median(v) for k, v in per_method.items()}}
    return out


def _blas() -> str:
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return f"threads {os.environ.get('OPENBLAS_NUM_THREADS', '?')} (environment; threadpoolctl not installed)"
    info = [f"{d.get('internal_api')} {d.get('num_threads')} thread(s)" for d in threadpool_info()]
    return ", ".join(info) or "no BLAS found by threadpoolctl"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[4000, 40000, 400000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cap", type=float, default=30.0, help="seconds: a method slower than this at a size is skipped")
    ap.add_argument("--data", choices=("h4", "gauss"), default="h4")
    ap.add_argument("--campaign-runs", type=int, default=2, help="runs of the enclosure campaign per method (0: none)")
    ap.add_argument("--big", type=int, default=0, help="rows of a hull-only run with peak memory (0: none)")
    ap.add_argument("--methods", default="all", help="comma-separated estimator names (default all registered)")
    ap.add_argument("--quick", action="store_true", help="sizes 4000 40000, 3 repeats, no campaign")
    ap.add_argument("--json", action="store_true", help="print the results as JSON instead of tables")
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1; set before numpy loads)")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.repeats, args.campaign_runs = [4000, 40000], 3, 0

    found = registry.available()
    estimators = list(found.estimators)
    if args.methods != "all":
        wanted = args.methods.split(",")
        known = {e.name for e in estimators}
        estimators = [e for e in estimators if e.name in wanted] + [registry.get(m) for m in wanted if m not in known]
    load_before = os.getloadavg()[0]
    skipped: dict = {}
    last: dict = {}
    rows = [bench_size(n, args.data, estimators, args.repeats, args.cap, skipped, last) for n in args.sizes]
    builtin = [e.name for e in estimators if e.origin == "built-in"]
    campaign = bench_campaign(args.campaign_runs, builtin) if args.campaign_runs and builtin else None
    big = bench_big(args.big, args.data) if args.big else None
    load_after = os.getloadavg()[0]
    result = {"big": big, "data": args.data, "threads": args.threads, "blas": _blas(), "repeats": args.repeats,
              "cap_s": args.cap, "sizes": rows, "skipped": skipped, "broken": [list(b) for b in found.broken],
              "campaign": campaign,
              "load_average": [load_before, load_after]}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"data {args.data}, p = {P}, bound 1, errors U[-1, 1]; BLAS: {result['blas']}; medians of {args.repeats} "
          f"interleaved runs; x = time / lstsq time at the same N (load average {load_before:.2f} -> "
          f"{load_after:.2f} on {os.cpu_count()} cores: other processes distort timings)")
    names = [e.name for e in estimators] + ([HULL_LPS] if any(HULL_LPS in r["methods"] for r in rows) else [])
    print(f"{'method':>14} " + " ".join(f"{'N=' + str(r['N']):>26}" for r in rows))
    print(f"{'lstsq':>14} " + " ".join(f"{r['lstsq_s'] * 1e3:>23.2f} ms" for r in rows))
    for name in names:
        cells = []
        for r in rows:
            m = r["methods"].get(name)
            if m is None:
                cells.append(f"{'skipped':>26}")
            elif "error" in m:
                cells.append(f"{'error':>26}")
            else:
                enc = "" if m["encloses"] else " MISS"
                cells.append(f"{m['seconds'] * 1e3:>9.1f} ms {m['ratio']:>7.2f}x{enc:>5}   ")
        print(f"{name:>14} " + " ".join(cells))
    print("mean width / hull's: " + "; ".join(
        f"{name} " + " ".join(f"{r['methods'][name]['width_vs_hull']:.3g}" for r in rows
                              if "width_vs_hull" in r["methods"].get(name, {})) for name in names
        if name not in ("hull", HULL_LPS)))
    for r in rows:
        for name, m in r["methods"].items():
            if "error" in m:
                print(f"error at N = {r['N']}: {name}: {m['error']}")
    for name, why in skipped.items():
        print(f"{name}: {why}")
    for name, why in found.broken:
        print(f"broken plugin {name}: {why}")
    forty = [r for r in rows if r["N"] == 40000 and "ratio" in r["methods"].get("hull", {})]
    if forty:
        ratio = forty[0]["methods"]["hull"]["ratio"]
        lps = forty[0]["methods"].get(HULL_LPS, {}).get("ratio", float("nan"))
        print(f"target: hull at N = 40 000 at most 3x lstsq: ident.estimate {ratio:.2f}x "
              f"({'met' if ratio <= 3 else 'MISSED'}), its LPs alone {lps:.2f}x")
    if big:
        print(f"hull at N = {big['N']}: {big['hull_s']:.2f} s ({big['hull_ratio']:.2f}x lstsq = "
              f"{big['lstsq_s']:.2f} s), "
              f"peak traced memory {big['peak_over_W']:.2f}x W ({big['W_MB']:.0f} MB), {big['working_rows']} working "
              f"rows, {big['lp_iterations']} LP iterations, encloses truth: {big['encloses']}")
    if campaign:
        print(f"campaign throughput (enclosure --quick, {args.campaign_runs} runs each, simulation included):")
        for label, c in campaign.items():
            if "error" in c:
                print(f"  {label:>14}: error {c['error']}")
                continue
            ms = ", ".join(f"{k} {v:.3f} s" for k, v in c["method_seconds"].items())
            print(f"  {label:>14}: {c['runs_per_minute']:6.1f} runs/min ({c['seconds_per_run']:.2f} s/run; median "
                  f"estimator time {ms})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
