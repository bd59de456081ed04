"""Speed of a serial arm's certified equation (:func:`ident.robots.serial_certified.certified_equation`).

A 12 s, 1 kHz log of an analytic sum-of-sines motion (exact q, qd, qdd and exact motion bounds, as in
``tests/ident/test_serial_certified.py``), torques ``robot.regressor(q, qd, qdd) @ theta`` at the sample
instants, positions rounded to 2^17 counts per turn. For each kernel (80, 200, 400 steps) at stride 20: the
vectorised equation against the per-window reference (``reference=True``, the previous implementation) in the
same run, medians over repeats of the wall and the CPU time and their ratios, the largest difference of their
outputs (over each output's largest entry) and the memory peak of the vectorised one (tracemalloc in a separate run: numpy's allocations).

    python benchmarks/bench_serial_equation.py --urdf PATH/ur5_robot.urdf [--urdf PATH/panda.urdf]
        [--seconds 12] [--kernels 80 200 400] [--stride 20] [--repeats 3] [--reference-repeats 1]

A URDF with prismatic joints (the Panda's fingers) is copied with those joints fixed. Without ``--urdf`` the
UR5 and the Panda of the ``example-robot-data`` package are used if it is installed.

Measured (one process per robot, ``--repeats 3 --reference-repeats 1``, on 2 cores shared with other jobs at a
load of 12-27: the CPU seconds are the figures to read, the wall times swing with the load):

    robot  kernel  rows  CPU new [s]  CPU reference [s]  ratio  peak [MB]  largest difference
    UR5        80  3576         14.4               24.3    1.7         88  1.3e-03 (terms.float)
    UR5       200  3540         16.3               29.0    1.8        126  1.1e-03 (terms.float)
    UR5       400  3480         17.7               36.4    2.1        149  9.1e-04 (terms.float)
    Panda      80  4172         23.3               35.1    1.5        131  1.4e-03 (terms.float)
    Panda     200  4130         26.0               39.8    1.5        144  1.2e-03 (terms.float)
    Panda     400  4060         29.3               49.1    1.7        200  1.0e-03 (terms.float)

The floor of both is pinocchio at each step's own arguments (``2 + 2 n + n (n - 1) / 2 + n (3 n + 2)`` calls a
step, 149 for the UR5 and 198 for the Panda, about 4-5 us each: 8 s and 12 s of CPU on 12 000 steps); the rest
of the vectorised one is numpy over the steps (about a quarter) and over the windows' steps (a fifth at L = 400).
Differences over each output's largest entry: ``y``, ``bound``, the torque-side and Coulomb terms 0; ``parts``,
``terms.position``, ``terms.motion`` at most 2.3e-15; ``Wc`` 1.5e-13 (L = 400); ``D`` 3.5e-12, through
``terms.float``, larger by the rebuilt regressor's rounding bound (:mod:`ident.robots.serial_steps`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sysconfig
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.robots.serial import SerialRobot
from h4bench.ident.robots.serial_certified import certified_equation
from h4bench.scenarios.arm_log import fixed_fingers_urdf

COUNTS = 2**17
DT = 1e-3


def synthetic_log(robot: SerialRobot, seconds: float, seed: int = 0):
    """(q_meas, tau, spec): sums of three sines per joint, torques at the sample instants from the standard
    regressor at the URDF's parameters plus friction, rotor inertia and offsets; exact motion bounds; the torque
    rate bound from 4 points per sample step with a 1.5 margin."""
    n = robot.n_joints
    rng = np.random.default_rng(seed)
    om = np.array([1.3, 2.9, 5.1]) * 2 * np.pi / 3
    a = rng.uniform(0.1, 0.4, (n, 3))
    ph = rng.uniform(0, 2 * np.pi, (n, 3))
    c = rng.uniform(-1, 1, n)

    def traj(t):
        arg = om[None, None, :] * np.asarray(t)[:, None, None] + ph[None]
        return (c + (a * np.sin(arg)).sum(-1), (a * om * np.cos(arg)).sum(-1), -(a * om**2 * np.sin(arg)).sum(-1))

    extras = {k: rng.uniform(lo, hi, n) for k, lo, hi in (("fv", 0.5, 3), ("Ia", 0.01, 0.3), ("off", -0.5, 0.5))
              if f"{k}1" in robot.names}
    theta = robot.urdf_parameters(extras)
    N = int(round(seconds / DT)) + 1
    q, qd, qdd = traj(np.arange(N) * DT)
    tau = (robot.regressor(q, qd, qdd) @ theta).reshape(N, n)
    res = 2 * np.pi / COUNTS
    q_meas = np.round(q / res) * res
    tf = np.linspace(0, seconds, 4 * N)
    tauf = (robot.regressor(*traj(tf)) @ theta).reshape(-1, n)
    rate = 1.5 * np.max(np.abs(np.diff(tauf, axis=0)), axis=0) / (tf[1] - tf[0])
    spec = ErrorSpec(n_joints=n, sample_period=DT, position_resolution=res, torque_error=0.5,
                     torque_timing="sample", torque_rate=rate, qd_max=(a * om).sum(1), qdd_max=(a * om**2).sum(1))
    return q_meas, tau, spec


def _timed(fn, repeats: int):
    """Medians of the wall and the CPU time of this process [s] (on a shared machine the CPU time is the steadier
    measure of the work; both are reported), and the last result."""
    wall, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu), out


def _max_rel(a, b) -> float:
    """Largest |a - b| over the array's largest magnitude (per output: a scale-relative difference)."""
    scale = max(float(np.max(np.abs(b))), 1e-300)
    return float(np.max(np.abs(a - b))) / scale


