"""The on-disk cache of joint-controller designs (:func:`sim.control_design.design_joint_controller`).

A design takes about a second (root finding and eight python-control step responses) and a campaign's workers
each start with none; the gains depend only on the design's inputs. Entries live in ``cache_root() /
"controllers"``: ``$H4BENCH_CACHE`` if set, else ``$XDG_CACHE_HOME/h4bench`` (default ``~/.cache/h4bench``),
the root the trajectory designs use too. The key is the SHA-256 of the inputs (J and Fv bit for bit, the other
arguments), the source of the design modules and the versions of python-control, scipy and numpy; not the BLAS
kernel nor its thread count (the gains come from scalar root finding on directly evaluated responses, no
BLAS, and :mod:`h4bench.portable` for the axis inertia: the same bits on any CPU). An entry
stores every float as ``float.hex`` (exact), is written atomically (temp file + ``os.replace``) and is used only
if it parses into a design of the same inputs; anything else is recomputed and overwritten. A cache that cannot
be written costs nothing but the next lookup.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from h4bench import portable

__all__ = ["cache_root", "design_key", "load_array", "load_design", "store_array", "store_design"]

CACHE_ENV = "H4BENCH_CACHE"
_CODE = ("control_design.py", "controller.py", "design_cache.py")


def cache_root() -> Path:
    """The project's cache folder (module docstring); not created here."""
    root = os.environ.get(CACHE_ENV)
    if root:
        return Path(root).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "h4bench"


def _versions() -> list:
    out = []
    for dist in ("control", "scipy", "numpy"):
        try:
            out.append(importlib.metadata.version(dist))
        except importlib.metadata.PackageNotFoundError:
            out.append(None)
    return out


def design_key(J: np.ndarray, Fv: np.ndarray, bandwidth_hz: float, dt: float, pm_deg: float,
               velocity_filter_hz: float | None) -> str:
    """SHA-256 naming the design of these (validated) inputs, with the design code and library versions."""
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in _CODE:
        h.update(name.encode())
        h.update((here / name).read_bytes())
    h.update(b"portable.py")  # the design's logarithms (h4bench.portable.log)
    h.update(Path(portable.__file__).read_bytes())
    inputs = [[float(v).hex() for v in J], [float(v).hex() for v in Fv], float(bandwidth_hz).hex(),
              float(dt).hex(), float(pm_deg).hex(), None if velocity_filter_hz is None else float(velocity_filter_hz).hex(),
              _versions()]
    h.update(json.dumps(inputs).encode())
    return h.hexdigest()


def _path(key: str) -> Path:
    return cache_root() / "controllers" / f"{key}.json"


def _hex(values) -> list[str]:
    return [float(v).hex() for v in np.ravel(values)]


def _unhex(values) -> np.ndarray:
    return np.array([float.fromhex(v) for v in values], dtype=float)


def _report_dict(rep) -> dict:
    out = {k: float(getattr(rep, k)).hex() for k in _REPORT_FLOATS}
    poles = np.asarray(rep.poles)
    out.update(poles_real=_hex(poles.real), poles_imag=_hex(poles.imag), poles_complex=bool(np.iscomplexobj(poles)),
               stable=bool(rep.stable))
    return out


_REPORT_FLOATS = ("bandwidth_hz", "crossover_hz", "phase_margin_deg", "gain_margin", "lower_gain_margin",
                  "rise_time", "settling_time", "overshoot_pct")


def _atomic_write(path: Path, write) -> None:
    """``write(file)`` into a temp file beside ``path``, then ``os.replace``; an unwritable cache is ignored."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                write(f)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError:
        pass


def store_array(folder: str, key: str, arr: np.ndarray) -> None:
    """Write a float64 array under ``cache_root() / folder / key.npy``, atomically (the key names its inputs)."""
    _atomic_write(cache_root() / folder / f"{key}.npy",
                  lambda f: np.save(f, np.ascontiguousarray(arr, dtype=np.float64), allow_pickle=False))


def load_array(folder: str, key: str, shape: tuple) -> np.ndarray | None:
    """The stored array of ``key`` if it reads back as a finite float64 array of ``shape``, else None."""
    try:
        arr = np.load(cache_root() / folder / f"{key}.npy", allow_pickle=False)
    except (OSError, ValueError):
        return None
    if arr.dtype != np.float64 or arr.shape != tuple(shape) or not np.all(np.isfinite(arr)):
        return None
    return arr


def store_design(key: str, design) -> None:
    """Write ``design`` (a ControllerDesign) under ``key``, atomically; an unwritable cache is ignored."""
    entry = {"key": key, "J": _hex(design.J), "Fv": _hex(design.Fv), "kp": _hex(design.kp), "kv": _hex(design.kv),
             "ki": _hex(design.ki), "dt": float(design.dt).hex(),
             "velocity_filter_hz": None if design.velocity_filter_hz is None else float(design.velocity_filter_hz).hex(),
             "bandwidth_hz": float(design.bandwidth_hz).hex(), "phase_margin_deg": float(design.phase_margin_deg).hex(),
             "continuous": [_report_dict(r) for r in design.continuous],
             "discrete": [_report_dict(r) for r in design.discrete]}
    _atomic_write(_path(key), lambda f: f.write(json.dumps(entry).encode()))


def load_design(key: str, J: np.ndarray, Fv: np.ndarray, bandwidth_hz: float, dt: float, pm_deg: float,
                velocity_filter_hz: float | None, design_type, report_type):
    """The stored design of ``key`` built with ``design_type(**fields)`` and ``report_type(**fields)`` (the
    ControllerDesign and LoopReport classes, passed in: this module imports no design code) when it parses and
    holds exactly these inputs, else None."""
    try:
        entry = json.loads(_path(key).read_text())
        if entry.get("key") != key:
            return None

        def report(d):
            poles = _unhex(d["poles_real"])
            if d["poles_complex"]:  # real and imaginary parts set apart: exact, signed zeros included
                c = np.empty(poles.shape, dtype=complex)
                c.real, c.imag = poles, _unhex(d["poles_imag"])
                poles = c
            return report_type(**{k: float.fromhex(d[k]) for k in _REPORT_FLOATS}, poles=poles,
                               stable=bool(d["stable"]))

        vf = None if entry["velocity_filter_hz"] is None else float.fromhex(entry["velocity_filter_hz"])
        arrays = {k: _unhex(entry[k]) for k in ("J", "Fv", "kp", "kv", "ki")}
        design = design_type(**arrays, dt=float.fromhex(entry["dt"]), velocity_filter_hz=vf,
                             bandwidth_hz=float.fromhex(entry["bandwidth_hz"]),
                             phase_margin_deg=float.fromhex(entry["phase_margin_deg"]),
                             continuous=tuple(report(d) for d in entry["continuous"]),
                             discrete=tuple(report(d) for d in entry["discrete"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None
    same = (np.array_equal(design.J, J) and np.array_equal(design.Fv, Fv) and design.dt == dt
            and design.bandwidth_hz == bandwidth_hz and design.phase_margin_deg == pm_deg
            and design.velocity_filter_hz == velocity_filter_hz
            and all(a.shape == (4,) for a in (design.kp, design.kv, design.ki)))
    if not same:
        return None
    for arr in (design.J, design.Fv, design.kp, design.kv, design.ki):
        arr.setflags(write=False)
    return design
