"""One experiment, end to end: trajectory -> closed-loop simulation -> processing -> estimators -> checks.

The ground truth is read here only to *check* (enclosure, oracle residual, error budget), never passed to an
estimator. The controller and the feed-forward are designed from the nominal (a priori) parameters.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from h4bench import fingerprint, ident
from h4bench import sim
from h4bench.fingerprint import array_digest
from h4bench.ident.processing.filtering import ProcessingSettings
from h4bench.ident.robots.h4_equation import Equation, build_equation, raw_equation
from h4bench.ident.estimators import isolation, registry
from h4bench.scenarios import judging
from h4bench.scenarios.budget import error_budget
from h4bench.scenarios.explain import width_analysis


@dataclass
class ExperimentRun:
    """Everything one experiment produced (in memory); :meth:`result` is its JSON-able summary."""

    spec: dict
    seed: int
    model_path: str
    model: object
    geometry: sim.H4Geometry
    theta_true: np.ndarray
    reference: object
    dataset: sim.Dataset
    truth: sim.GroundTruth
    settings: ProcessingSettings
    equation: Equation
    prior: ident.Box
    bound_raw: float
    boxes: dict = field(default_factory=dict)  # method -> Box
    failures: dict = field(default_factory=dict)  # method -> message (e.g. inconsistent data)
    outcomes: dict = field(default_factory=dict)  # method -> scenarios.judging.Outcome
    hull_ref: object = None  # scenarios.judging.HullReference of the exact hull (None: no hull box)
    claims: dict = field(default_factory=dict)  # a kind's own box (not a registry method) -> (kind, rigorous)
    seconds: dict = field(default_factory=dict)
    wls: object = None
    min_consistent_bound: float = float("nan")
    budget: dict = field(default_factory=dict)
    controller_report: str = ""
    timings: dict = field(default_factory=dict)
    width_analysis: dict | None = None
    noise_bound: float = 0.0
    noise_description: dict = field(default_factory=dict)
    content_hashes: dict = field(default_factory=dict)  # stage -> SHA-256 (:func:`content_hashes`)

    @property
    def residual(self) -> np.ndarray:
        """Oracle residual ``y - W theta_true`` on the rows the estimators saw (m,) [N m]."""
        return self.equation.y - self.equation.W @ self.theta_true

    def result(self) -> dict:
        eq = self.equation
        r = np.abs(self.residual)
        names = list(eq.names)
        outcomes = dict(self.outcomes)
        for name in (*self.boxes, *self.failures):  # a kind's own boxes (e.g. the relaxed hull of the outliers)
            if name not in outcomes:
                kind, rigorous = self.claims.get(name, ("guaranteed", False))
                est = registry.Estimator(name, name, kind, rigorous, origin="scenario")
                ok = name in self.boxes
                outcomes[name] = judging.Outcome(name, est, "ok" if ok else "inconsistent", self.boxes.get(name),
                                                 None if ok else self.failures[name], self.seconds.get(name, 0.0))
        t0 = time.perf_counter()
        methods = judging.judge(outcomes, self.hull_ref, self.theta_true, names)
        self.timings["judging"] = time.perf_counter() - t0
        self.timings["methods"] = dict(self.seconds)
        out = {
            "scenario": self.spec["name"],
            "kind": self.spec["kind"],
            "seed": self.seed,
            "model": self.model_path,
            "quick": self.spec.get("quick_applied", False),
            "parameters": names,
            "units": list(ident.parameter_units(self.spec["structure"]["regressor"])),
            "true": self.theta_true.tolist(),
            "bound": self.bound_raw,
            "bound_parts": {"noise": self.noise_bound, "allowance": self.spec["bound"]["allowance"]},
            "bound_processed": float(eq.bound.max()),
            "filter_l1_norm": eq.info.get("l1_norm", 1.0),
            "min_consistent_bound": self.min_consistent_bound,
            "oracle_residual": float(r.max()),
            "bound_covers_residual": bool(np.all(r <= eq.bound)),
            "rows": len(eq),
            "rows_raw": eq.info.get("rows_raw"),
            "noise": {**self.spec["noise"], "bound": self.noise_bound, "description": self.noise_description},
            "prior": {"lower": self.prior.lower.tolist(), "upper": self.prior.upper.tolist()},
            "methods": methods,
            "hull_reference": None if self.hull_ref is None else self.hull_ref.describe(),
            "budget": self.budget,
            "timings": self.timings,
            "duration": float(self.dataset.t[-1] - self.dataset.t[0]),
            "content_hashes": self.content_hashes,
            "platform": fingerprint.platform(),
        }
        if self.width_analysis is not None:
            out["width_analysis"] = self.width_analysis
        if self.wls is not None:
            out["wls"] = {"theta": np.asarray(self.wls.theta).tolist(), "std": np.asarray(self.wls.std).tolist(),
                          "rel_std_percent": np.asarray(self.wls.rel_std_percent).tolist()}
        return out


def make_reference(spec: dict, geometry, seed: int):
    """The exciting trajectory of a spec (trajectories package), seeded: the legacy cond(W) design
    (``trajectory.criterion = "cond"`` with the default limits) or :func:`trajectories.design_excitation`
    (bounded-error criterion ``"h"`` or ``"cond"``, cached by its inputs) under ``trajectory.limits``."""
    from h4bench import trajectories

    tr = spec["trajectory"]
    if tr["kind"] != "fourier":
        raise ValueError(f"trajectory.kind must be 'fourier', got {tr['kind']!r}")
    if tr["criterion"] == "cond" and tr["limits"] == "default":
        return trajectories.fourier_excitation(geometry, duration=tr["duration"], harmonics=tr["harmonics"],
                                               base_hz=tr["base_hz"], seed=seed, optimise=tr["optimise"])
    limits = trajectories.Limits.h4_class() if tr["limits"] == "h4_class" else trajectories.Limits()
    return trajectories.design_excitation(geometry, duration=tr["duration"], seed=seed, limits=limits,
                                          criterion=tr["criterion"], processing=dict(spec["processing"]),
                                          harmonics=tr["harmonics"], base_hz=tr["base_hz"])


def traced_reference(spec: dict, geometry, seed: int):
    """:func:`make_reference` and where it came from: ``"memory"``, ``"disk"`` (the design cache) or
    ``"computed"`` (:func:`trajectories.excitation.cache_stats`), ``"direct"`` for the legacy cond design."""
    from h4bench.trajectories.excitation import cache_stats

    before = cache_stats()
    reference = make_reference(spec, geometry, seed)  # the same design under any BLAS thread count
    after = cache_stats()
    source = next((k for k in ("memory", "disk", "computed") if after[k] != before[k]), "direct")
    return reference, source


_FEEDFORWARD: dict = {}
_INSTRUMENT_ROWS: dict = {}
FEEDFORWARD_CACHE_SIZE = 16


def _feedforward_code() -> bytes:
    """The source of the inverse dynamics (regressor, kinematics, geometry) and numpy's version: in the key."""
    import importlib

    out = [np.__version__.encode()]
    for name in ("h4bench.ident.robots.h4", "h4bench.sim.kinematics", "h4bench.sim.model", "h4bench.portable"):
        out.append(Path(importlib.import_module(name).__file__).read_bytes())
    return b"\0".join(out)


