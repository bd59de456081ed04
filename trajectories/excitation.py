"""The scenario layer's entry point: :func:`design_excitation`, a bounded-error (or cond) optimised excitation
under the H4-class envelope, cached on disk by its inputs.

Cache. A design takes seconds to tens of seconds; campaigns and reruns ask for the same ones. Entries live in
``$H4BENCH_CACHE/trajectories`` if the environment variable ``H4BENCH_CACHE`` is set, else in
``$XDG_CACHE_HOME/h4bench/trajectories`` (default ``~/.cache/h4bench/trajectories``). The key is the SHA-256 of
every input that changes the result: the geometry's arrays, the limits, seed, duration, criterion, processing
settings, targets, nominal parameters, the remaining design options, the source code of the design modules
(:data:`CODE_FILES` and :mod:`h4bench.portable`, so an edit invalidates old entries) and the versions of numpy
and scipy. Not the BLAS kernel nor its thread count: the design's result does not depend on them (its
criterion, constraints and gradients are computed without BLAS and its iterates on a fixed grid,
:mod:`trajectories.design`), so an entry designed on one machine is the one any other would design. Files are
written atomically (temp file + ``os.replace``, :meth:`trajectories.Trajectory.save`). An entry is used only if it loads, carries the same key
and inputs, and either holds exactly the arrays that passed :func:`trajectories.check_trajectory` when it was
designed (their SHA-256 and the check report's, stored with the entry, :func:`content_hash`: the key already
covers the geometry, limits, nominal parameters and the checks' code, so the check would repeat itself) or, for
an entry without that hash, passes the check again on the caller's geometry and limits; otherwise it is
recomputed and overwritten (never trusted). An entry loaded and checked once is kept in the
process (:data:`MEMORY_SIZE` entries) and returned again while its file is unchanged, so a campaign's worker
loads and checks each shared design once; :func:`cache_stats` says how the calls were served and what they
cost. A cache that cannot be written (a read-only
folder, ``H4BENCH_CACHE`` naming a file) never costs a run: the design is returned uncached and a
:class:`CacheWarning` says why.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from h4bench import ident, portable
from h4bench.fingerprint import array_digest
from h4bench import sim
from h4bench.trajectories.bounded import as_targets
from h4bench.trajectories.checks import check_trajectory
from h4bench.trajectories.fourier import CRITERIA, as_processing, fourier_excitation
from h4bench.trajectories.limits import Limits, as_limits, as_theta
from h4bench.trajectories.trajectory import Trajectory

CACHE_ENV = "H4BENCH_CACHE"
#: Source files whose content enters the cache key.
CODE_FILES = ("bounded.py", "checks.py", "design.py", "excitation.py", "fourier.py", "limits.py", "trajectory.py")
#: Defaults of :func:`design_excitation`. Fast-phase fundamental and harmonics for the H4-class envelope (10 s,
#: seed 0, max relative h: 0.5 Hz x 5 harmonics 2.44, 0.75 x 4 1.97-2.00, 1.0 x 5 1.97 with 3 % less torque
#: headroom); 40 SLSQP iterations: the smooth max reached 0.754 / 0.739 (seeds 0 / 1) against 0.754 / 0.743 at
#: 60 and 0.779 / 0.796 at 25, in about half the time of 60.
DEFAULT_OPTIONS = {"harmonics": 4, "base_hz": 0.75, "max_iter": 40}


class CacheWarning(UserWarning):
    """The trajectory cache could not be written; the design was used without it."""


def cache_dir() -> Path:
    """The trajectory cache folder (module docstring); not created here."""
    root = os.environ.get(CACHE_ENV)
    if root:
        return Path(root).expanduser() / "trajectories"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "h4bench" / "trajectories"


def _code_hash() -> str:
    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in CODE_FILES:
        h.update(name.encode())
        h.update((here / name).read_bytes())
    h.update(b"portable.py")
    h.update(Path(portable.__file__).read_bytes())
    return h.hexdigest()


def _versions() -> dict:
    import scipy  # noqa: PLC0415

    return {"numpy": np.__version__, "scipy": scipy.__version__}


def geometry_hash(geometry) -> str:
    """SHA-256 of every field of a :class:`sim.H4Geometry` (arrays as float64/int64 bytes, with shapes)."""
    h = hashlib.sha256()
    for f in fields(geometry):
        value = getattr(geometry, f.name)
        arr = np.asarray(value)
        arr = arr.astype(np.float64 if arr.dtype.kind == "f" else np.int64)
        h.update(f.name.encode())
        h.update(str(arr.shape).encode())
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def cache_inputs(geometry, duration, seed, limits, criterion, processing, targets, theta_nominal, options) -> dict:
    """The JSON-ready inputs that identify a design (what the key hashes): not the BLAS kernel nor its thread
    count, which do not change the result (module docstring)."""
    return {
        "geometry": geometry_hash(geometry), "code": _code_hash(), "versions": _versions(),
        "duration": float(duration), "seed": int(seed),
        "limits": limits.to_dict(), "criterion": criterion, "processing": asdict(processing),
        "targets": None if targets is None else [float(v) for v in targets],
        "theta_nominal": [float(v) for v in theta_nominal], "options": options,
    }


def cache_key(inputs: dict) -> str:
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()


def content_hash(traj: Trajectory) -> str:
    """SHA-256 of a trajectory's arrays (dtype, shape, bytes) and of its check report (JSON; null for a
    reference without one)."""
    return array_digest([(name, getattr(traj, name)) for name in ("t", "x", "q", "qd", "qdd")],
                        json.dumps(getattr(traj, "checks", None), sort_keys=True, default=str).encode())


def _load_valid(path: Path, key: str, inputs: dict, geometry, limits, theta) -> Trajectory | None:
    try:
        traj = Trajectory.load(path)
    except Exception:  # noqa: BLE001 - any unreadable entry is recomputed
        return None
    meta = traj.parameters.get("cache", {})
    if meta.get("key") != key or meta.get("inputs") != json.loads(json.dumps(inputs)):
        return None
    if meta.get("content") is not None and meta["content"] == content_hash(traj) \
            and (traj.checks or {}).get("feasible") is True:
        return traj  # the very arrays that passed the checks when designed, under the same inputs and code
    try:
        report = check_trajectory(geometry, traj, limits, theta, raise_on_violation=False)
    except Exception:  # noqa: BLE001
        return None
    return traj if report["feasible"] else None


def design_excitation(geometry, duration: float = 10.0, seed: int = 0, limits=None, criterion: str = "h",
                      processing=None, targets=None, cache: bool = True, *, theta_nominal=None,
                      harmonics: int | None = None, base_hz: float | None = None, **options) -> Trajectory:
    """An optimised exciting trajectory for bounded-error identification (see :mod:`trajectories.bounded`).

    geometry : :class:`sim.H4Geometry`; duration [s]; seed : seeds the start; limits : :class:`Limits`
    (default :meth:`Limits.h4_class`, the H4-class envelope); criterion : ``"h"`` (smooth max of the relative
    bounded-error half-widths on the processed regressor) or ``"cond"``; processing :
    ``ident.processing.filtering.ProcessingSettings`` or a dict of its fields (the scenario's ``[processing]`` table; default
    ``ProcessingSettings()``); targets : (14,) > 0, default the nominal parameters; cache : look up / store the
    design in :func:`cache_dir`; theta_nominal : (14,) for the torque check (default
    ``trajectories.nominal_parameters()``); harmonics, base_hz : default :data:`DEFAULT_OPTIONS`; other keyword
    options go to :func:`trajectories.fourier_excitation` (dt, slow_ratio, max_iter, ...).

    Returns a :class:`Trajectory` (kind ``"fourier"``) that passed every check; ``parameters["cache"]`` holds
    the key, the inputs and whether it came from the cache (``parameters["cache"]["hit"]`` is not stored).
    """
    if not isinstance(geometry, sim.H4Geometry):
        raise TypeError(f"geometry must be a sim.H4Geometry, got {type(geometry).__name__}")
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    if not isinstance(cache, bool):
        raise TypeError(f"cache must be a bool, got {type(cache).__name__}")
    limits = Limits.h4_class() if limits is None else as_limits(limits)
    theta = as_theta(theta_nominal)
    dt = float(options.get("dt", 1e-3))
    settings = as_processing(processing, dt)
    if targets is not None:
        targets = as_targets(targets, len(ident.PARAMETER_NAMES))
    opts = dict(DEFAULT_OPTIONS)
    if harmonics is not None:
        opts["harmonics"] = harmonics
    if base_hz is not None:
        opts["base_hz"] = base_hz
    opts.update(options)
    inputs = cache_inputs(geometry, duration, seed, limits, criterion, settings, targets, theta, opts)
    key = cache_key(inputs)
    path = cache_dir() / f"{key}.npz"
    started = time.perf_counter()
    if cache:
        hit = _recall(path, key, inputs, geometry, limits, theta)
        if hit is not None:
            return hit
    traj = fourier_excitation(geometry, duration=duration, seed=seed, limits=limits, theta_nominal=theta,
                              criterion=criterion, processing=settings, targets=targets, **opts)
    params = dict(traj.parameters, cache={"key": key, "inputs": inputs, "content": content_hash(traj)})
    traj = Trajectory(t=traj.t, x=traj.x, q=traj.q, qd=traj.qd, qdd=traj.qdd, kind=traj.kind, parameters=params,
                      checks=traj.checks)
    if cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            traj.save(path)
        except OSError as exc:
            warnings.warn(f"the trajectory cache {str(path.parent)!r} cannot be written ({exc.strerror or exc}); "
                          f"the design is used without caching it (set {CACHE_ENV} to a writable folder)",
                          CacheWarning, stacklevel=2)
    _count("computed", started)
    return traj


#: Designs kept in this process (entry path -> ((key, size, mtime, inode) of the file, the checked Trajectory)).
_MEMORY: dict = {}
MEMORY_SIZE = 32
_STATS = {"memory": 0, "disk": 0, "computed": 0, "seconds_memory": 0.0, "seconds_disk": 0.0,
          "seconds_computed": 0.0}


def _count(source: str, started: float) -> None:
    _STATS[source] += 1
    _STATS[f"seconds_{source}"] += time.perf_counter() - started


def cache_stats() -> dict:
    """How this process's :func:`design_excitation` calls were served so far: counts ``memory`` (an entry loaded
    and checked earlier in this process, its file unchanged), ``disk`` (loaded and checked), ``computed``
    (designed), and the seconds spent in each (``seconds_memory``, ...). A copy; take differences around a
    call to time one lookup."""
    return dict(_STATS)


def _recall(path: Path, key: str, inputs: dict, geometry, limits, theta) -> Trajectory | None:
    """The cached design at ``path`` (module docstring), checked once per process: an entry already loaded
    and checked here is returned again while its file keeps the same signature (size, modification time,
    inode); the key covers the geometry, limits and nominal parameters the check depends on."""
    started = time.perf_counter()
    try:
        st = path.stat()
    except OSError:
        return None
    signature = (key, st.st_size, st.st_mtime_ns, st.st_ino)
    kept = _MEMORY.get(str(path))
    if kept is not None and kept[0] == signature:
        _count("memory", started)
        return kept[1]
    traj = _load_valid(path, key, inputs, geometry, limits, theta)
    if traj is None:
        return None
    for arr in (traj.t, traj.x, traj.q, traj.qd, traj.qdd):
        arr.setflags(write=False)  # shared by the calls that recall it
    if len(_MEMORY) >= MEMORY_SIZE:
        _MEMORY.pop(next(iter(_MEMORY)))
    _MEMORY[str(path)] = (signature, traj)
    _count("disk", started)
    return traj
