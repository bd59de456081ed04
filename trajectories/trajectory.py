"""The :class:`Trajectory` data type: a sampled reference for the H4, saved as ``.npz`` with JSON metadata."""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from h4bench.sim.dataset import atomic_write_bytes

FORMAT = "h4bench.trajectory/1"
ARRAYS = ("t", "x", "q", "qd", "qdd")


def _jsonable(value, name: str):
    """A JSON round-tripped copy (tuples become lists, numpy scalars/arrays become Python values)."""

    def default(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
        raise TypeError(f"{name} must be JSON-serialisable, got a {type(o).__name__}")

    return json.loads(json.dumps(value, default=default))


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A reference motion of the H4 sampled at a constant period.

    t : (n,) time [s], ``t[k] = k dt``; x : (n, 4) nacelle pose reference (x, y, z, theta) [m, m, m, rad];
    q, qd, qdd : (n, 4) motor angle [rad], speed [rad/s] and acceleration [rad/s^2] references (exact
    derivatives of the generating curve, not finite differences);
    kind : how it was made (``"fourier"``, ``"waypoints"``, ``"fourier+uniform-slowdown"``, ...);
    parameters : JSON-ready dict (coefficients, seed, limits, timing, ...); checks : the report of
    :func:`trajectories.check_trajectory` computed when the trajectory was made.
    """

    t: np.ndarray
    x: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    kind: str
    parameters: dict = field(default_factory=dict)
    checks: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"t must have shape (n,) with n >= 2, got {t.shape}")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("t must be finite and strictly increasing")
        for name in ARRAYS[1:]:
            arr = np.array(getattr(self, name), dtype=float)
            if arr.shape != (t.size, 4):
                raise ValueError(f"{name} must have shape ({t.size}, 4), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
                raise ValueError(f"{name} must be finite, got NaN/inf at sample(s) {bad[:10].tolist()}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        t.setflags(write=False)
        object.__setattr__(self, "t", t)
        if not isinstance(self.kind, str) or not self.kind:
            raise TypeError(f"kind must be a non-empty str, got {self.kind!r}")
        object.__setattr__(self, "parameters", _jsonable(dict(self.parameters), "parameters"))
        object.__setattr__(self, "checks", _jsonable(dict(self.checks), "checks"))

    def __repr__(self) -> str:
        return (f"Trajectory(kind={self.kind!r}, n={self.n}, dt={self.dt:g} s, duration={self.duration:.4g} s, "
                f"feasible={self.checks.get('feasible')})")

    @property
    def n(self) -> int:
        return self.t.size

    @property
    def dt(self) -> float:
        """Sampling period [s]."""
        return float(self.t[1] - self.t[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def report(self) -> dict:
        """The check report stored when the trajectory was made (a copy): cond(W) (raw, scaled, normalised), peak
        |qd|, |qdd|, |tau| per joint vs limits, margins to the workspace box and joint range, max cond(Jx),
        violations. To recompute it for another geometry or limits use :func:`trajectories.check_trajectory`
        (the data type does not depend on its checks)."""
        return json.loads(json.dumps(self.checks))

    def summary(self) -> str:
        """A few human-readable lines of the stored report."""
        r = self.checks
        if not r:
            return f"{self.kind} trajectory: {self.n} samples, {self.duration:.3f} s (no report)"
        fmt = lambda v: "(" + ", ".join(f"{a:.3g}" for a in v) + ")"  # noqa: E731
        return "\n".join([
            f"{self.kind} trajectory: {self.n} samples at {1 / self.dt:.0f} Hz, {self.duration:.3f} s",
            f"  cond(W diag(theta_nom)) = {r['cond_W_scaled']:.4g}, cond(W normalised) = {r['cond_W_normalised']:.4g}",
            f"  peak |qd|  {fmt(r['peak_qd'])} rad/s    limit {fmt(r['limit_qd'])}",
            f"  peak |qdd| {fmt(r['peak_qdd'])} rad/s^2  limit {fmt(r['limit_qdd'])}",
            f"  peak |tau| {fmt(r['peak_tau'])} N m      limit {fmt(r['limit_tau'])}",
            f"  max cond(Jx) {r['max_cond_jx']:.3g} (limit {r['limit_cond_jx']:.3g}); workspace margin "
            f"{r['min_workspace_margin_m'] * 1e3:.1f} mm, theta margin {r['min_theta_margin_rad']:.3f} rad",
            f"  feasible: {r['feasible']}" + (f" violations {r['violations']}" if r["violations"] else ""),
        ])

    def save(self, path) -> Path:
        """Write ``path`` (.npz: the arrays and a JSON ``metadata`` entry) atomically (temp file, os.replace)."""
        path = Path(path)
        meta = json.dumps({"format": FORMAT, "kind": self.kind, "parameters": self.parameters, "checks": self.checks})
        buf = io.BytesIO()
        np.savez(buf, metadata=np.array(meta), **{name: getattr(self, name) for name in ARRAYS})
        atomic_write_bytes(path, buf.getvalue())
        return path

    @classmethod
    def load(cls, path) -> "Trajectory":
        """Read a file written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"path must be an existing trajectory file, got {str(path)!r}")
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in ("metadata",) + ARRAYS if k not in data.files]
            if missing:
                raise ValueError(f"path {str(path)!r} is not a trajectory file (missing {missing})")
            meta = json.loads(str(data["metadata"]))
            arrays = {name: data[name] for name in ARRAYS}
        if meta.get("format") != FORMAT:
            raise ValueError(f"path {str(path)!r} has format {meta.get('format')!r}, expected {FORMAT!r}")
        return cls(kind=meta["kind"], parameters=meta["parameters"], checks=meta["checks"], **arrays)

    def equals(self, other: "Trajectory") -> bool:
        """Exact equality of every array and of the metadata."""
        return (isinstance(other, Trajectory) and self.kind == other.kind and self.parameters == other.parameters
                and self.checks == other.checks
                and all(np.array_equal(getattr(self, n), getattr(other, n)) for n in ARRAYS))
