"""``h4bench identify``: the estimators on a user's own log (CSV), with the same result.json as a scenario.

Inputs a user with a datasheet has (formats documented in docs/commands.md, "identify: priors and bounds"):

- the bound on ``|tau - W theta|`` for every raw sample [N m]: one number for all joints, four numbers
  ``b1,b2,b3,b4`` (one per joint), or a file: TOML ``joint1 = 1.2`` ... ``joint4 = 1.0``, or CSV with the header
  ``joint,bound`` and one row per joint (1..4);
- the prior box: one pair ``(lower, upper)`` for all 14 parameters, or a file naming parameters (paper eq. 18
  order ``Imot1..4, Mnac, Ibc, Fv1..4, Fs1..4``): TOML ``[Imot1]`` with ``lower = 0.0`` and ``upper = 0.05``, or
  CSV with the header ``name,lower,upper``; parameters the file does not name keep the default pair.

Option errors are :class:`OptionError` (a ValueError) whose message names the command-line option (or the file
and the parameter or joint), what was expected and what came. Data proven inconsistent with the bound are
recorded in result.json (``consistent: false``, the smallest consistent bound) and the command exits 3.
"""

from __future__ import annotations

import csv
import math
import os
import tomllib
from pathlib import Path

import numpy as np

from h4bench import ident
from h4bench import sim
from h4bench.ident.estimators import registry
from h4bench.ident.processing.filtering import ProcessingSettings
from h4bench.ident.robots.h4_equation import BLOCK_SAMPLES, build_equation
from h4bench.scenarios.rundir import RUNS_DIR, OwnedFolder, check_target, write_json
from h4bench.scenarios.exit_codes import EXIT_INCONSISTENT, EXIT_METHOD_FAILED  # noqa: F401  (re-exported)
from h4bench.scenarios.spec import DEFAULTS

METHODS = tuple(dict.fromkeys((*registry.BUILTINS, "wls")))  # the built-in box estimators (any the registry resolves works) and WLS
N_JOINTS = 4


def check_method(method) -> str:
    """One method or a comma-separated list (``hull,cgsp``; ``all`` = every registered estimator; names of the
    registry, entry points or ``package.module:attribute``, :func:`scenarios.judging.parse_methods`); ``wls`` is
    the registry's WLS box plus the %sigma table (``result["wls"]``). ValueError naming the choices otherwise;
    returns the method string."""
    from h4bench.scenarios.judging import parse_methods

    try:
        parse_methods(method)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"method must be one of {METHODS} (or several, comma-separated; all; or an estimator "
                         f"plugin), got {method!r}: {exc}") from None
    return method


class OptionError(ValueError):
    """A bad command-line option value or option file; the message names the option or the file."""


# ------------------------------------------------------------------------------------------- option values


def parse_number(text, option: str, *, positive: bool = False) -> float:
    """A finite number (``> 0`` if ``positive``) from an option's text; OptionError names ``option``."""
    expected = "a finite number > 0" if positive else "a finite number"
    try:
        x = float(text)
    except (TypeError, ValueError):
        raise OptionError(f"{option} must be {expected}, got {text!r}") from None
    if not math.isfinite(x) or (positive and not x > 0):
        raise OptionError(f"{option} must be {expected}, got {text!r}")
    return x


def _read_table(path: Path, option: str, columns: tuple[str, ...]) -> list[tuple[int, dict]]:
    """TOML -> [(0, {key: value})] or CSV with the header ``columns`` -> [(line, row dict)]."""
    if not path.is_file():
        raise OptionError(f"{option} must name an existing .toml or .csv file, got {str(path)!r} (not found)")
    try:
        if path.suffix.lower() == ".toml":
            with path.open("rb") as fh:
                return [(0, tomllib.load(fh))]
        if path.suffix.lower() != ".csv":
            raise OptionError(f"{option} file must end in .toml or .csv, got {str(path)!r}")
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            rows = [(reader.line_num, r) for r in reader if r and any(f.strip() for f in r)]
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise OptionError(f"{option} file {str(path)!r} is not valid {path.suffix[1:].upper()} text: {exc}") from None
    header = [h.strip() for h in rows[0][1]] if rows else []
    if header != list(columns):
        raise OptionError(f"{option} file {str(path)!r} must have the CSV header {','.join(columns)}, got "
                          f"{','.join(header) or 'an empty file'}")
    out = []
    for line, r in rows[1:]:
        if len(r) != len(columns):
            raise OptionError(f"{option} file {str(path)!r} line {line} must have {len(columns)} values "
                              f"({','.join(columns)}), got {len(r)}")
        out.append((line, dict(zip(columns, (f.strip() for f in r)))))
    return out


