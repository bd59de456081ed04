"""Datasets: what a robot (or the simulator) measures, and, kept apart, the simulator's ground truth.

A :class:`Dataset` holds only what a real H4 log holds: sample times ``t`` (n,) [s], measured motor angles
``q`` (n, 4) [rad] (encoder-quantised) and measured motor torques ``tau`` (n, 4) [N m] (``G_T V_T``, the
current reference), plus metadata. A :class:`GroundTruth` holds the simulator's exact states, the true
parameters, the applied torques and the injected noise; estimators never read it.

Files: ``<stem>.npz`` (arrays) + ``<stem>.json`` (metadata), each written atomically (temp file + rename).
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from h4bench.sim.csvlog import DatasetError, read_log  # DatasetError lives with the reader (the lower module)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: a temp file in the same folder, fsync, then os.replace.

    Parameters
    ----------
    path : file to write (its folder must exist)
    data : the bytes

    Returns
    -------
    None
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file the usual permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _save_npz(path: Path, arrays: dict) -> None:
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def json_default(obj):
    """JSON encoder fallback (``json.dumps(default=...)``): numpy arrays, numpy scalars and paths as
    lists, numbers and strings.

    Parameters
    ----------
    obj : the object json cannot encode

    Returns
    -------
    a JSON-able value (TypeError if there is none)
    """
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _stem(path) -> Path:
    path = Path(path)
    return path.with_suffix("") if path.suffix in (".npz", ".json") else path


def _check_series(name: str, arr, n: int | None, width: int = 4) -> np.ndarray:
    arr = np.asarray(arr, dtype=float)
    expected = (n, width) if n is not None else ("n", width)
    if arr.ndim != 2 or arr.shape[1] != width or (n is not None and arr.shape[0] != n):
        raise DatasetError(f"{name} must have shape {expected}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        k = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
        raise DatasetError(f"{name} must be finite, got NaN/inf at sample {k}")
    return arr


def _check_time(t, source: str | None = None) -> np.ndarray:
    """t (n,) [s], finite, strictly increasing and uniform to 1 %. ``source``: the CSV file the samples came
    from; the errors then name it and the 1-based data rows (the header excluded), else 0-based samples."""
    t = np.asarray(t, dtype=float)

    def at(k: int) -> str:
        return f"data row {k + 1}" if source else f"t[{k}]"

    where = f"CSV {source!r}: column t" if source else "t"
    if t.ndim != 1 or t.size < 3:
        raise DatasetError(f"{where} must be a 1-D array of at least 3 sample times, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise DatasetError(f"{where} must be finite, got NaN/inf at {at(int(np.flatnonzero(~np.isfinite(t))[0]))}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise DatasetError(f"{where} must be strictly increasing, got {float(t[k])!r} s at {at(k)} after {float(t[k - 1])!r} s "
                           f"at {at(k - 1)}")
    med = np.median(dt)
    if np.max(np.abs(dt - med)) > 0.01 * med:
        k = int(np.argmax(np.abs(dt - med))) + 1
        raise DatasetError(f"{where} must be uniformly sampled (1 % tolerance), got a step of {dt[k - 1]:.6g} s "
                           f"between {at(k - 1)} and {at(k)} against a median of {med:.6g} s")
    return t


@dataclass
class Dataset:
    """Measured data: t (n,) [s], q (n, 4) [rad], tau (n, 4) [N m], metadata (JSON-able dict)."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = _check_time(self.t)
        self.q = _check_series("q", self.q, self.t.size)
        self.tau = _check_series("tau", self.tau, self.t.size)

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.t)))

    def __len__(self) -> int:
        return self.t.size

    def slice(self, start: int, stop: int) -> "Dataset":
        """Samples ``start:stop`` (a Python slice of the rows) with a copy of the metadata."""
        return Dataset(self.t[start:stop], self.q[start:stop], self.tau[start:stop], dict(self.metadata))

    def save(self, path) -> Path:
        """Write ``<stem>.npz`` (t, q, tau) and ``<stem>.json`` (metadata), each atomically; returns the .npz path."""
        stem = _stem(path)
        _save_npz(stem.with_suffix(".npz"), {"t": self.t, "q": self.q, "tau": self.tau})
        atomic_write_bytes(stem.with_suffix(".json"), json.dumps(self.metadata, indent=2, default=json_default).encode())
        return stem.with_suffix(".npz")

    @classmethod
    def load(cls, path) -> "Dataset":
        stem = _stem(path)
        if not stem.with_suffix(".npz").is_file():
            raise DatasetError(f"path must name a saved dataset, got {str(path)!r} ({stem.with_suffix('.npz')} not found)")
        with np.load(stem.with_suffix(".npz")) as z:
            arrays = {k: z[k] for k in ("t", "q", "tau")}
        meta_path = stem.with_suffix(".json")
        metadata = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
        return cls(metadata=metadata, **arrays)

    @classmethod
    def from_csv(cls, path, delimiter: str = ",") -> "Dataset":
        """Import a robot log with a header row and columns ``t, q1..q4, tau1..tau4`` (SI units; extra
        columns are ignored), in bounded memory (:func:`sim.csvlog.read_log`). Errors name the file, the
        column or the sample."""
        t, q, tau = read_log(path, delimiter)
        return cls(_check_time(t, str(path)), q, tau, {"source": "csv", "path": str(path)})


@dataclass
class GroundTruth:
    """The simulator's truth at the sample instants: theta (p,), exact q/qd/qdd (n, 4), MuJoCo's nacelle pose
    x and acceleration xdd (n, 4), applied torques (n, 4), injected noise (n, 4) = applied - measured
    (before actuator clipping), loop violation (n,) [m], and h the internal timestep [s]."""

    theta: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    x: np.ndarray
    xdd: np.ndarray
    tau_applied: np.ndarray
    noise: np.ndarray
    loop_violation: np.ndarray
    h: float
    names: tuple = ()

    _ARRAYS = ("theta", "q", "qd", "qdd", "x", "xdd", "tau_applied", "noise", "loop_violation")

    def save(self, path) -> Path:
        """Write ``<stem>.npz`` (every array, h and the parameter names) atomically; returns its path."""
        stem = _stem(path)
        arrays = {k: getattr(self, k) for k in self._ARRAYS}
        arrays["h"] = np.array(self.h)
        arrays["names"] = np.array(self.names, dtype=str)
        _save_npz(stem.with_suffix(".npz"), arrays)
        return stem.with_suffix(".npz")

    @classmethod
    def load(cls, path) -> "GroundTruth":
        stem = _stem(path)
        with np.load(stem.with_suffix(".npz")) as z:
            kw = {k: z[k] for k in cls._ARRAYS}
            return cls(h=float(z["h"]), names=tuple(str(s) for s in z["names"]), **kw)
