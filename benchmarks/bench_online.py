"""Online hull against real time and against the batch hull, measured in the same run.

    python benchmarks/bench_online.py [--duration 10] [--chunks-ms 10 100] [--synthetic] [--seed 0] [--threads 1]

Data: a simulated H4 experiment (the paper scenario's trajectory, 1 kHz, 20000-count encoder, torque noise
+-1 N m) processed WITHOUT the parallel filter, so that every sample gives 4 rows as it arrives (an online
FIR would delay each row by half its length; here rows are streamed as soon as their derivatives exist).
Raw rows carry larger derivative errors than filtered ones, so the assumed raw bound is 3 N m (noise 1 +
allowance 2; the run reports the oracle residual beside it). ``--synthetic`` streams H4-like random rows
instead (p = 14, columns scaled like the H4's, noise +-1, bound 1), no MuJoCo needed.

For each chunk length (default 10 ms = 40 rows and 100 ms = 400 rows): every chunk is passed to
``OnlineHull.update``; the median and max update time are reported against the chunk's real-time duration
(it keeps up when the update time is below it; the largest backlog of a queue fed in real time says how far
behind the stream it ever falls), and the final box against ``ident.estimate`` (the batch hull on
all rows, timed in the same run): ratio of mean widths, the largest endpoint difference, and whether the online
box contains the batch box. At checkpoints the online box is also checked against the batch hull of the rows
seen so far.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import _setup  # noqa: F401  (BLAS threads, repository root; before numpy)
import numpy as np  # noqa: E402

from h4bench import ident  # noqa: E402
from h4bench.ident.estimators.online import OnlineHull  # noqa: E402

P = 14
DT = 1e-3


def simulated(duration: float, seed: int):
    """Raw rows (time order) of a simulated H4 experiment: W, y, bound, sample index of each row, theta_true."""
    from h4bench.scenarios.experiment import run_experiment
    from h4bench.scenarios.spec import load_spec

    spec = load_spec("paper")
    spec["trajectory"]["duration"] = float(duration)
    spec["processing"].update({"decimation": 1, "numtaps": 1})
    spec["bound"]["allowance"] = 2.0
    spec["replay"]["enabled"] = False
    run = run_experiment(spec, seed, estimate=False)
    eq = run.equation
    info = {"source": "simulated H4 (paper trajectory, raw rows)", "oracle_residual": float(np.abs(run.residual).max()),
            "bound": float(eq.bound.max())}
    return eq.W, eq.y, eq.bound, eq.sample, run.prior, run.theta_true, info


def synthetic(duration: float, seed: int):
    """H4-like random rows: 4 per sample, columns scaled like the H4's (qdd ~ 30, J^T(xdd - G) ~ 3, qd ~ 2,
    sign ~ 1), smooth in time (sums of sines), noise uniform in +-1, bound 1."""
    rng = np.random.default_rng(seed)
    n = int(round(duration / DT))
    t = np.arange(n) * DT
    f = rng.uniform(0.2, 2.5, (P, 3))
    ph = rng.uniform(0, 2 * np.pi, (P, 3))
    scale = np.array([30.0] * 4 + [3.0, 30.0] + [2.0] * 4 + [1.0] * 4)
    base = np.einsum("pk,npk->np", np.ones((P, 3)), np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None]))
    W = (base[:, None, :] * scale * rng.uniform(0.5, 1.5, (1, 4, P))).reshape(-1, P)
    theta = np.asarray(ident.NOMINAL_PARAMETERS)
    y = W @ theta + rng.uniform(-1.0, 1.0, W.shape[0])
    prior = ident.Box(np.zeros(P), 2.0 * np.ones(P))
    sample = np.repeat(np.arange(n), 4)
    return W, y, np.ones(W.shape[0]), sample, prior, theta, {"source": "synthetic H4-like rows", "bound": 1.0}


def stream(W, y, b, sample, prior, chunk_samples: int, checkpoints: int = 4) -> dict:
    hull = OnlineHull(prior)
    chunk_id = sample // chunk_samples
    starts = np.flatnonzero(np.r_[True, np.diff(chunk_id) != 0])
    ends = np.r_[starts[1:], W.shape[0]]
    times, resolved = [], []
    check_at = set(np.linspace(0, len(starts) - 1, checkpoints + 1).round().astype(int)[1:-1].tolist())
    checks = []
    box = hull.box
    for c, (s, e) in enumerate(zip(starts, ends)):
        t0 = time.perf_counter()
        box = hull.update(W[s:e], y[s:e], b[s:e])
        times.append(time.perf_counter() - t0)
        resolved.append(len(box.info["resolved"]))
        if c in check_at:
            batch = ident.estimate(W[:e], y[:e], b[:e], prior)
            checks.append({"rows": int(e), "contains_batch": bool(np.all(box.lower <= batch.lower + 1e-9)
                                                                 and np.all(box.upper >= batch.upper - 1e-9)),
                           "width_ratio": float(np.mean(box.width) / np.mean(batch.width))})
    t0 = time.perf_counter()
    batch = ident.estimate(W, y, b, prior)
    batch_seconds = time.perf_counter() - t0
    real = chunk_samples * DT
    lag, max_lag = 0.0, 0.0  # a queue fed in real time: how far behind the stream the estimator ever falls
    for t in times:
        lag = max(0.0, lag + t - real)
        max_lag = max(max_lag, lag)
    return {
        "chunk_ms": 1e3 * real, "chunks": len(times), "rows_per_chunk_median": float(np.median(ends - starts)),
        "update_ms_median": 1e3 * statistics.median(times), "update_ms_max": 1e3 * max(times),
        "update_ms_p95": 1e3 * float(np.percentile(times, 95)),
        "median_over_real_time": statistics.median(times) / real, "max_over_real_time": max(times) / real,
        "chunks_over_real_time": int(np.sum(np.asarray(times) > real)),
        "keeps_up_median": statistics.median(times) < real,
        "max_backlog_ms": 1e3 * max_lag, "keeps_up_overall": float(sum(times)) < len(times) * real,
        "total_online_s": float(sum(times)), "batch_hull_s": batch_seconds,
        "endpoints_resolved_mean": float(np.mean(resolved)),
        "final_width_ratio_online_over_batch": float(np.mean(box.width) / np.mean(batch.width)),
        "final_max_endpoint_difference": float(max(np.abs(box.lower - batch.lower).max(),
                                                   np.abs(box.upper - batch.upper).max())),
        "final_contains_batch": bool(np.all(box.lower <= batch.lower + 1e-9) and np.all(box.upper >= batch.upper - 1e-9)),
        "checkpoints": checks, "lp_solves": hull.stats["lp_solves"],
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of data at 1 kHz")
    ap.add_argument("--chunks-ms", type=float, nargs="+", default=[10.0, 100.0])
    ap.add_argument("--synthetic", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None, help="BLAS threads (set before numpy loads)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results to this file")
    args = ap.parse_args(argv)
    W, y, b, sample, prior, theta, info = (synthetic if args.synthetic else simulated)(args.duration, args.seed)
    out = {"data": {**info, "rows": int(W.shape[0]), "duration_s": args.duration}, "runs": []}
    print(f"{info['source']}: {W.shape[0]} rows over {args.duration:g} s, bound {info['bound']:.3g}"
          + (f", oracle residual {info['oracle_residual']:.3g}" if "oracle_residual" in info else ""))
    for ms in args.chunks_ms:
        res = stream(W, y, b, sample, prior, max(1, int(round(ms * 1e-3 / DT))))
        out["runs"].append(res)
        print(f"chunk {res['chunk_ms']:.0f} ms (~{res['rows_per_chunk_median']:.0f} rows): update median "
              f"{res['update_ms_median']:.2f} ms, p95 {res['update_ms_p95']:.2f} ms, max {res['update_ms_max']:.2f} ms "
              f"-> median/real time {res['median_over_real_time']:.3f}, max/real time {res['max_over_real_time']:.3f} "
              f"({res['chunks_over_real_time']} of {res['chunks']} chunks slower than real time, largest backlog "
              f"{res['max_backlog_ms']:.1f} ms); final width "
              f"online/batch {res['final_width_ratio_online_over_batch']:.6f}, max endpoint diff "
              f"{res['final_max_endpoint_difference']:.2e}, contains batch {res['final_contains_batch']}; "
              f"total online {res['total_online_s']:.2f} s vs one batch hull {res['batch_hull_s']:.2f} s")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