def parse_bound(text) -> np.ndarray:
    """``--bound``: ``1.5``, ``1.2,1.5,1.5,1.0`` (joints 1..4) or a .toml/.csv file -> (4,) [N m], each > 0."""
    text = str(text).strip()
    if text.lower().endswith((".toml", ".csv")) or os.sep in text:
        return _bound_file(Path(text))
    parts = text.split(",")
    if len(parts) == 1:
        try:
            return np.full(N_JOINTS, parse_number(text, "--bound", positive=True))
        except OptionError:
            raise OptionError(f"--bound must be a finite number > 0 [N m], {N_JOINTS} comma-separated numbers "
                              f"(joints 1..{N_JOINTS}) or a .toml/.csv file, got {text!r}") from None
    if len(parts) != N_JOINTS:
        raise OptionError(f"--bound must be one number, {N_JOINTS} comma-separated numbers (joints 1..{N_JOINTS}) "
                          f"or a .toml/.csv file, got {text!r} ({len(parts)} values)")
    return np.array([parse_number(p.strip(), f"--bound (joint {i + 1})", positive=True) for i, p in enumerate(parts)])


def _bound_file(path: Path) -> np.ndarray:
    option = "--bound"
    out = np.full(N_JOINTS, np.nan)
    for line, row in _read_table(path, option, ("joint", "bound")):
        where = f"{option} file {str(path)!r}" + (f" line {line}" if line else "")
        items = row.items() if not line else [(f"joint{row['joint'].removeprefix('joint')}", row["bound"])]
        for key, value in items:
            joints = {f"joint{i + 1}": i for i in range(N_JOINTS)}
            if key not in joints:
                raise OptionError(f"{where}: the joint must be one of {list(joints)} (or 1..{N_JOINTS} in CSV), "
                                  f"got {key!r}")
            if isinstance(value, bool) or isinstance(value, dict):
                raise OptionError(f"{where}: {key} must be a finite number > 0 [N m], got {value!r}")
            j = joints[key]
            if not np.isnan(out[j]):
                raise OptionError(f"{where}: {key} is given twice")
            out[j] = parse_number(value, f"{where}: {key}", positive=True)
    missing = [f"joint{i + 1}" for i in range(N_JOINTS) if np.isnan(out[i])]
    if missing:
        raise OptionError(f"{option} file {str(path)!r} must give a bound for every joint, missing {missing}")
    return out