def feedforward(geometry, theta, reference) -> np.ndarray:
    """The feed-forward torque (n, 4) [N m]: ``ident.inverse_dynamics`` of the reference with the nominal
    parameters ``theta``, kept by its inputs (the geometry, theta and the reference's q, qd, qdd, bit for bit,
    with the inverse dynamics' source and numpy's version; computed without BLAS) per process and in the design
    cache on disk (``sim.design_cache``, folder ``feedforward``): a campaign's runs share a few trajectories, and
    its workers and the next campaign find them there. Read-only."""
    import hashlib

    from h4bench.sim.design_cache import load_array, store_array
    from h4bench.trajectories.excitation import geometry_hash

    theta = np.ascontiguousarray(theta, dtype=float)
    h = hashlib.sha256()
    h.update(geometry_hash(geometry).encode())
    h.update(theta.tobytes())
    for name in ("q", "qd", "qdd"):
        arr = np.ascontiguousarray(getattr(reference, name), dtype=float)
        h.update(str(arr.shape).encode())
        h.update(arr.tobytes())
    h.update(_feedforward_code())
    key = h.hexdigest()
    ff = _FEEDFORWARD.get(key)
    if ff is None:
        n = np.shape(reference.q)[0]
        ff = load_array("feedforward", key, (n, 4))
        if ff is None:
            ff = ident.inverse_dynamics(geometry, theta, reference.q, reference.qd, reference.qdd)
            store_array("feedforward", key, ff)
        ff.setflags(write=False)
        if len(_FEEDFORWARD) >= FEEDFORWARD_CACHE_SIZE:
            _FEEDFORWARD.pop(next(iter(_FEEDFORWARD)))
        _FEEDFORWARD[key] = ff
    return ff


