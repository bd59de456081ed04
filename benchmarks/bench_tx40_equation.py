"""Speed of the TX40's certified equations (``h4bench run tx40 --error-model derived``): the chain regressor against
pinocchio's calls, in the same run.

The two equations of the study's certified stage (:func:`scenarios.tx40_certified.certify`: the identification part,
the first 2/3 of the log, and the held-out part, each ``certified_equation`` with the study's kernel, the position
error of the motor angles' five digits, ``processes`` as the run uses), timed with the batched chain regressor
(:mod:`ident.robots.chain`, the default) and with pinocchio's regressor called once per evaluation (the code before
it, :func:`ident.robots.serial_steps._pinocchio_calls`), alternating, ``--repeats`` times each. Prints the medians,
their ratio, and the largest difference of the two equations' row radii (the same bounds from regressors that
differ in their last bits).

    python benchmarks/bench_tx40_equation.py [--repeats 3] [--processes 2] [--samples 0]

Measured at 56795d0 (``--repeats 2``, 2 cores, nothing else running; 30 000 + 15 000 samples, 1776 + 876 rows):

    chain regressor   25.9 s  (27.9, 23.8)
    pinocchio calls   57.2 s  (60.6, 53.9)
    ratio chain / pinocchio: 0.452
    largest relative difference of the row bounds 0; of Wc against |Wc| + D 5.2e-13 and 5.9e-13

The row bounds do not involve the regressor; the centres differ in their last bits (the two regressors' rounding),
far inside the rows' radii. f2be299's code (pinocchio's calls, all 360 regressor entries) took 50.7 and 53.3 s on
the same equations in the same session.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import _setup  # noqa: F401  (the repository on sys.path, --threads)

from h4bench.ident.robots import serial_steps, tx40  # noqa: E402
from h4bench.ident.robots.serial_certified import certified_equation  # noqa: E402
from h4bench.scenarios import tx40_certified as tc  # noqa: E402
from h4bench.scenarios.registry import load_spec  # noqa: E402


CFG: dict = {}


def equations(robot, base, log, spec, n, n1, processes):
    cc = CFG["certified"]
    kw = {"half_width": int(cc["half_width"]), "stride": int(cc["stride"]), "processes": processes}
    e = tc.joint_position_error(spec, log.q_motor[:n])
    eq = certified_equation(robot, base, log.q[:n1], log.tau[:n1], spec, position_error=e[:n1], **kw)
    sl = slice(n1, n)
    eq_ho = certified_equation(robot, base, log.q[sl], log.tau[sl], spec, position_error=e[sl], first_sample=n1,
                               **kw)
    return eq, eq_ho


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--processes", type=int, default=2, choices=(1, 2))
    ap.add_argument("--samples", type=int, default=0, help="the log's first samples only (0: as the scenario)")
    args = ap.parse_args()
    cfg = load_spec("tx40")["tx40"]
    CFG.update(cfg)
    log = tx40.load_log()
    robot = tx40.robot()
    base = robot.base(int(cfg["base_samples"]), 0)
    spec = tc.error_spec(cfg["error_model"])
    n = log.q.shape[0] if not (args.samples or cfg["samples"]) else min(args.samples or int(cfg["samples"]),
                                                                          log.q.shape[0])
    n1 = round(cfg["identify_fraction"] * n)
    if args.processes == 2:
        from h4bench.ident.workers import prewarm

        prewarm(2)
    times = {"chain": [], "pinocchio": []}
    out = {}
    chain = serial_steps.robot_chain(robot)
    for rep in range(args.repeats):
        for name in ("chain", "pinocchio"):
            # the robot carries its chain (None: pinocchio's calls), to the worker process too
            robot._chain_cache = chain if name == "chain" else None
            t0 = time.perf_counter()
            out[name] = equations(robot, base, log, spec, n, n1, args.processes)
            times[name].append(time.perf_counter() - t0)
            print(f"repeat {rep + 1}: {name} {times[name][-1]:.1f} s", flush=True)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"\nTX40 certified equations ({n1} + {n - n1} samples, {len(out['chain'][0])} + {len(out['chain'][1])} "
          f"rows, {args.processes} process(es), median of {args.repeats}):")
    print(f"  chain regressor   {med['chain']:.1f} s")
    print(f"  pinocchio calls   {med['pinocchio']:.1f} s")
    print(f"  ratio chain / pinocchio: {med['chain'] / med['pinocchio']:.3f}")
    for k, (a, b) in enumerate(zip(out["chain"], out["pinocchio"])):
        rel = np.max(np.abs(a.bound - b.bound) / np.maximum(np.abs(b.bound), 1e-300))
        dW = np.max(np.abs(a.Wc - b.Wc) / (np.abs(b.Wc) + b.D + 1e-300))
        print(f"  equation {k}: largest relative difference of the row bounds {rel:.2e}, of Wc against |Wc| + D "
              f"{dW:.2e}")


if __name__ == "__main__":
    main()