def _compare(new, old) -> dict:
    out = {k: _max_rel(getattr(new, k), getattr(old, k)) for k in ("Wc", "D", "y", "bound")}
    out.update({f"terms.{k}": _max_rel(new.terms[k], old.terms[k]) for k in new.terms})
    out.update({f"parts.{k}": _max_rel(new.parts[k], old.parts[k]) for k in new.parts})
    return out


def run(urdf: Path, seconds: float, kernels, stride: int, repeats: int, ref_repeats: int) -> list[dict]:
    robot = SerialRobot(urdf)
    base = robot.base()
    q, tau, spec = synthetic_log(robot, seconds)
    rows = []
    for L in kernels:
        kw = {"half_width": L // 2, "stride": stride}
        t_new, c_new, new = _timed(lambda: certified_equation(robot, base, q, tau, spec, **kw), repeats)
        tracemalloc.start()  # a separate run: tracing slows the allocations down
        certified_equation(robot, base, q, tau, spec, **kw)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        t_old, c_old, old = _timed(lambda: certified_equation(robot, base, q, tau, spec, reference=True, **kw),
                                   ref_repeats)
        rows.append({"robot": urdf.stem, "joints": robot.n_joints, "base": len(base), "kernel": L, "stride": stride,
                     "rows": len(new), "new_s": t_new, "reference_s": t_old, "ratio": t_old / t_new,
                     "new_cpu_s": c_new, "reference_cpu_s": c_old, "cpu_ratio": c_old / c_new,
                     "peak_MB": peak / 2**20, "max_rel_diff": _compare(new, old)})
        r = rows[-1]
        worst = max(r["max_rel_diff"].items(), key=lambda kv: kv[1])
        print(f"{r['robot']:>12} n={r['joints']} kernel {L:>3} stride {stride}: {r['rows']} rows, wall new {t_new:.1f} s"
              f" reference {t_old:.1f} s ratio {r['ratio']:.1f}x; CPU new {c_new:.1f} s reference {c_old:.1f} s ratio "
              f"{r['cpu_ratio']:.1f}x; peak {r['peak_MB']:.0f} MB; largest difference {worst[1]:.1e} ({worst[0]})",
              flush=True)
    return rows


def _default_urdfs() -> list[Path]:
    """The UR5 and the Panda of the ``example-robot-data`` wheel (installed under the environment's cmeel.prefix)."""
    root = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
    return [p for p in (root / "ur_description/urdf/ur5_robot.urdf", root / "panda_description/urdf/panda.urdf")
            if p.exists()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--urdf", type=Path, action="append")
    parser.add_argument("--seconds", type=float, default=12.0)
    parser.add_argument("--kernels", type=int, nargs="+", default=[80, 200, 400])
    parser.add_argument("--stride", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--reference-repeats", type=int, default=1)
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args()
    urdfs = args.urdf or _default_urdfs()
    if not urdfs:
        raise SystemExit("give --urdf PATH (or pip install example-robot-data)")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for urdf in urdfs:
            rows += run(fixed_fingers_urdf(urdf, Path(tmp) / urdf.name), args.seconds, args.kernels, args.stride, args.repeats,
                        args.reference_repeats)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
