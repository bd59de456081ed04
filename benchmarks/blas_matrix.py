"""Same seed, same numbers under every BLAS kernel and thread count? Designs and quick paper runs, each in a
fresh process with ``OPENBLAS_CORETYPE`` and ``OPENBLAS_NUM_THREADS`` set, side by side.

    python benchmarks/blas_matrix.py [--seeds 0 7] [--duration 4] [--max-iter N] [--paper]
                                     [--kernels Haswell SandyBridge] [--threads 1 2] [--processes 4] [--json]

Per seed and setting: the content hash (:func:`trajectories.excitation.content_hash`, first 8 hex digits) and
the h criterion (``max_relative`` of :func:`trajectories.design_criterion`) of the paper's design
(``trajectories.design_excitation`` with the spec's limits, processing, harmonics and fundamental, ``cache=False``)
of ``--duration`` seconds; with ``--paper`` instead, ``h4bench run paper --quick --seed S`` in a fresh design
cache (so it designs its 4 s trajectory itself): its ``content_hashes`` (trajectory, controller, feed-forward,
dataset) and the hull box (Imot1 lower bound and a hash of every bound). ``--processes`` settings run at once. A kernel the CPU cannot run (e.g. SkylakeX without AVX-512) ends its process with
SIGILL: check ``architecture`` in threadpoolctl's report, or the ``platform`` entry of a result.json. One value
per column means the setting does not matter.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_DESIGN = """
import json, sys
from h4bench import sim, trajectories as tj
from h4bench.scenarios.spec import load_spec
from h4bench.trajectories.excitation import content_hash
seed, duration, max_iter = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
spec = load_spec("paper")
tr = spec["trajectory"]
geometry = sim.H4Geometry.from_model(sim.load_model(sim.DEFAULT_MODEL_PATH))
opts = {} if max_iter == "default" else {"max_iter": int(max_iter)}
traj = tj.design_excitation(geometry, duration=duration, seed=seed, limits=tj.Limits.h4_class(), criterion="h",
                            processing=dict(spec["processing"]), harmonics=tr["harmonics"], base_hz=tr["base_hz"],
                            cache=False, **opts)
from h4bench.trajectories.fourier import as_processing
crit = tj.design_criterion(geometry, traj, as_processing(dict(spec["processing"]), traj.parameters["dt"]))
print(json.dumps({"hash": content_hash(traj), "h": crit["max_relative"],
                  "smooth_max": traj.parameters["optimisation"]["criterion_optimised"]}))
"""


def environment(kernel: str, threads: int, cache: str | None = None) -> dict:
    """The environment of a child process: the kernel and thread count set explicitly (an environment that
    already sets OPENBLAS_CORETYPE or OPENBLAS_L2_SIZE is overridden)."""
    env = dict(os.environ, OPENBLAS_CORETYPE=kernel, OPENBLAS_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    env.pop("OPENBLAS_L2_SIZE", None)
    if cache is not None:
        env["H4BENCH_CACHE"] = cache
    return env


def design(seed: int, duration: float, max_iter, kernel: str, threads: int) -> dict:
    """The design of one seed under one setting, in a fresh process: {"hash", "h", "smooth_max"}."""
    out = subprocess.run([sys.executable, "-c", _DESIGN, str(seed), str(duration), str(max_iter)], check=True,
                         capture_output=True, text=True, env=environment(kernel, threads), cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def box_digest(lower, upper) -> str:
    """SHA-256 of a box's bounds as exact hex floats (first 8 digits are shown)."""
    return hashlib.sha256(json.dumps([[float(v).hex() for v in lower], [float(v).hex() for v in upper]])
                          .encode()).hexdigest()


def paper(seed: int, kernel: str, threads: int) -> dict:
    """``h4bench run paper --quick --seed S`` in a fresh process and design cache: content hashes and hull box."""
    with tempfile.TemporaryDirectory(prefix="h4-blas-") as tmp:
        out = Path(tmp) / "run"
        subprocess.run([sys.executable, "-m", "h4bench", "run", "paper", "--quick", "--seed", str(seed), "--out",
                        str(out), "--json"], check=True, capture_output=True, text=True,
                       env=environment(kernel, threads, cache=str(Path(tmp) / "cache")), cwd=ROOT)
        result = json.loads((out / "result.json").read_text())
    hull = result["methods"]["hull"]
    return {**result.get("content_hashes", {}), "imot1_lower": hull["lower"][0],
            "box": box_digest(hull["lower"], hull["upper"]),
            "verdicts": {m: [v.get("enclosed"), v.get("unsound")] for m, v in result["methods"].items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 7])
    parser.add_argument("--duration", type=float, default=4.0, help="design duration [s] (the quick paper's: 4)")
    parser.add_argument("--max-iter", default="default", help="SLSQP iterations (default: the design's)")
    parser.add_argument("--paper", action="store_true", help="also run h4bench run paper --quick per setting")
    parser.add_argument("--kernels", nargs="+", default=["Haswell", "SandyBridge"])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--processes", type=int, default=4, help="settings run at once (default 4)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    jobs = [(seed, k, t) for seed in args.seeds for k in args.kernels for t in args.threads]

    def one(job):
        seed, kernel, threads = job
        row = {"seed": seed, "kernel": kernel, "threads": threads}
        if args.paper:  # the paper run designs its own trajectory in a fresh cache: its hash is the design's
            row["paper"] = p = paper(seed, kernel, threads)
            row["design"] = {"hash": p["trajectory"]}
            line = (f"seed {seed} {kernel:>11}/{threads}: trajectory {p['trajectory'][:8]} controller "
                    f"{p['controller'][:8]} feed-forward {str(p['feedforward'])[:8]} dataset {p['dataset'][:8]} "
                    f"Imot1 lower {p['imot1_lower']!r} box {p['box'][:8]}")
        else:
            row["design"] = d = design(seed, args.duration, args.max_iter, kernel, threads)
            line = f"seed {seed} {kernel:>11}/{threads}: design {d['hash'][:8]} h {d['h']:.6f}"
        print(line, file=sys.stderr, flush=True)
        return row

    with ThreadPoolExecutor(max_workers=max(1, args.processes)) as pool:
        rows = list(pool.map(one, jobs))
    for seed in args.seeds:
        mine = [r for r in rows if r["seed"] == seed]
        designs = {r["design"]["hash"] for r in mine}
        boxes = {r["paper"]["box"] for r in mine} if args.paper else set()
        print(f"seed {seed}: {len(designs)} design hash(es)" + (f", {len(boxes)} hull box(es)" if args.paper else ""))
    if args.json:
        print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