def load_prior(path, lower: float = 0.0, upper: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """``--prior FILE`` -> (lower (14,), upper (14,)): the file's parameters, the others ``[lower, upper]``."""
    option = "--prior"
    path = Path(path)
    names = list(ident.PARAMETER_NAMES)
    lo, hi = np.full(len(names), float(lower)), np.full(len(names), float(upper))
    seen = set()
    for line, row in _read_table(path, option, ("name", "lower", "upper")):
        where = f"{option} file {str(path)!r}" + (f" line {line}" if line else "")
        items = row.items() if not line else [(row["name"], {"lower": row["lower"], "upper": row["upper"]})]
        for name, entry in items:
            if name not in names:
                raise OptionError(f"{where}: the parameter must be one of {names}, got {name!r}")
            if name in seen:
                raise OptionError(f"{where}: parameter {name} is given twice")
            if not isinstance(entry, dict) or set(entry) != {"lower", "upper"}:
                got = sorted(entry) if isinstance(entry, dict) else repr(entry)
                raise OptionError(f"{where}: parameter {name} must have exactly the keys lower and upper, got {got}")
            j = names.index(name)
            for key in ("lower", "upper"):
                if isinstance(entry[key], bool):
                    raise OptionError(f"{where}: {name}.{key} must be a finite number, got {entry[key]!r}")
            lo[j] = parse_number(entry["lower"], f"{where}: {name}.lower")
            hi[j] = parse_number(entry["upper"], f"{where}: {name}.upper")
            if not lo[j] < hi[j]:
                raise OptionError(f"{where}: parameter {name} must have lower < upper, got lower = {lo[j]:g}, "
                                  f"upper = {hi[j]:g}")
            seen.add(name)
    return lo, hi


def _prior_box(prior) -> "ident.Box":
    """(lower, upper) scalars, (lower (14,), upper (14,)) or a Box -> a validated Box."""
    lower, upper = (prior.lower, prior.upper) if hasattr(prior, "lower") else prior
    p = len(ident.PARAMETER_NAMES)
    try:
        lo = np.broadcast_to(np.asarray(lower, dtype=float), (p,)).copy()
        hi = np.broadcast_to(np.asarray(upper, dtype=float), (p,)).copy()
    except (TypeError, ValueError):
        raise ValueError(f"prior must be (lower, upper) with numbers or {p} values each, got {prior!r}") from None
    for j, name in enumerate(ident.PARAMETER_NAMES):
        if not (math.isfinite(lo[j]) and math.isfinite(hi[j])):
            raise ValueError(f"prior of {name} must be finite, got [{lo[j]}, {hi[j]}]")
        if not lo[j] < hi[j]:
            raise ValueError(f"prior of {name} must have lower < upper, got [{lo[j]:g}, {hi[j]:g}]")
    return ident.Box(lo, hi, ident.PARAMETER_NAMES)


def _joint_bounds(bound) -> np.ndarray:
    b = np.asarray(bound, dtype=float)
    if b.ndim == 0:
        b = np.full(N_JOINTS, float(b))
    if b.shape != (N_JOINTS,):
        raise ValueError(f"bound must be a number or {N_JOINTS} numbers (one per joint) [N m], got shape {b.shape}")
    for i, v in enumerate(b):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"bound of joint {i + 1} must be a finite number > 0 [N m], got {v!r}")
    return b


# ------------------------------------------------------------------------------------------------ identify


def _check_processed_bound(rows_bound, bound) -> None:
    """The filtered rows' bound (the raw bound times the filter's gain) must be finite: else --bound is too large."""
    if not np.all(np.isfinite(rows_bound)):
        raise OptionError(f"--bound must be a physical bound [N m]: {np.max(bound):g} overflows to infinity once "
                          "propagated through the filter (the processed rows' bound); give a smaller finite bound")


