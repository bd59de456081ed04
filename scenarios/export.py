"""``h4bench export RUN_DIR log.csv``: a simulated run's dataset as the CSV ``identify`` reads, with the run's true
error specification, so that the certified box of a simulated log is two commands::

    h4bench run paper --quick
    h4bench export runs/paper log.csv            # writes log.csv and spec.toml beside it
    h4bench identify log.csv --spec spec.toml    # the certified box; the truth is in runs/paper/result.json

The CSV has the header ``t,q1..q4,tau1..tau4`` and one row per sample of the run's ``dataset.npz``, every
number written with 17 significant digits (``repr``), so reading it back (:meth:`sim.Dataset.from_csv`) gives the
dataset's arrays bit for bit. The specification (``spec.toml``, ``[error_model]`` of
:class:`~ident.processing.errorspec.ErrorSpec`, and ``[certified]``, the certified scenario's processing) is the
one the ``certified`` scenario states for a simulated run (:func:`scenarios.certificate.simulated_error_spec`):
the sample period, the encoder's counts per turn, held torques, the injected torque error's rigorous bound, and
the motion bounds stated from the reference trajectory's peaks times the scenario's tracking margins (the run's
own ``error_model`` when the run was a certified one). Nothing in it is read from the ground truth.

Files: each is written atomically; an existing file is replaced only when h4bench wrote it and it is unchanged
since (a hidden ``.<name>.h4bench`` beside it holds the SHA-256 of what was written); any other file is refused
with an error naming the option.
"""

from __future__ import annotations

import gzip
import hashlib
import json
from pathlib import Path

import numpy as np

from h4bench.sim.dataset import atomic_write_bytes

__all__ = ["ExportError", "export_run", "log_csv_text", "run_error_spec", "spec_toml_text", "toml_value"]


class ExportError(ValueError):
    """A run folder that cannot be exported, or a target file h4bench may not write."""


def toml_value(v) -> str:
    """A TOML value: a string (escaped), a bool, an int, a float (``repr``: exact), or a list of those."""
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string: JSON's escapes (\\, \", \uXXXX) are TOML's
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))


def log_csv_text(t, q, tau) -> str:
    """The CSV ``identify`` reads: header ``t, q1..qn, tau1..taun``; t (N,) [s], q (N, n) [rad], tau (N, n) [N m],
    every number as its ``repr`` (17 significant digits at most: read back bit for bit)."""
    t, q, tau = np.asarray(t, dtype=float), np.asarray(q, dtype=float), np.asarray(tau, dtype=float)
    n = q.shape[1]
    head = ",".join(["t"] + [f"q{i + 1}" for i in range(n)] + [f"tau{i + 1}" for i in range(n)])
    body = np.column_stack([t, q, tau])
    return "\n".join([head] + [",".join(map(repr, row)) for row in body.tolist()]) + "\n"


def spec_toml_text(error_model: dict, certified: dict | None = None, comment: str = "") -> str:
    """A spec file: ``comment`` (lines prefixed ``#``), ``[error_model]`` (entries, then its ``sources`` as
    ``[error_model.sources]``) and, when given, ``[certified]``; None entries are left out."""
    lines = [f"# {line}" if line else "#" for line in comment.splitlines()]
    lines += ["[error_model]"]
    lines += [f"{k} = {toml_value(v)}" for k, v in error_model.items() if k != "sources" and v is not None]
    if error_model.get("sources"):
        lines += ["", "[error_model.sources]"]
        lines += [f"{k} = {toml_value(v)}" for k, v in error_model["sources"].items()]
    if certified:
        lines += ["", "[certified]"] + [f"{k} = {toml_value(v)}" for k, v in certified.items()]
    return "\n".join(lines) + "\n"


def _read_result(run_dir: Path) -> dict:
    path = run_dir / "result.json"
    if not path.is_file():
        raise ExportError(f"RUN_DIR must be a run folder written by h4bench run (result.json, dataset.npz), got "
                          f"{str(run_dir)!r} ({path.name} not found)")
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ExportError(f"RUN_DIR {str(run_dir)!r}: cannot read result.json ({exc})") from None