def make_noise(spec: dict):
    """The torque error a spec injects (``noise.shape``; see scenarios.spec.DEFAULTS): a sim.TorqueNoise or a
    sim.noise.TorqueError, each with its rigorous ``bound`` [N m]."""
    from h4bench.sim.noise import TorqueError, realistic_drive

    nz = spec["noise"]
    if nz["shape"] == "realistic":
        return realistic_drive(nz["bound"])
    if nz["shape"] == "model":
        return TorqueError.from_spec(nz["model"])
    return sim.TorqueNoise(nz["bound"], nz["shape"] if nz["bound"] > 0 else "none", nz["frequency_hz"])


def content_hashes(reference, design, ff, dataset) -> dict:
    """SHA-256 of each stage that selects the experiment, in the order they are made (``h4bench compare`` names
    the first that differs): ``trajectory`` (the reference's arrays and check report,
    :func:`trajectories.excitation.content_hash`), ``controller`` (the gains, J, Fv, period and velocity filter
    the law runs with), ``feedforward`` (the torque (n, 4), or None without it) and ``dataset`` (t, q, tau of
    the simulated measurement, the torque error included)."""
    from h4bench.trajectories.excitation import content_hash

    vf = design.velocity_filter_hz
    return {
        "trajectory": content_hash(reference),
        "controller": array_digest([(k, getattr(design, k)) for k in ("J", "Fv", "kp", "kv", "ki")]
                                   + [("dt", np.float64(design.dt)), ("velocity_filter_hz",
                                                                        np.float64(np.nan if vf is None else vf))]),
        "feedforward": None if ff is None else array_digest([("feedforward", ff)]),
        "dataset": array_digest([(k, getattr(dataset, k)) for k in ("t", "q", "tau")]),
    }


def nominal_parameters() -> np.ndarray:
    """The a priori parameter values a designer has (controller, feed-forward, trajectory checks)."""
    return np.asarray(ident.NOMINAL_PARAMETERS, dtype=float)


