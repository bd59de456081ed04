"""The hull LPs with and without the per-solve budgets of ``ident.numerics.lp.LPModel``: time, limit hits, boxes.

    python benchmarks/bench_lp_budget.py [--problems tx40,h4] [--samples 0] [--rows 40000] [--refine 1]
                                         [--repeats 3] [--threads 1] [--no-unlimited] [--json]
    python benchmarks/bench_lp_budget.py --quick      (tx40 with refine 0, h4 on 8 000 rows, 2 repeats)

Problems:

* ``tx40``: the certified (Oettli-Prager) equation of the real Staubli TX40 log (``data/tx40``, a 6-joint serial
  arm) on its first ``--samples`` samples at 5 kHz (default all 45 000: 2 676 rows x 61 base parameters), with the ``tx40 --error-model derived`` scenario's
  specification and kernel (half-width 200, stride 100), its base parameters and physical prior; the box is
  ``signed_uncertain_hull(..., refine=--refine)`` (the path of ``h4bench identify --urdf --spec``). The
  equation is cached in ``$H4BENCH_CACHE/bench_lp_budget/`` (building it takes minutes).
* ``h4``: the H4 regressor on a multi-sine motion (``bench_estimators.h4_data``, ``--rows`` rows, bound 1 N m),
  the hull's 2p LPs alone (``interval_hull`` from the least-squares centre).

Variants, run interleaved (the same machine load), ``--repeats`` times each; medians and ratios to ``unlimited``:

* ``budget``: the default per-solve budgets (``LPModel.budgets``: iterations and seconds from the model's size);
* ``unlimited``: no budget (HiGHS's defaults: no iteration or time limit; a stuck solve would hang it, which is
  what the budget prevents; ``--no-unlimited`` skips it);
* ``budget+dual``: the budgets, and a re-solve after added rows (same cost) runs the dual simplex
  (``LPModel(dual_after_rows=True)``, set through ``ident.estimators.hull.DUAL_AFTER_ROWS``).

Each row: median seconds, ratio, LP runs, total simplex iterations, the largest iterations of one run, limit hits,
retries, fallbacks, and the largest endpoint difference to the ``budget`` box relative to its width. The budgets
(module constants of ``ident.numerics.lp``) are printed with the largest budget any model had.
"""

from __future__ import annotations

import os
import sys

if __name__ == "__main__":  # BLAS threads: fixed before numpy is imported (default one thread)
    _threads = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "1"
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_var] = _threads

import argparse  # noqa: E402
import contextlib  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import _setup  # noqa: E402,F401  (repository root on sys.path)
import numpy as np  # noqa: E402

from h4bench import ident  # noqa: E402
from h4bench.ident.estimators import hull as hull_module  # noqa: E402
from h4bench.ident.numerics import lp  # noqa: E402

VARIANTS = ("budget", "unlimited", "budget+dual")


def tx40_problem(samples: int) -> dict:
    """The TX40 certified equation on the log's first ``samples`` samples (cached): Wc, D, y, bound, prior."""
    from h4bench.sim.design_cache import cache_root

    path = cache_root() / "bench_lp_budget" / f"tx40_{samples or 'all'}.npz"
    if path.is_file():
        d = np.load(path)
        return {k: d[k] for k in d.files}
    from h4bench.ident.robots import tx40
    from h4bench.ident.robots.serial_certified import certified_equation
    from h4bench.scenarios.tx40_certified import DEFAULTS, error_spec, joint_position_error

    log, robot = tx40.load_log(), tx40.robot()
    base = robot.base(200, 0)
    spec = error_spec(DEFAULTS["error_model"])
    n = log.q.shape[0] if not samples else min(samples, log.q.shape[0])
    cc = DEFAULTS["certified"]
    eq = certified_equation(robot, base, log.q[:n], log.tau[:n], spec, half_width=cc["half_width"],
                            stride=cc["stride"], position_error=joint_position_error(spec, log.q_motor[:n]))
    lo, hi = base.box_from_standard(*tx40.standard_prior(robot))
    out = {"Wc": eq.Wc, "D": eq.D, "y": eq.y, "bound": eq.bound, "lo": lo, "hi": hi}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    tmp.replace(path)
    return out


def runner(name: str, args):
    """``(description, run)``: run() returns (lower, upper) of the problem's box."""
    if name == "tx40":
        from h4bench.ident.estimators.uncertain_signed import signed_uncertain_hull

        d = tx40_problem(args.samples)
        prior = ident.Box(d["lo"], d["hi"])
        desc = f"tx40 certified equation, {d['Wc'].shape[0]} rows x {d['Wc'].shape[1]} parameters, refine {args.refine}"

        def run():
            box = signed_uncertain_hull(d["Wc"], d["D"], d["y"], d["bound"], prior, refine=args.refine, rtol=0.02)
            return box.lower, box.upper
        return desc, run
    from bench_estimators import h4_data

    from h4bench.ident.estimators.estimate import least_squares_center

    W, y, _, (lo, hi), _ = h4_data(args.rows)
    bl, bu = hull_module.strip_bounds(y, np.ones(W.shape[0]))
    center = least_squares_center(W.T @ W, W, y, lo, hi)

    def run():
        res = hull_module.interval_hull(W, bl, bu, lo, hi, scale=np.ones(W.shape[0]), center=center)
        return res.lower, res.upper
    return f"h4 regressor, {W.shape[0]} rows x {W.shape[1]} parameters, the hull's 2p LPs", run


