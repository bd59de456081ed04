"""h4bench from Python, cell by cell (a notebook's steps as a script): simulate the H4, identify its 14 parameters
with a guaranteed box, project the feasible set onto a pair of parameters, plot it.

    python examples/python_api.py [--seconds 4] [--out runs/python-api]

Every function used here is in the API reference (docs/api/*.md): the public names of ``h4bench.sim``,
``h4bench.trajectories`` and ``h4bench.ident``, plus the H4's processed equation
(``h4bench.ident.robots.h4_equation.build_equation``) and the projections
(``h4bench.ident.estimators.projection.projections``). About 10-30 s for a 4 s experiment.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=4.0, help="length of the experiment [s]")
    ap.add_argument("--out", type=Path, default=Path("runs/python-api"), help="folder of the plot")
    args = ap.parse_args(argv)

    # %% 1. the robot: the MuJoCo model of the H4 and its geometry (dimensions read from the compiled model)
    from h4bench import ident, sim, trajectories

    model = sim.load_model()
    geometry = sim.H4Geometry.from_model(model)

    # %% 2. an exciting trajectory (a Fourier series in the nacelle's pose, checked against the limits; the
    # feasible start of the optimiser, to be quick: `optimise=True` designs it)
    reference = trajectories.fourier_excitation(geometry, duration=args.seconds, harmonics=4, base_hz=0.75,
                                                seed=0, optimise=False)

    # %% 3. the closed-loop experiment at 1 kHz: a joint controller and a feed-forward designed from the NOMINAL
    # parameters (never the truth), a structured drive error bounded by 1.3 N m, a 20000-count encoder
    nominal = trajectories.nominal_parameters()
    _, controller = sim.default_controller(geometry, nominal)
    feedforward = ident.inverse_dynamics(geometry, nominal, reference.q, reference.qd, reference.qdd)
    dataset, truth = sim.simulate(model, reference, noise=sim.realistic_drive(1.3), controller=controller,
                                  feedforward=feedforward, seed=0,
                                  settings=sim.SimulationSettings(encoder_counts=20000))
    print(f"simulated {len(dataset)} samples at {1 / dataset.dt:.0f} Hz")

    # %% 4. the paper's processing (filtering, decimation, speed threshold) with the bound propagated, then the
    # exact hull of the feasible set: an outer box of every theta with |y - W theta| <= bound on every row
    from h4bench.ident.processing.filtering import ProcessingSettings
    from h4bench.ident.robots.h4_equation import build_equation

    settings = ProcessingSettings(dt=dataset.dt, position_cutoff_hz=50.0, decimation=2, numtaps=41, fir_cutoff=0.04,
                                  speed_threshold=0.5)
    prior = ident.Box(np.zeros(14), np.full(14, 2.0), ident.PARAMETER_NAMES)
    equation = build_equation(geometry, dataset, 1.3 + 0.2, settings, prior=prior)  # noise bound + allowance
    box = ident.estimate(equation.W, equation.y, equation.bound, prior, method="hull")
    inside = (box.lower <= truth.theta) & (truth.theta <= box.upper)
    for name, lo, hi, true in zip(box.names, box.lower, box.upper, truth.theta):
        print(f"{name:6s} [{lo:9.4g}, {hi:9.4g}]  true {true:.4g}")
    print(f"truth enclosed: {int(inside.sum())} of {inside.size}")

    # %% 5. the feasible set is a polytope; its projection onto Fv1 (viscous) and Fs1 (Coulomb) of joint 1
    from h4bench.ident.estimators.projection import projections

    (polygon,), info = projections(equation.W, equation.y, equation.bound, box, pairs=[("Fv1", "Fs1")])
    print(f"projection Fv1:Fs1: {len(polygon.vertices)} vertices, {info['lp_solves']} LPs")

    # %% 6. the plot: the polygon, the hull box, the truth
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    i, j = polygon.indices
    fig, ax = plt.subplots(figsize=(4.5, 3.6))
    v = np.vstack([polygon.vertices, polygon.vertices[:1]])
    ax.fill(v[:, 0], v[:, 1], alpha=0.3, label="feasible set (outer polygon)")
    ax.plot([box.lower[i], box.upper[i], box.upper[i], box.lower[i], box.lower[i]],
            [box.lower[j], box.lower[j], box.upper[j], box.upper[j], box.lower[j]], "k--", label="hull box")
    ax.plot(truth.theta[i], truth.theta[j], "r*", ms=10, label="truth")
    ax.set_xlabel(f"{polygon.parameters[0]} [N m s/rad]")
    ax.set_ylabel(f"{polygon.parameters[1]} [N m]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out / "projection.png", dpi=100)
    plt.close(fig)
    summary = {"samples": len(dataset), "rows": len(equation), "enclosed": int(inside.sum()),
               "parameters": int(inside.size), "plot": str(args.out / "projection.png"),
               "polygon_vertices": int(len(polygon.vertices))}
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