def identify_csv(path, bound, method: str = "hull", prior=(0.0, 2.0), model=None, out=None,
                 block_samples: int = BLOCK_SAMPLES, torque_timing: str = "hold", pairs: str | None = None,
                 timeout: float | None = None) -> dict:
    """Identify the 14 parameters from a CSV log and write ``result.json`` in ``out``.

    bound : raw-row bound [N m], one number or (4,) per joint; prior : (lower, upper) numbers, (14,) arrays
    each, or a Box; block_samples : processing block length (:func:`ident.robots.h4_equation.build_equation`);
    torque_timing : "hold" (each logged torque is a command held over its step: the regressor at mid-step) or
    "sample" (a torque measured at the sample instant), :func:`ident.processing.filtering.derivatives`;
    pairs : ``--pairs`` (``auto`` or ``NAME:NAME,...``): the feasible set's projections, ``feasible_set.png``;
    timeout : ``--method-timeout``, seconds per method (None: no limit). Returns the result dict. Data proven inconsistent with the bound give ``result["consistent"] = False``
    (the method's status ``inconsistent`` with ``min_bound``, the smallest consistent scalar bound), not an exception.
    """
    check_method(method)
    _pairs(pairs, ident.PARAMETER_NAMES)  # a bad --pairs fails before the log is read
    b = _joint_bounds(bound)
    box_prior = _prior_box(prior)
    out = check_target(Path(out) if out is not None else RUNS_DIR / f"identify-{Path(path).stem}")
    dataset = sim.Dataset.from_csv(path)
    geometry = sim.H4Geometry.from_model(sim.load_model(model))
    settings = ProcessingSettings(dt=dataset.dt, **{**DEFAULTS["processing"], "torque_timing": torque_timing})
    with np.errstate(over="ignore", invalid="ignore"):
        eq = build_equation(geometry, dataset, b, settings, prior=box_prior, block_samples=block_samples)
    _check_processed_bound(eq.bound, b)
    samples = len(dataset)
    del dataset
    uniform = bool(np.all(b == b[0]))
    result = {
        "scenario": f"identify-{Path(path).stem}", "kind": "identify", "seed": None, "model": str(model or sim.DEFAULT_MODEL_PATH),
        "source": str(path), "samples": samples, "parameters": list(ident.PARAMETER_NAMES), "true": None,
        "bound": float(b[0]) if uniform else b.tolist(), "bound_processed": float(eq.bound.max()), "rows": len(eq),
        "processing": {"torque_timing": settings.torque_timing,
                       **{k: v for k, v in eq.info.items() if k in ("blocks", "block_samples", "block_margin", "l1_norm")}},
        "oracle_residual": None, "consistent": None,
        "prior": {"lower": box_prior.lower.tolist(), "upper": box_prior.upper.tolist()}, "methods": {},
    }
    result["min_consistent_bound"] = float(ident.min_consistent_bound(eq.W, eq.y, box_prior))
    return _estimate_and_write(result, eq.W, eq.y, eq.bound, box_prior, method, N_JOINTS, eq.names, eq.joint, out,
                               pairs, raw_bound=b, gain=float(eq.info["l1_norm"]), timeout=timeout)


# ------------------------------------------------------------------------------- any serial robot (URDF)

# Processing of a serial robot's log: the tx40 scenario's defaults (scenarios/kinds/tx40.py), for logs sampled at
# about 1-10 kHz: zero-phase Butterworth (order 4) on q at cutoff_hz, central differences, the base regressor,
# rows slower than speed_threshold [rad/s] dropped (sign(qd) not trusted), a Hamming FIR of
# numtaps_per_decimation x decimation + 1 taps with its -6 dB point at fir_cutoff x the decimated Nyquist
# frequency, decimation; base parameters from base_samples random states (seed).
URDF_PROCESSING = {"cutoff_hz": 100.0, "butter_order": 4, "decimation": 100, "numtaps_per_decimation": 4,
                   "fir_cutoff": 0.8, "speed_threshold": 0.05, "base_samples": 200, "seed": 0,
                   "torque_timing": "sample"}  # the regressor at the sampling instants (as the tx40 scenario)
MASS_FACTOR = 2.0  # default total mass of the prior: the URDF's total mass times this
OFFSET_FRACTION = 0.2  # |off_i| <= this x the URDF effort limit


def parse_joint_bound(text, n_joints: int) -> np.ndarray:
    """``--bound`` of an n-joint robot: ``1.5`` or ``b1,..,bn`` -> (n,) [N m], each > 0; OptionError names it."""
    text = str(text).strip()
    parts = text.split(",")
    if len(parts) not in (1, n_joints):
        raise OptionError(f"--bound must be one number or {n_joints} comma-separated numbers (joints 1..{n_joints}) "
                          f"[N m], got {text!r} ({len(parts)} values)")
    if len(parts) == 1:
        return np.full(n_joints, parse_number(text, "--bound", positive=True))
    return np.array([parse_number(p.strip(), f"--bound (joint {i + 1})", positive=True) for i, p in enumerate(parts)])


