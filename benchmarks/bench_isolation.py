"""What it costs to keep an estimator from changing its inputs, at 10^6 rows (W 10^6 x 14), measured in one run:
a read-only view, a copy of W, y and bound, the checksums (:mod:`ident.estimators.door`: one pass over the
inputs before the call, one after it, both in the child), and a whole isolated call of a plugin that returns its prior (fork,
checksums, result over a pipe), against the exact hull on the same rows as the reference.

    python benchmarks/bench_isolation.py [--rows 1000000] [--repeat 3]

Prints the median wall time of each and its ratio to the hull.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from h4bench import ident
from h4bench.ident.estimators import door, isolation


def prior_plugin(W, y, bound, prior):
    """A plugin that does nothing: what remains is the isolation's own cost."""
    return prior


def _median(f, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    p = 14
    W = rng.normal(size=(args.rows, p))
    theta = rng.uniform(0.5, 1.5, p)
    y = W @ theta + rng.uniform(-1, 1, args.rows)
    bound = np.full(args.rows, 1.0)
    prior = ident.Box(np.zeros(p), np.full(p, 2.0))
    inputs = {"W": W, "y": y, "bound": bound}
    rows = {
        "read-only views": lambda: [isolation.readonly(a) for a in inputs.values()],
        "copies": lambda: [a.copy() for a in inputs.values()],
        "checksums (one pass)": lambda: door.checksums(inputs),
        "isolated plugin call (fork)": lambda: isolation.call(prior_plugin, W, y, bound, prior),
        "hull (in process)": lambda: isolation.call("hull", W, y, bound, prior),
    }
    times = {k: _median(f, args.repeat) for k, f in rows.items()}
    ref = times["hull (in process)"]
    print(f"W {W.shape[0]} x {p} ({W.nbytes / 1e6:.0f} MB), median of {args.repeat}")
    for k, t in times.items():
        print(f"{k:30s} {t * 1e3:10.3f} ms   {t / ref:8.4f} x hull")


if __name__ == "__main__":
    main()
