"""Closed-loop simulation speed: seconds of simulated robot per second of wall time at 1 kHz.

Reference measured in the same run: bare MuJoCo stepping of the same model (the same number of
``mj_step`` calls from the same initial state, replaying the closed loop's applied torques open-loop: the
same motion, no controller, no recording). Medians over repeats (noisy machines). The closed loop is
``sim.simulate`` (controller, encoder, noise stream, recording at every 1 kHz sample). Wall time and this
process's CPU time are both printed: on a shared machine the CPU time is the one that does not depend on the
other processes.

    python benchmarks/bench_sim.py [--seconds 10] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
import types

import mujoco
import numpy as np

from h4bench import ident
from h4bench import sim


def reference_trajectory(geometry, seconds: float, dt: float = 1e-3):
    t = np.arange(int(round(seconds / dt))) * dt
    s = np.clip(t / 0.5, 0, 1)
    amp = np.array([0.05, 0.05, 0.07, 0.2])
    x = geometry.x_home + amp * (s * s * (3 - 2 * s))[:, None] * np.sin(2 * np.pi * np.array([0.4, 0.6, 0.5, 0.7]) * t[:, None])
    q = sim.inverse_kinematics(geometry, x)
    qd = np.gradient(q, dt, axis=0)
    return types.SimpleNamespace(t=t, q=q, qd=qd, qdd=np.gradient(qd, dt, axis=0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    model = sim.load_model()
    geometry = sim.H4Geometry.from_model(model)
    nominal = np.asarray(ident.NOMINAL_PARAMETERS)
    ref = reference_trajectory(geometry, args.seconds)
    ff = ident.inverse_dynamics(geometry, nominal, ref.q, ref.qd, ref.qdd)
    steps = int(round(args.seconds / model.opt.timestep))

    bare, loop, bare_cpu, loop_cpu = [], [], [], []
    for _ in range(args.repeats):
        _, controller = sim.default_controller(geometry, nominal)
        t0, c0 = time.perf_counter(), time.process_time()
        _, truth = sim.simulate(model, ref, noise=sim.TorqueNoise(1.0), controller=controller, feedforward=ff,
                                seed=0)
        loop.append(time.perf_counter() - t0)
        loop_cpu.append(time.process_time() - c0)

        data = mujoco.MjData(model)
        data.qpos[:] = geometry.qpos(ref.q[0], sim.forward_kinematics(geometry, ref.q[0]))
        mujoco.mj_forward(model, data)
        torques = truth.tau_applied[:, None, :].repeat(steps // len(ref.t), axis=1).reshape(-1, 4)
        ctrl = data.ctrl
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(steps):
            ctrl[:] = torques[k]
            mujoco.mj_step(model, data)
        bare.append(time.perf_counter() - t0)
        bare_cpu.append(time.process_time() - c0)
    t_bare, t_loop = statistics.median(bare), statistics.median(loop)
    c_bare, c_loop = statistics.median(bare_cpu), statistics.median(loop_cpu)
    print(f"simulated {args.seconds:g} s at 1 kHz ({steps} MuJoCo steps of {model.opt.timestep * 1e3:g} ms), "
          f"median of {args.repeats}")
    print(f"bare mj_step:  {t_bare:.3f} s wall -> {args.seconds / t_bare:.1f}x real time; "
          f"CPU {c_bare:.3f} s -> {args.seconds / c_bare:.1f}x (reference)")
    print(f"closed loop:   {t_loop:.3f} s wall -> {args.seconds / t_loop:.1f}x real time; "
          f"CPU {c_loop:.3f} s -> {args.seconds / c_loop:.1f}x (sim.simulate)")
    print(f"ratio closed loop / bare stepping: wall {t_loop / t_bare:.2f}, CPU {c_loop / c_bare:.2f}")


if __name__ == "__main__":
    main()