def read_serial_log(path, n_joints: int) -> tuple[np.ndarray, np.ndarray, float]:
    """CSV ``t, q1..qn, tau1..taun`` (joint side, SI; other columns ignored) -> q (N, n) [rad], tau (N, n)
    [N m], dt [s] (the mean step, to 12 significant digits). The time must increase uniformly (each step
    within 0.1 % of the median step). Errors are
    :class:`sim.DatasetError` naming the file, the column and the data row."""
    from h4bench.sim.csvlog import read_log

    DatasetError = sim.DatasetError

    t, q, tau = read_log(path, n_joints=n_joints)
    if t.size < 3:
        raise DatasetError(f"CSV {str(path)!r} must have at least 3 data rows, got {t.size}")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if dt > 0:  # text time stamps: the mean step to 12 significant digits (k 2e-4 s gives 2e-4 exactly, not 2e-4 - 1 ulp)
        dt = float(f"{(t[-1] - t[0]) / (t.size - 1):.12g}")
    bad = np.flatnonzero(~(np.abs(steps - dt) <= 1e-3 * dt)) if dt > 0 else np.array([0])
    if bad.size:
        k = int(bad[0])
        raise DatasetError(f"CSV {str(path)!r}: column t must increase uniformly (step {dt:g} s), got the step "
                           f"{steps[k]:g} s between data rows {k + 1} and {k + 2}")
    return q, tau, dt


def urdf_robot_and_prior(urdf, mass=None, reach=None, *, friction: bool = True, rotor_inertia: bool = True,
                         offset: bool = True, coupled_wrist=None, rotor_inertia_max: float | None = None):
    """The serial robot of ``--urdf``, its base parameters and their physical prior (as :func:`identify_urdf_csv`
    documents). Returns (robot, base, prior dict: ``lower``, ``upper`` (base, lists), the standard box, the total
    mass, reach, rotor bound, offset fraction and the source)."""
    from h4bench.ident.robots.serial import SerialRobot, default_reach, physical_prior

    urdf = Path(urdf)
    if not urdf.is_file():
        raise OptionError(f"--urdf must name an existing URDF file, got {str(urdf)!r} (not found)")
    try:
        robot = SerialRobot(urdf, friction=friction, rotor_inertia=rotor_inertia, offset=offset,
                            coupled_wrist=coupled_wrist)
    except (ValueError, RuntimeError) as exc:
        raise OptionError(f"--urdf {str(urdf)!r} is not a usable serial robot: {exc}") from None
    import pinocchio  # present: SerialRobot was built

    urdf_mass = float(pinocchio.computeTotalMass(robot.model))
    M = MASS_FACTOR * urdf_mass if mass is None else parse_number(mass, "--mass", positive=True)
    r = default_reach(robot) if reach is None else parse_number(reach, "--reach", positive=True)
    if not M > 0:
        raise OptionError(f"--mass must be given when the URDF's total mass is 0, got the URDF mass {urdf_mass:g} kg")
    p = URDF_PROCESSING
    base = robot.base(int(p["base_samples"]), int(p["seed"]))
    lo_s, hi_s = physical_prior(robot, M, r, rotor_inertia_max=rotor_inertia_max, offset_fraction=OFFSET_FRACTION)
    blo, bhi = base.box_from_standard(lo_s, hi_s)
    info = {"lower": blo.tolist(), "upper": bhi.tolist(), "standard_lower": lo_s.tolist(),
            "standard_upper": hi_s.tolist(), "total_mass": M, "urdf_mass": urdf_mass, "reach": r,
            "rotor_inertia_max": rotor_inertia_max, "offset_fraction": OFFSET_FRACTION,
            "source": "h4bench.ident.robots.serial.physical_prior mapped by the base-parameter matrix"}
    return robot, base, info