def run_experiment(spec: dict, seed: int | None = None, model=None, model_path: str | Path | None = None,
                   theta_true=None, reference=None, estimate: bool = True, progress=None) -> ExperimentRun:
    """Run one experiment of ``spec``. ``model``: a compiled variant (e.g. randomised parameters) whose truth
    is ``theta_true`` (default ``sim.true_parameters(model)``); else loaded from ``model_path``."""
    seed = spec["seed"] if seed is None else int(seed)
    timings = {}
    t0 = time.perf_counter()
    path = str(model_path or spec["model"] or sim.DEFAULT_MODEL_PATH)
    model = sim.load_model(path) if model is None else model
    geometry = sim.H4Geometry.from_model(model)
    structure = spec["structure"]["regressor"]
    theta_true = sim.true_parameters(model) if theta_true is None else np.asarray(theta_true, dtype=float)
    nominal = nominal_parameters()
    if reference is None:
        reference, timings["trajectory_source"] = traced_reference(spec, geometry, seed)
    timings["trajectory"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    design, controller = sim.default_controller(geometry, nominal, bandwidth_hz=spec["controller"]["bandwidth_hz"])
    ff = feedforward(geometry, nominal, reference) if spec["controller"]["feedforward"] else None
    timings["controller"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    noise = make_noise(spec)
    dataset, truth = sim.simulate(
        model, reference, noise=noise, controller=controller, feedforward=ff, seed=seed,
        settings=sim.SimulationSettings(encoder_counts=spec["encoder"]["counts_per_turn"] or None),
        metadata={"scenario": spec["name"], "model": path}, progress=progress, theta_true=theta_true,
    )
    timings["simulation"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    settings = ProcessingSettings(dt=dataset.dt, **spec["processing"])
    p = len(ident.parameter_names(structure))
    prior = ident.Box(np.full(p, spec["prior"]["lower"]), np.full(p, spec["prior"]["upper"]),
                      ident.parameter_names(structure))
    bound_raw = noise.bound + spec["bound"]["allowance"]
    # one regressor evaluation on the estimated motion, shared by the equation and the error budget
    raw = raw_equation(geometry, dataset.q, dataset.tau, dataset.dt, settings, structure)
    raw[0].setflags(write=False)
    equation = build_equation(geometry, dataset, bound_raw, settings, prior=prior, structure=structure, raw=raw)
    timings["processing"] = time.perf_counter() - t0
    run = ExperimentRun(spec=spec, seed=seed, model_path=path, model=model, geometry=geometry,
                        theta_true=theta_true, reference=reference, dataset=dataset, truth=truth, settings=settings,
                        equation=equation, prior=prior, bound_raw=bound_raw, controller_report=design.report(),
                        timings=timings, noise_bound=float(noise.bound), noise_description=noise.describe(),
                        content_hashes=content_hashes(reference, design, ff, dataset))
    t0 = time.perf_counter()
    run.budget = error_budget(geometry, dataset, truth, settings, structure, theta=theta_true, raw=raw)
    timings["budget"] = time.perf_counter() - t0
    if estimate:
        estimate_boxes(run)
    return run


def estimate_boxes(run: ExperimentRun) -> None:
    """Run the spec's estimators on the run's equation (never on the truth)."""
    eq, prior = run.equation, run.prior
    t0 = time.perf_counter()
    run.min_consistent_bound = float(ident.min_consistent_bound(eq.W, eq.y, prior))
    run.seconds["min_consistent_bound"] = time.perf_counter() - t0
    judge_methods(run, run.spec["estimators"]["methods"])
    if run.spec["estimators"]["wls"]:
        t0 = time.perf_counter()
        run.wls = ident.wls(eq.W, eq.y, joints=4, names=eq.names, joint_of_row=eq.joint)
        run.seconds["wls"] = time.perf_counter() - t0
    if run.spec["estimators"]["explain"]:
        t0 = time.perf_counter()
        hull = run.boxes.get("hull")
        run.width_analysis = width_analysis(eq.W, eq.y, eq.bound, run.theta_true, prior.lower, prior.upper,
                                            list(eq.names), None if hull is None else hull.width)
        run.seconds["width_analysis"] = time.perf_counter() - t0


def estimator_context(run: ExperimentRun) -> dict:
    """The context the scenario gives the estimators: ``groups`` (the joint of each row, (m,) ints) and
    ``instruments`` (:func:`instruments`, when they can be built row-aligned)."""
    context = {"groups": np.asarray(run.equation.joint, dtype=np.int64)}
    z = instruments(run)
    if z is not None:
        context["instruments"] = z
    return context


def instruments(run: ExperimentRun) -> np.ndarray | None:
    """The IDIM-IV instruments (Janot, Vandanjon & Gautier, IEEE TCST 22(1), 2014), (m, p): the regressor
    evaluated on the REFERENCE motion (the trajectory's noise-free q, sampled at the log's instants: no encoder
    quantisation, no tracking error, no torque noise), processed by exactly the same chain as W (Butterworth,
    derivatives, parallel filter and decimation, same settings) and restricted to W's rows (the same sample and
    joint, so row-aligned with W). The reference's rows are computed with the speed threshold at 0 so that
    every row W keeps exists; None if a row of W has no counterpart (never for a simulated run)."""
    import dataclasses

    import hashlib

    from h4bench.trajectories.excitation import geometry_hash

    eq, ds = run.equation, run.dataset
    ref_q = np.ascontiguousarray(run.reference.q, dtype=float)
    if ref_q.shape != ds.q.shape:
        return None
    settings = dataclasses.replace(run.settings, speed_threshold=0.0)
    structure = run.spec["structure"]["regressor"]
    # the reference's rows (W, sample, joint) do not depend on the run's torques, bound or prior (they set y and
    # the bound only): kept per process by what they do depend on, bit for bit
    h = hashlib.sha256()
    for part in (geometry_hash(run.geometry), repr(dataclasses.asdict(settings)), structure, str(ref_q.shape)):
        h.update(part.encode())
        h.update(b"\0")
    h.update(ref_q.tobytes())
    h.update(np.ascontiguousarray(ds.t, dtype=float).tobytes())
    cached = _INSTRUMENT_ROWS.get(h.hexdigest())
    if cached is None:
        ref = build_equation(run.geometry, sim.Dataset(ds.t, ref_q, ds.tau), run.bound_raw, settings,
                             prior=run.prior, structure=structure)
        cached = tuple(np.array(a) for a in (ref.W, ref.sample, ref.joint))
        for a in cached:
            a.setflags(write=False)
        if len(_INSTRUMENT_ROWS) >= FEEDFORWARD_CACHE_SIZE:
            _INSTRUMENT_ROWS.pop(next(iter(_INSTRUMENT_ROWS)))
        _INSTRUMENT_ROWS[h.hexdigest()] = cached
    ref_w, ref_sample, ref_joint = cached
    key = {(int(s), int(j)): k for k, (s, j) in enumerate(zip(ref_sample, ref_joint))}
    rows = [key.get((int(s), int(j))) for s, j in zip(eq.sample, eq.joint)]
    if any(r is None for r in rows):
        return None
    return np.ascontiguousarray(ref_w[np.asarray(rows, dtype=np.int64)])


def _takes(method, keyword: str) -> bool:
    """Whether ``method`` declares the context ``keyword``, read without running a plugin's import code in this
    process (:func:`ident.estimators.isolation.resolve`); a method that cannot be resolved takes nothing (it fails
    by name when it is run)."""
    try:
        return keyword in isolation.resolve(method).estimator.context
    except ident.EstimatorError:
        return False


def judge_methods(run: ExperimentRun, methods) -> None:
    """Run ``methods`` (and the exact hull as reference) on the run's equation through
    :func:`scenarios.judging.run_methods`; fills ``outcomes``, ``hull_ref``, ``boxes``, ``failures``, ``seconds``."""
    eq, prior = run.equation, run.prior
    # the instruments cost one more processing pass: built only for a method that may use them
    needs = any(_takes(m, "instruments") for m in methods)
    context = estimator_context(run) if needs else {"groups": np.asarray(run.equation.joint, dtype=np.int64)}
    outcomes, hull = judging.run_methods(list(methods), eq.W, eq.y, eq.bound, prior, context,
                                         timeout=run.spec["estimators"].get("method_timeout"))
    run.outcomes = outcomes
    for name, o in outcomes.items():
        run.seconds[name] = o.seconds
        if o.status == "ok":
            run.boxes[name] = o.box
        else:
            run.failures[name] = o.message
    run.hull_ref = None
    if hull is not None and hull.status == "ok":
        run.hull_ref = judging.hull_reference(eq.W, eq.y, eq.bound, prior, hull.box)
        if "hull" not in outcomes:
            run.seconds["hull_reference"] = hull.seconds


def estimate_hull(run: ExperimentRun) -> None:
    """The ordinary hull on the run's equation: a box, or the failure message when the set is proven empty."""
    eq = run.equation
    t0 = time.perf_counter()
    run.min_consistent_bound = float(ident.min_consistent_bound(eq.W, eq.y, run.prior))
    t1 = time.perf_counter()
    judge_methods(run, ["hull"])
    run.seconds["min_consistent_bound"] = t1 - t0