def run_error_spec(run_dir):
    """The run's true :class:`~ident.processing.errorspec.ErrorSpec` and ``[certified]`` processing table.

    A certified run's own ``error_model`` (result.json) when it has one; else the certified scenario's statement
    for a simulated run (:func:`scenarios.certificate.simulated_error_spec` with the ``certified`` kind's
    ``[error_model]`` defaults): the dataset's sample period and encoder counts (``dataset.json``), the injected
    torque error's bound (result.json ``noise.bound``), the reference trajectory's peaks (``trajectory.npz``)
    times the tracking margins and the friction band of the shipped model's friction rows (a certified run on
    another model has its own in ``result.json``). Returns ``(ErrorSpec, dict)``.
    """
    from h4bench.ident.processing.errorspec import SPEC_ENTRIES, ErrorSpec
    from h4bench.scenarios import registry
    from h4bench.scenarios.certificate import simulated_error_spec
    from h4bench.trajectories.trajectory import Trajectory

    run_dir = Path(run_dir)
    result = _read_result(run_dir)
    defaults = registry.spec_defaults()
    certified = {k: v for k, v in defaults["certified"].items() if k != "enabled"}
    if isinstance(result.get("error_model"), dict):
        table = {k: v for k, v in result["error_model"].items() if k != "n_joints" and v is not None}
        if isinstance(table.get("sources"), dict):
            # a certified run's sources also list what its equation assumed without proof (assembly mode, sin/cos,
            # the fallback's factor): not entries of a specification; identify --spec lists its own again
            table["sources"] = {k: v for k, v in table["sources"].items() if k in SPEC_ENTRIES}
        return ErrorSpec.from_mapping(table, 4, where=f"{run_dir / 'result.json'} error_model"), certified
    dataset = _load_dataset(run_dir)
    if not (run_dir / "trajectory.npz").is_file():
        raise ExportError(f"RUN_DIR {str(run_dir)!r} has no trajectory.npz: the stated motion bounds come from the "
                          "reference trajectory (a simulated run's folder holds it)")
    reference = Trajectory.load(run_dir / "trajectory.npz")
    noise = result.get("noise") or {}
    if not isinstance(noise.get("bound"), (int, float)):
        raise ExportError(f"RUN_DIR {str(run_dir)!r}: result.json has no noise.bound (the injected torque error's "
                          "bound): not a simulated run")
    from h4bench.scenarios.spec import DEFAULTS

    spec = {"error_model": dict(defaults["error_model"]), "prior": dict(DEFAULTS["prior"]),
            "encoder": {"counts_per_turn": dataset.metadata.get("encoder_counts") or 0}}
    return simulated_error_spec(spec, reference, dataset.dt, float(noise["bound"]), dataset.tau), certified


def _load_dataset(run_dir: Path):
    from h4bench import sim

    if not (run_dir / "dataset.npz").is_file():
        raise ExportError(f"RUN_DIR must hold a run's dataset (dataset.npz), got {str(run_dir)!r} without one "
                          "(a campaign's folder holds none: re-run one run with --only INDEX)")
    return sim.Dataset.load(run_dir / "dataset")


def _marker(path: Path) -> Path:
    return path.parent / f".{path.name}.h4bench"


def _check_writable(path: Path, option: str) -> None:
    """Refuse an existing ``path`` that h4bench did not write, or that changed since (module docstring)."""
    if path.is_symlink() or (path.exists() and not path.is_file()):
        raise ExportError(f"{option} must be a file path, got {str(path)!r} (a folder or a link)")
    if not path.exists():
        return
    marker = _marker(path)
    try:
        written = json.loads(marker.read_text()).get("sha256")
    except (OSError, json.JSONDecodeError, AttributeError):
        written = None
    if written != hashlib.sha256(path.read_bytes()).hexdigest():
        raise ExportError(f"{option} {str(path)!r} exists and h4bench did not write it (or it changed since): "
                          "choose another path; h4bench never replaces a user's file")


def _write_owned(path: Path, data: bytes) -> None:
    atomic_write_bytes(path, data)
    atomic_write_bytes(_marker(path), json.dumps({"h4bench": "export",
                                                  "sha256": hashlib.sha256(data).hexdigest()}).encode())


def export_run(run_dir, csv_path, spec_path=None) -> dict:
    """Write the run folder ``run_dir``'s dataset as the CSV ``csv_path`` (gzip-compressed when the name ends in
    ``.gz``) and its true error specification as ``spec_path`` (default ``spec.toml`` beside the CSV); returns
    ``{"csv", "spec", "rows", "seconds", "error_model"}``. Errors (:class:`ExportError`, a ValueError) name
    ``RUN_DIR``, ``LOG_CSV`` or ``--spec``."""
    run_dir = Path(run_dir)
    csv_path = Path(csv_path)
    spec_path = Path(spec_path) if spec_path is not None else csv_path.parent / "spec.toml"
    if csv_path.resolve() == spec_path.resolve():
        raise ExportError(f"--spec must differ from LOG_CSV, got {str(spec_path)!r} for both")
    for path, option in ((csv_path, "LOG_CSV"), (spec_path, "--spec")):
        _check_writable(path, option)
        if not path.parent.is_dir():
            raise ExportError(f"{option} {str(path)!r}: its folder {str(path.parent)!r} does not exist")
    _read_result(run_dir)
    dataset = _load_dataset(run_dir)
    error_spec, certified = run_error_spec(run_dir)
    table = error_spec.to_dict()
    table.pop("n_joints")
    res = table.pop("position_resolution")
    if res is not None and dataset.metadata.get("encoder_counts"):
        counts = int(dataset.metadata["encoder_counts"])
        if np.allclose(res, 2 * np.pi / counts, rtol=0, atol=0):
            table = {"counts_per_turn": counts, **table}
            res = None
    if res is not None:
        table = {"position_resolution": res, **table}
    comment = (f"The true error specification of the simulated run {run_dir} (h4bench export), for\n"
               f"  h4bench identify {csv_path.name} --spec {spec_path.name}\n"
               "[error_model]: the certified scenario's statement (scenarios/certificate.py); nothing read from the\n"
               "ground truth. The run's true parameters are in its result.json (\"true\").")
    text = log_csv_text(dataset.t, dataset.q, dataset.tau).encode()
    if csv_path.name.endswith(".gz"):
        text = gzip.compress(text, mtime=0)
    _write_owned(csv_path, text)
    _write_owned(spec_path, spec_toml_text(table, certified, comment).encode())
    return {"csv": str(csv_path), "spec": str(spec_path), "rows": len(dataset),
            "seconds": float(dataset.t[-1] - dataset.t[0]), "error_model": error_spec.to_dict()}