def identify_urdf_csv(path, urdf, bound, method: str = "hull", *, mass: float | None = None,
                      reach: float | None = None, friction: bool = True, rotor_inertia: bool = True,
                      offset: bool = True, coupled_wrist: tuple[int, int] | None = None,
                      rotor_inertia_max: float | None = None,
                      cutoff_hz: float = URDF_PROCESSING["cutoff_hz"],
                      decimation: int = URDF_PROCESSING["decimation"], out=None, pairs: str | None = None,
                      timeout: float | None = None) -> dict:
    """Identify a serial robot's base parameters from a joint-side CSV log; write ``result.json`` in ``out``.

    urdf : the robot (:class:`ident.robots.serial.SerialRobot`, n actuated joints; friction, rotor_inertia, offset
    select its extra columns; coupled_wrist : None or 0-based joints (a, b), the motor of b turning with a);
    path : CSV ``t, q1..qn, tau1..taun`` (:func:`read_serial_log`); bound : raw-row
    bound on ``|tau - W theta|`` [N m], one number or (n,) per joint; method : hull | cgsp | wls.
    Prior: :func:`ident.robots.serial.physical_prior` with total mass ``mass`` [kg] (default the URDF's total mass
    times :data:`MASS_FACTOR`), ``reach`` [m] (default :func:`ident.robots.serial.default_reach`: the sum of the
    joint-origin offsets plus the last link's centre-of-mass distance), ``rotor_inertia_max`` [kg m^2]
    (joint side; default M r^2) and offsets within :data:`OFFSET_FRACTION` x the effort limit, mapped exactly to
    the base parameters (``BaseParameters.box_from_standard``). Processing: :data:`URDF_PROCESSING` with
    ``cutoff_hz`` [Hz] and ``decimation``. Returns the result dict; data proven inconsistent with the bound give
    ``result["consistent"] = False`` (and the method's ``min_bound``), not an exception.
    """
    from h4bench.ident.robots.serial import process

    check_method(method)
    robot, base, prior_info = urdf_robot_and_prior(urdf, mass, reach, friction=friction, rotor_inertia=rotor_inertia,
                                                   offset=offset, coupled_wrist=coupled_wrist,
                                                   rotor_inertia_max=rotor_inertia_max)
    urdf, nj = Path(urdf), robot.n_joints
    b = np.asarray(bound, dtype=float)
    b = np.full(nj, float(b)) if b.ndim == 0 else b
    if b.shape != (nj,) or not np.all(np.isfinite(b) & (b > 0)):
        raise OptionError(f"--bound must be one number or {nj} numbers > 0 (one per joint of {urdf.name}) [N m], "
                          f"got {np.asarray(bound).tolist()!r}")
    cutoff_hz = parse_number(cutoff_hz, "--cutoff-hz", positive=True)
    if isinstance(decimation, bool) or int(decimation) != decimation or decimation < 1:
        raise OptionError(f"--decimation must be an integer >= 1, got {decimation!r}")
    decimation = int(decimation)
    out = check_target(Path(out) if out is not None else RUNS_DIR / f"identify-{Path(path).stem}")
    q, tau, dt = read_serial_log(path, nj)
    p = URDF_PROCESSING
    blo, bhi = np.asarray(prior_info["lower"]), np.asarray(prior_info["upper"])
    prior = ident.Box(blo, bhi, names=base.names)
    settings = {"cutoff_hz": cutoff_hz, "decimation": decimation,
                "numtaps": int(p["numtaps_per_decimation"]) * decimation + 1, "fir_cutoff": p["fir_cutoff"],
                "speed_threshold": p["speed_threshold"], "butter_order": p["butter_order"],
                "torque_timing": p["torque_timing"]}
    eq = process(robot, base, q, tau, dt, theta_abs_max=np.maximum(np.abs(blo), np.abs(bhi)), **settings)
    if len(eq) == 0:
        raise sim.DatasetError(f"CSV {str(path)!r} gives no processed row (too short, or too slow: rows below "
                               f"{p['speed_threshold']} rad/s are dropped)")
    with np.errstate(over="ignore", invalid="ignore"):
        rows_bound = eq.bound(b)
    _check_processed_bound(rows_bound, b)
    uniform = bool(np.all(b == b[0]))
    t_min = float(ident.min_consistent_bound(eq.W, eq.y, prior))
    result = {
        "scenario": f"identify-{Path(path).stem}", "kind": "identify", "seed": int(p["seed"]), "robot": str(urdf),
        "source": str(path), "samples": int(q.shape[0]), "dt": dt, "joints": list(robot.joint_names),
        "parameters": list(base.names), "parameter_expressions": list(base.expressions),
        "parameter_units": list(base.units), "standard_parameters": list(robot.names), "true": None,
        "bound": float(b[0]) if uniform else b.tolist(), "bound_processed": float(rows_bound.max()), "rows": len(eq),
        "processing": {**settings, "seed": int(p["seed"]), "base_samples": int(p["base_samples"]),
                       "filter_l1_norm": eq.gain,
                       **{k: v for k, v in eq.info.items() if isinstance(v, (int, float, bool))}},
        "oracle_residual": None, "consistent": None,
        "prior": prior_info,
        # processed rows [N m]; divided by ||h||_1: the raw-row scalar bound it corresponds to (approximately)
        "min_consistent_bound": t_min, "min_consistent_bound_raw": t_min / eq.gain,
        "base_parameters": {"count": len(base), "standard_count": robot.n_parameters,
                            "singular_gap": base.singular_gap},
        "methods": {},
    }
    return _estimate_and_write(result, eq.W, eq.y, rows_bound, prior, method, nj, base.names, eq.joint, out, pairs,
                               raw_bound=b, gain=float(eq.gain), timeout=timeout)


