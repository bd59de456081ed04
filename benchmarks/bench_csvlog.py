"""Reading a robot log: sim.csvlog (pyarrow, numpy's C parser in blocks) against numpy.genfromtxt, the generic
reader sim.Dataset.from_csv used before, measured in the same run on the same file.

    python benchmarks/bench_csvlog.py [--rows 1000000] [--repeat 3]

Prints, per reader, the median wall time and the growth of the peak resident memory of a fresh process
(``ru_maxrss`` after the read minus before it, libraries already imported), and both as ratios to genfromtxt.
The log is synthetic (seeded random walk for q, noise for tau, 17 significant digits as a logger writes them).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

READERS = {
    "arrow": "from h4bench.sim.csvlog import read_log; read_log(path, engine='arrow')",
    "numpy-blocks": "from h4bench.sim.csvlog import read_log; read_log(path, engine='numpy')",
    "genfromtxt": "np.genfromtxt(path, delimiter=',', skip_header=1, dtype=float, ndmin=2)",
}

CHILD = """
import resource, sys, time
import numpy as np, pyarrow.csv, sim.csvlog
path = sys.argv[1]
r0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
{stmt}
dt = time.perf_counter() - t0
print(dt, (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - r0) * 1024)
"""


def write_log(path: Path, rows: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    t = np.arange(rows) * 1e-3
    q = np.cumsum(rng.normal(scale=1e-3, size=(rows, 4)), axis=0)
    tau = rng.normal(size=(rows, 4))
    with path.open("w") as fh:
        fh.write("t,q1,q2,q3,q4,tau1,tau2,tau3,tau4\n")
        for k in range(0, rows, 100_000):
            np.savetxt(fh, np.column_stack([t, q, tau])[k:k + 100_000], delimiter=",", fmt="%.17g")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "log.csv"
        write_log(path, args.rows)
        size = path.stat().st_size
        print(f"{args.rows} rows, {size / 1e6:.0f} MB of text; result arrays {72 * args.rows / 1e6:.0f} MB")
        res = {}
        for name, stmt in READERS.items():
            runs = [subprocess.run([sys.executable, "-c", CHILD.format(stmt=stmt), str(path)], cwd=root, check=True,
                                   capture_output=True, text=True).stdout.split() for _ in range(args.repeat)]
            res[name] = (statistics.median(float(r[0]) for r in runs), statistics.median(int(r[1]) for r in runs))
        ref_t, ref_m = res["genfromtxt"]
        for name, (t, m) in res.items():
            print(f"{name:13s} {t:7.2f} s ({t / ref_t:5.2f} x genfromtxt)   peak growth {m / 1e6:7.0f} MB "
                  f"({m / size:5.2f} x file, {m / ref_m:5.2f} x genfromtxt)")


if __name__ == "__main__":
    main()