class _Recorder:
    """Wraps ``LPModel._run`` and ``LPModel.solve``: per-run iterations, the counters, the largest budgets."""

    def __init__(self):
        self.runs: list[int] = []
        self.totals = dict.fromkeys(("lp_limit_hits", "lp_retries", "lp_fallbacks"), 0)
        self.budget = (0, 0.0)

    @contextlib.contextmanager
    def active(self):
        run, solve, rec = lp.LPModel._run, lp.LPModel.solve, self

        def wrapped_run(model, *a, **k):
            rec.budget = max(rec.budget, model.budgets())
            ms, it = run(model, *a, **k)
            rec.runs.append(it)
            return ms, it

        def wrapped_solve(model, *a, **k):
            before = model.counters()
            try:
                return solve(model, *a, **k)
            finally:
                for key in rec.totals:
                    rec.totals[key] += model.counters()[key] - before[key]
        lp.LPModel._run, lp.LPModel.solve = wrapped_run, wrapped_solve
        try:
            yield self
        finally:
            lp.LPModel._run, lp.LPModel.solve = run, solve


@contextlib.contextmanager
def variant(name: str):
    """The module settings of one variant, restored afterwards."""
    saved = (lp.ITERATIONS_FLOOR, lp.ITERATIONS_PER_LINE, lp.SECONDS_FLOOR, hull_module.DUAL_AFTER_ROWS)
    if name == "unlimited":
        lp.ITERATIONS_FLOOR, lp.ITERATIONS_PER_LINE, lp.SECONDS_FLOOR = 2**31 - 1, 0, float("inf")
    hull_module.DUAL_AFTER_ROWS = name == "budget+dual"
    try:
        yield
    finally:
        lp.ITERATIONS_FLOOR, lp.ITERATIONS_PER_LINE, lp.SECONDS_FLOOR, hull_module.DUAL_AFTER_ROWS = saved


def bench(name: str, args) -> dict:
    desc, run = runner(name, args)
    names = [v for v in VARIANTS if not (args.no_unlimited and v == "unlimited")]
    times = {v: [] for v in names}
    stats, boxes = {}, {}
    for _ in range(args.repeats):
        for v in names:
            rec = _Recorder()
            with variant(v), rec.active():
                t0 = time.perf_counter()
                boxes[v] = run()
                times[v].append(time.perf_counter() - t0)
            stats[v] = {"lp_runs": len(rec.runs), "iterations": int(sum(rec.runs)),
                        "max_run_iterations": max(rec.runs, default=0), **rec.totals,
                        "largest_budget": [int(rec.budget[0]), rec.budget[1]]}
    ref_lo, ref_hi = boxes["budget"]
    width = np.maximum(ref_hi - ref_lo, 1e-300)
    out = {"problem": desc, "variants": {}}
    base = statistics.median(times["unlimited"]) if "unlimited" in times else None
    for v in names:
        med = statistics.median(times[v])
        lo_, hi_ = boxes[v]
        diff = float(np.max(np.maximum(np.abs(lo_ - ref_lo), np.abs(hi_ - ref_hi)) / width))
        out["variants"][v] = {"median_seconds": med, "seconds": times[v], "ratio_to_unlimited":
                              None if base is None else med / base, "box_difference_to_budget": diff, **stats[v]}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problems", default="tx40,h4")
    ap.add_argument("--samples", type=int, default=0, help="tx40 log samples (5 kHz; 0: all 45 000)")
    ap.add_argument("--rows", type=int, default=40_000, help="h4 rows")
    ap.add_argument("--refine", type=int, default=1, help="tx40: refinement rounds of the signed hull")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", default="1")
    ap.add_argument("--no-unlimited", action="store_true")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.refine, args.rows, args.repeats = 0, 8_000, 2
    print(f"budgets: max({lp.ITERATIONS_FLOOR}, {lp.ITERATIONS_PER_LINE} (m + n)) iterations, "
          f"max({lp.SECONDS_FLOOR:g}, {lp.SECONDS_PER_ENTRY:g} m n) s per HiGHS run; {args.repeats} repeats, "
          f"BLAS threads {args.threads}")
    results = {}
    for name in args.problems.split(","):
        r = results[name] = bench(name, args)
        print(f"\n{r['problem']}")
        print(f"  {'variant':>12} {'median s':>9} {'ratio':>6} {'runs':>6} {'iters':>8} {'max/run':>8} {'hits':>5} "
              f"{'retries':>7} {'fallbk':>6} {'box diff':>9}  largest budget")
        for v, s in r["variants"].items():
            ratio = "-" if s["ratio_to_unlimited"] is None else f"{s['ratio_to_unlimited']:.2f}"
            print(f"  {v:>12} {s['median_seconds']:9.2f} {ratio:>6} {s['lp_runs']:6d} {s['iterations']:8d} "
                  f"{s['max_run_iterations']:8d} {s['lp_limit_hits']:5d} {s['lp_retries']:7d} {s['lp_fallbacks']:6d} "
                  f"{s['box_difference_to_budget']:9.2g}  {s['largest_budget'][0]} it, {s['largest_budget'][1]:g} s")
    if args.json:
        print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