# the Chebyshev LP's upper bound exceeds the smallest consistent scale by at most its tolerance (about 1e-9
# relative, ident.min_consistent_bound); a scale above 1 + this margin is an inconsistency well beyond it
WLS_INCONSISTENCY_MARGIN = 1e-6


def wls_consistency(W, y, bound, prior, min_bound: float | None = None) -> dict:
    """Whether some theta in the prior satisfies ``|y - W theta| <= bound`` row by row, by the Chebyshev LP
    (:func:`ident.min_consistent_bound`) on the rows scaled by their bound: ``scale`` (an upper bound of the
    smallest factor of the bounds that admits a theta) <= 1 proves them consistent (``consistent`` True); above
    ``1 + WLS_INCONSISTENCY_MARGIN`` (1000 times the LP's tolerance) they are inconsistent (False), the same
    verdict as the box methods'; in between, None (not decided). ``min_bound``: the smallest consistent scalar
    bound of the rows as given [N m] (``min_bound``: already computed, else computed here)."""
    b = np.broadcast_to(np.asarray(bound, dtype=float), (len(y),))
    if min_bound is None:
        min_bound = float(ident.min_consistent_bound(W, y, prior))
    if np.all(b == b[0]):  # one bound: the scale is min_bound / b, rounded up (still an upper bound)
        scale = float(np.nextafter(min_bound / b[0], np.inf))
    else:
        scale = float(ident.min_consistent_bound(W / b[:, None], y / b, prior))
    verdict = True if scale <= 1.0 else (False if scale > 1.0 + WLS_INCONSISTENCY_MARGIN else None)
    return {"consistent": verdict, "scale": scale, "min_bound": float(min_bound),
            "method": "Chebyshev LP (ident.min_consistent_bound) on the rows scaled by their bound"}


def _pairs(pairs, names):
    """``--pairs`` parsed (None: not asked; ``"auto"``: the most coupled), OptionError naming it."""
    from h4bench.scenarios.feasible import pairs_option

    if pairs is None:
        return None
    try:
        return pairs_option(pairs, names) or "auto"
    except ValueError as exc:
        raise OptionError(str(exc)) from None


def consistent_raw_bound(W, y, bound, prior, joint_of_row, raw_bound, gain: float) -> dict:
    """The smallest consistent bound in ``--bound``'s units (raw rows), from the processed rows.

    The processed rows' bounds are ``bound_k = gain * b_j + r_k`` (b_j the raw bound of row k's joint j, gain the
    filter's ``||h||_1``, r_k >= 0 the folded rounding terms, which do not decrease with b). ``scale`` is an upper
    bound of the smallest factor s that makes ``s * bound`` consistent (:func:`wls_consistency`, the Chebyshev LP
    on the rows scaled by their bound). Raw bounds ``b'_j = b_j + (s - 1) max_{k in j} bound_k / gain`` give
    processed bounds ``>= s * bound_k`` row by row, so they are consistent: ``raw`` (n joints,) [N m] is that
    choice (the given per-joint bounds scaled up together; other per-joint trade-offs may exist), ``raw_max`` the
    one number that covers every joint, ``processed`` the smallest consistent scalar bound of the processed rows
    [N m] (not in --bound's units)."""
    b = np.broadcast_to(np.asarray(bound, dtype=float), (len(y),))
    joint_of_row = np.asarray(joint_of_row)
    raw = np.asarray(raw_bound, dtype=float)
    s = max(1.0, wls_consistency(W, y, b, prior)["scale"])
    need = np.array([b[joint_of_row == j].max() if np.any(joint_of_row == j) else 0.0 for j in range(raw.size)])
    raw_new = np.nextafter(raw + (s - 1.0) * need / gain, np.inf)
    return {"scale": s, "raw": raw_new.tolist(), "raw_max": float(raw_new.max()),
            "processed": float(ident.min_consistent_bound(W, y, prior)), "gain": gain}


