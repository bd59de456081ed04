"""Scenario specifications: TOML files beside this module (``scenarios/<name>.toml``) or given by path.

A spec is a nested table merged over :data:`DEFAULTS`; unknown sections or keys are errors (a typo must not
silently fall back to a default). ``[quick]`` holds overrides applied by ``--quick`` (CI-sized runs), with the
same structure as the spec itself.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

from h4bench.ident.errors import EstimatorError
from h4bench.ident.estimators import registry

SPEC_DIR = Path(__file__).resolve().parent


class ScenarioError(ValueError):
    """Unknown scenario, malformed TOML or a bad value in a scenario spec."""


DEFAULTS: dict = {
    "name": "",
    "kind": "paper",
    "description": "",
    "seed": 0,
    "model": "",  # empty: models/h4.xml
    # criterion: "cond" (cond(W diag theta_nominal), the legacy design) or "h" (bounded-error half-widths,
    # trajectories.design_excitation, cached); limits: "default" (trajectories.Limits()) or "h4_class"
    "trajectory": {"kind": "fourier", "duration": 10.0, "harmonics": 5, "base_hz": 0.5, "optimise": True,
                   "criterion": "cond", "limits": "default"},
    "controller": {"bandwidth_hz": 15.0, "feedforward": True},
    # shape: uniform | square | sine | none (bound, frequency_hz), realistic (sim.noise.realistic_drive(bound)),
    # model (the table noise.model, sim.noise.TorqueError.from_spec: its bound replaces noise.bound)
    "noise": {"shape": "uniform", "bound": 1.0, "frequency_hz": 5.0, "model": {}},
    "encoder": {"counts_per_turn": 20000},
    "bound": {"allowance": 0.5},  # assumed raw-row bound = noise.bound + allowance [N m]
    # torque_timing "hold": the simulator (like a joint controller's log of its commands) holds each torque over
    # its step, so the regressor is evaluated at mid-step (ident.processing.filtering.derivatives)
    "processing": {"position_cutoff_hz": 20.0, "butter_order": 4, "decimation": 10, "numtaps": 41,
                   "fir_cutoff": 0.8, "speed_threshold": 0.05, "torque_timing": "hold"},
    "prior": {"lower": 0.0, "upper": 2.0},
    "estimators": {"methods": ["hull", "cgsp"], "wls": True, "explain": True},
    "structure": {"regressor": "paper", "arm_com_offset": 0.0, "forearm_mass": 0.0},
    # trajectories: number of distinct trajectories (run i uses seed base + i % trajectories); 0: one per run
    "campaign": {"runs": 200, "noise_shapes": ["uniform", "square", "sine"], "parameter_spread": 0.3,
                 "workers": 0, "scheduler": "", "trajectories": 0},
    "sweep": {"factors": [0.5, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5, 2.0, 3.0, 5.0]},
    "outliers": {"count": 5, "magnitude": 6.0, "relax": 8, "method": "auto"},
    # uncertain_regressor: the filter-distortion assumption is calibrated on a simulation with the same reference,
    # seed + calibration_seed_offset and robot parameters within +-calibration_spread, times safety
    "uncertain": {"calibration_seed_offset": 1000, "calibration_spread": 0.3, "safety": 2.0, "sign_band": 0.005,
                  "second_order_margin": 0.1},
    "replay": {"enabled": True, "history_points": 10},
    # the feasible set's projections (scenarios.feasible; kind paper): pairs "NAME:NAME" (empty: the `count` most
    # coupled), K directions (a multiple of 4), refinement rounds towards the exact projection, methods drawn
    # beside it (empty: the spec's methods plus ellipsoid, zonotope and wls when registered)
    "feasible": {"enabled": True, "pairs": [], "count": 3, "directions": 32, "refine": 3, "methods": []},
    # guaranteed prediction on a held-out motion (kind paper): a second designed trajectory and its simulation
    # with seed + seed_offset, processed the same way; the polytope envelope on `rows` evenly spaced rows
    "prediction": {"enabled": True, "seed_offset": 100, "rows": 240, "joint": 1},
    "quick": {},
}


def _merge(base: dict, override: dict, where: str) -> dict:
    out = copy.deepcopy(base)
    for key, value in override.items():
        if key not in base:
            raise ScenarioError(f"unknown key {where}{key!r} (known: {sorted(base)})")
        if isinstance(base[key], dict) and key not in ("quick", "model"):
            if not isinstance(value, dict):
                raise ScenarioError(f"{where}{key} must be a table, got {type(value).__name__}")
            out[key] = _merge(base[key], value, f"{where}{key}.")
        else:
            if base[key] is not None and not isinstance(value, type(base[key])) and not (
                isinstance(base[key], float) and isinstance(value, int) and not isinstance(value, bool)
            ):
                raise ScenarioError(f"{where}{key} must be of type {type(base[key]).__name__}, got {value!r}")
            out[key] = float(value) if isinstance(base[key], float) else copy.deepcopy(value)
    return out


NOISE_SHAPES = ("uniform", "square", "sine", "none", "realistic", "model")  # see DEFAULTS["noise"]
CRITERIA = ("cond", "h")
LIMITS = ("default", "h4_class")


def _check_list(value, where: str, allowed: tuple[str, ...], allow_empty: bool) -> None:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ScenarioError(f"{where} must be a list of strings from {allowed}, got {value!r}")
    if not value and not allow_empty:
        raise ScenarioError(f"{where} must not be empty (choose from {allowed})")
    unknown = [v for v in value if v not in allowed]
    if unknown:
        raise ScenarioError(f"{where} must be a list of strings from {allowed}, got unknown {unknown}")


def _check_methods(value, where: str) -> None:
    """Box estimators: any name the estimator registry resolves (a built-in, an entry point, module:attribute)."""
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ScenarioError(f"{where} must be a list of strings, estimator names (built-in: "
                            f"{tuple(registry.BUILTINS)}), got {value!r}")
    from h4bench.ident.estimators import isolation

    for v in value:
        try:
            isolation.resolve(v)  # a plugin's import code runs in a child process, never here
        except (EstimatorError, TypeError) as exc:
            raise ScenarioError(f"{where}: {exc}") from None


def _check_lists(spec: dict) -> None:
    _check_methods(spec["estimators"]["methods"], "estimators.methods")
    _check_list(spec["campaign"]["noise_shapes"], "campaign.noise_shapes", NOISE_SHAPES, allow_empty=False)
    if spec["noise"]["shape"] not in NOISE_SHAPES:
        raise ScenarioError(f"noise.shape must be one of {NOISE_SHAPES}, got {spec['noise']['shape']!r}")
    if spec["trajectory"]["criterion"] not in CRITERIA:
        raise ScenarioError(f"trajectory.criterion must be one of {CRITERIA}, got {spec['trajectory']['criterion']!r}")
    if spec["trajectory"]["limits"] not in LIMITS:
        raise ScenarioError(f"trajectory.limits must be one of {LIMITS}, got {spec['trajectory']['limits']!r}")
    n_traj = spec["campaign"]["trajectories"]
    if isinstance(n_traj, bool) or not isinstance(n_traj, int) or n_traj < 0:
        raise ScenarioError(f"campaign.trajectories must be an integer >= 0, got {n_traj!r}")
    fs, pr = spec["feasible"], spec["prediction"]
    _check_methods(fs["methods"], "feasible.methods")
    if not isinstance(fs["pairs"], list) or not all(isinstance(v, str) and v.count(":") == 1 for v in fs["pairs"]):
        raise ScenarioError(f"feasible.pairs must be a list of strings NAME:NAME, got {fs['pairs']!r}")
    for key, value, ok in (("feasible.count", fs["count"], fs["count"] >= 1),
                           ("feasible.directions", fs["directions"],
                            fs["directions"] >= 4 and fs["directions"] % 4 == 0),
                           ("feasible.refine", fs["refine"], fs["refine"] >= 0),
                           ("prediction.seed_offset", pr["seed_offset"], pr["seed_offset"] != 0),
                           ("prediction.rows", pr["rows"], pr["rows"] >= 1),
                           ("prediction.joint", pr["joint"], 1 <= pr["joint"] <= 4)):
        if isinstance(value, bool) or not ok:
            raise ScenarioError(f"{key} has a bad value {value!r} (count >= 1, directions a multiple of 4, refine "
                                ">= 0, seed_offset != 0, rows >= 1, joint in 1..4)")
    factors = spec["sweep"]["factors"]
    if not isinstance(factors, list) or not factors or not all(
            isinstance(f, (int, float)) and not isinstance(f, bool) and f > 0 for f in factors):
        raise ScenarioError(f"sweep.factors must be a non-empty list of numbers > 0, got {factors!r}")


def available() -> list[str]:
    return sorted(p.stem for p in SPEC_DIR.glob("*.toml"))


def load_spec(name_or_path: str | Path, quick: bool = False, kinds: tuple[str, ...] | None = None,
              extra_defaults: dict | None = None) -> dict:
    """The merged spec of a scenario name (``paper``) or a TOML path; ``quick`` applies ``[quick]``.

    kinds : the known kinds (checked when given; :func:`scenarios.registry.load_spec` passes the registry's);
    extra_defaults : spec sections declared by the kinds, merged over :data:`DEFAULTS`."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = SPEC_DIR / f"{name_or_path}.toml"
        if not path.is_file():
            raise ScenarioError(f"scenario must be one of {available()} or a .toml path, got {str(name_or_path)!r}")
    elif not path.is_file():
        raise ScenarioError(f"scenario file {str(path)!r} does not exist")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"scenario file {str(path)!r} is not valid TOML: {exc}") from exc
    defaults = {**DEFAULTS, **(extra_defaults or {})}
    spec = _merge(defaults, raw, "")
    if quick:
        spec = _merge(spec, spec["quick"], "quick.")
    spec["name"] = spec["name"] or path.stem
    kind = spec["kind"].replace("-", "_")
    if kinds is not None and kind not in kinds:
        raise ScenarioError(f"kind must be one of {tuple(kinds)}, got {spec['kind']!r}")
    spec["kind"] = kind
    _check_lists(spec)
    if spec["noise"]["bound"] < 0 or spec["bound"]["allowance"] < 0:
        raise ScenarioError("noise.bound and bound.allowance must be >= 0 [N m]")
    if spec["prior"]["lower"] >= spec["prior"]["upper"]:
        raise ScenarioError(f"prior.lower must be < prior.upper, got {spec['prior']}")
    spec["quick_applied"] = bool(quick)
    return spec
