"""Regressor speed: W(q, qd, qdd) for 10^5 samples (paper eqs. 14-18, forward kinematics included).

Reference measured in the same run: the same function called sample by sample in a Python loop (on a
subset, scaled to the same count). Medians over repeats.

    python benchmarks/bench_regressor.py [--samples 100000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from h4bench import ident
from h4bench import sim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    geometry = sim.H4Geometry.from_model(sim.load_model())
    rng = np.random.default_rng(0)
    n = args.samples
    x = geometry.x_home + rng.uniform(-1, 1, (n, 4)) * np.array([0.08, 0.08, 0.1, 0.3])
    q = sim.inverse_kinematics(geometry, x)
    qd, qdd = rng.uniform(-3, 3, (n, 4)), rng.uniform(-50, 50, (n, 4))

    vec = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        w = ident.regressor(geometry, q, qd, qdd)
        vec.append(time.perf_counter() - t0)
    m = min(n, 500)
    loop = []
    for _ in range(max(1, args.repeats // 2)):
        t0 = time.perf_counter()
        for k in range(m):
            ident.regressor(geometry, q[k], qd[k], qdd[k])
        loop.append((time.perf_counter() - t0) * n / m)
    t_vec, t_loop = statistics.median(vec), statistics.median(loop)
    assert w.shape == (4 * n, 14)
    print(f"regressor for {n} samples ({w.shape[0]} x {w.shape[1]}), median of {args.repeats}")
    print(f"per-sample loop (reference, scaled from {m} samples): {t_loop:.3f} s")
    print(f"vectorised: {t_vec:.3f} s = {t_vec / n * 1e6:.2f} us/sample; speed-up over the loop {t_loop / t_vec:.0f}x")


if __name__ == "__main__":
    main()
