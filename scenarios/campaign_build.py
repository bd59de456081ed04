"""A campaign's experiments: run ``index``'s spec (:func:`campaign_spec`) and its simulated experiment
(:func:`campaign_experiment`). The engine that runs them is :mod:`scenarios.campaign`."""

from __future__ import annotations

import copy
import time

from h4bench import sim

__all__ = ["campaign_experiment", "campaign_spec"]


def campaign_spec(spec: dict, index: int) -> dict:
    """The spec of run ``index``: the index's noise shape (cycling through ``campaign.noise_shapes``)."""
    spec_i = copy.deepcopy(spec)
    shapes = spec["campaign"]["noise_shapes"]
    spec_i["noise"]["shape"] = shapes[index % len(shapes)]
    return spec_i


def campaign_experiment(spec: dict, index: int, base_seed: int, estimate: bool = True):
    """The experiment of run ``index``: seed ``base_seed + index`` (noise, randomised true parameters), the
    index's noise shape, and the trajectory of seed ``base_seed + index % campaign.trajectories`` (one per run
    when 0; a few designed trajectories shared by many runs keep campaigns fast, the design being cached).
    Returns (ExperimentRun, noise shape)."""
    from h4bench.scenarios.experiment import run_experiment, traced_reference

    seed = base_seed + index
    spec_i = campaign_spec(spec, index)
    path = spec["model"] or None
    spread = spec["campaign"]["parameter_spread"]
    t0 = time.perf_counter()
    model = sim.randomised_model(seed, spread, path) if spread > 0 else sim.load_model(path)
    t_model = time.perf_counter() - t0
    n_traj = spec["campaign"]["trajectories"]
    reference, source = None, None
    t0 = time.perf_counter()
    if n_traj:
        geometry = sim.H4Geometry.from_model(model)
        reference, source = traced_reference(spec_i, geometry, base_seed + index % n_traj)
    t_traj = time.perf_counter() - t0
    run = run_experiment(spec_i, seed, model=model, model_path=path, reference=reference, estimate=estimate)
    run.timings["model"] = t_model
    if source is not None:
        run.timings["trajectory"] += t_traj
        run.timings["trajectory_source"] = source
    return run, spec_i["noise"]["shape"]