def _estimate_and_write(result: dict, W, y, bound, prior, method: str, joints: int, names, joint_of_row, out,
                        pairs: str | None = None, raw_bound=None, gain: float | None = None,
                        timeout: float | None = None) -> dict:
    """The methods (``method``: one or a comma-separated list, :func:`check_method`) on (W, y, bound), judged side
    by side with the exact hull as reference (:mod:`scenarios.judging`: no truth, so ``enclosed`` is null, but the
    narrower-than-hull check runs), into ``result``; ``wls`` also gives the %sigma table (``result["wls"]``). A
    proven inconsistency is recorded (status ``inconsistent`` with ``min_bound``; ``consistent`` False), then
    ``result.json`` is written into the owned folder ``out``; ``pairs`` (``--pairs``) adds the feasible set's
    projections (``feasible_set.png``, drawn with the hull's box); returns ``result``."""
    from h4bench.scenarios import judging

    methods = judging.parse_methods(method)
    groups = np.asarray(joint_of_row, dtype=np.int64)
    outcomes, hull = judging.run_methods(methods, W, y, bound, prior, {"groups": groups}, timeout=timeout)
    if hull is None:  # no method other than the hull: still the reference of the verdict
        hull = outcomes.get("hull") or judging.run_method("hull", W, y, bound, prior, timeout=timeout)
    ref = judging.hull_reference(W, y, bound, prior, hull.box) if hull.status == "ok" else None
    result["methods"] = judging.judge(outcomes, ref, None, list(names))
    result["hull_reference"] = None if ref is None else ref.describe()
    for name, o in outcomes.items():
        if o.status == "inconsistent":
            result["methods"][name].update(error=type(o.error).__name__, min_bound=getattr(o.error, "min_bound", None),
                                           scale_lower=getattr(o.error, "scale_lower", None))
    if hull.status == "ok":
        result["consistent"] = True
    elif hull.status == "inconsistent":
        result["consistent"] = False
        result.setdefault("inconsistency", {"min_bound": getattr(hull.error, "min_bound", None),
                                            "scale_lower": getattr(hull.error, "scale_lower", None)})
        if raw_bound is not None and gain:
            result["inconsistency"]["smallest_consistent"] = consistent_raw_bound(W, y, bound, prior, joint_of_row,
                                                                                  raw_bound, gain)
    result["failed_methods"] = [n for n, o in outcomes.items() if o.status == "failed"]
    result["unsound"] = sorted(n for n, m in result["methods"].items() if m.get("unsound"))
    if "wls" in methods:
        w = ident.wls(W, y, joints=joints, names=names, joint_of_row=joint_of_row)
        result["wls"] = {"theta": np.asarray(w.theta).tolist(), "std": np.asarray(w.std).tolist(),
                         "rel_std_percent": np.asarray(w.rel_std_percent).tolist(),
                         "consistency": wls_consistency(W, y, bound, prior,
                                                        result.get("min_consistent_bound"))}
        if result.get("consistent") is None:
            result["consistent"] = result["wls"]["consistency"]["consistent"]
    with OwnedFolder(out, what={"scenario": result["scenario"], "kind": "identify"}) as tmp:
        chosen = _pairs(pairs, names)
        if chosen is not None and result.get("consistent") is not False:
            from h4bench.scenarios.feasible import identify_projections

            box = hull.box if hull.status == "ok" else None
            units = ident.PARAMETER_UNITS if tuple(names) == tuple(ident.PARAMETER_NAMES) else None  # the H4's
            result["feasible_set"] = identify_projections(tmp, W, y, bound, prior, names, None if chosen == "auto"
                                                          else chosen, box=box, method="hull", units=units)
        write_json(tmp / "result.json", result)
    return result
