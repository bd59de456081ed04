"""The error specification a certified box rests on: sensor facts and stated assumptions, with units and sources.

A guaranteed box holds the true parameters only if the error model covers the real errors. An
:class:`ErrorSpec` lists every input of that error model as a fact about the sensors and the log, or as a stated
assumption about the true motion and the model, never as a number measured against a truth:

==========================  ========  ==================================================================
entry                       unit      meaning
==========================  ========  ==================================================================
``sample_period``           s         the log's sample period (uniform sampling)
``position_resolution``     rad       (n,) quantisation step of each joint's position (e.g. 2 pi / counts
                                      per turn); ``position_rounding`` "nearest": ``|e| <= res / 2``,
                                      "floor" (a counter truncates): ``|e| < res``
``significant_digits``      -         instead of a resolution: the log writes positions with this many
                                      significant digits (``|e| <=`` half a unit in the last written place
                                      of each sample)
``torque_timing``           -         "hold": logged torque k is held over ``[t_k, t_k + dt)``; "sample":
                                      it is the torque at the instant ``t_k``
``latency``                 s         bound on the delay between the logged and the applied torque
``torque_rate``             N m/s     (n,) bound on ``|d tau / dt|`` of the applied torque apart from the
                                      Coulomb friction's steps at reversals (used with a latency and with
                                      sample-instant torques; None: unknown, then ``latency`` must be 0).
                                      The steps need no entry: on a row they lie in the Coulomb column's
                                      sign interval (``ident.processing.weakform.coulomb_columns``)
``torque_error``            N m       (n,) bound on ``|applied - logged|`` torque (drive, current sensing,
                                      gain, ripple, ...)
``qd_max``, ``qdd_max``     rad/s,    (n,) stated bounds of the TRUE motion's speed and acceleration
                            rad/s^2   (there is no bound on the jerk: a held-torque step makes qdd jump)
``model_error``             N m       (n,) bound on what the regressor's structure leaves out
``friction_band``           rad/s     (n,) speed below which the friction is only known to lie in
                                      ``[-Fs, Fs]`` (0, the default: ideal Coulomb friction, exactly
                                      ``Fs sign(qd)`` at every non-zero speed); a step whose speed may be
                                      below it gets the Coulomb column's sign interval, like a step
                                      through rest (pre-sliding, stiction, a simulator's soft friction:
                                      :mod:`sim.friction`)
==========================  ========  ==================================================================

``sources`` says where each entry comes from (a data sheet, the file format, the simulator's settings, an
assumption). The processing that uses the specification (the derived interval equation) reads only these
entries; the stated motion bounds are checked against what the measured positions prove
(:mod:`ident.processing.motion_check`: a bound below it is contradicted by the data), and a simulation checks
them and the derived radii against its truth as well.

A TOML file (``h4bench identify --spec FILE``) holds one table ``[error_model]`` with these keys (per-joint
entries as one number or a list of n), an optional ``counts_per_turn`` instead of ``position_resolution``, and
an optional sub-table ``[error_model.sources]``.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from h4bench.ident.validation import per_joint, positive

__all__ = ["SPEC_ENTRIES", "ErrorSpec", "ErrorSpecError"]

_PER_JOINT = ("position_resolution", "torque_rate", "torque_error", "qd_max", "qdd_max", "model_error",
              "friction_band")
_ROUNDING = ("nearest", "floor")
# 10^e for e in [_POW10_LOW, ...], each correctly rounded (Python's parsing of "1e<e>"): numpy's ``10.0 ** k`` and
# ``np.log10`` run SIMD code chosen by CPU whose last bits differ (on an AVX-512 CPU ``10.0 ** k`` was one ulp
# below the correctly rounded power for 29 of the exponents -300..300)
_POW10_LOW = -340
_POW10 = np.array([float(f"1e{e}") for e in range(_POW10_LOW, 320)])


def _pow10(e) -> np.ndarray:
    """10^e (e integral floats or ints), correctly rounded, the same bits on any CPU."""
    i = np.clip(np.asarray(e, dtype=float) - _POW10_LOW, 0, _POW10.size - 1).astype(np.int64)
    return _POW10[i]


def _decade(a) -> np.ndarray:
    """The exponent E with ``fl(10^E) <= a < fl(10^(E+1))`` for a > 0 (finite floats): ``log10`` gives it within one
    on any CPU, the exact comparisons decide. A written decimal value is in the decade of the float it reads as."""
    e = np.floor(np.log10(a))
    e = np.where(a < _pow10(e), e - 1, e)
    return np.where(a >= _pow10(e + 1), e + 1, e)
_TIMING = ("hold", "sample")
_KEYS = {"sample_period", "position_resolution", "counts_per_turn", "significant_digits", "position_rounding",
         "torque_timing", "latency", "torque_rate", "torque_error", "qd_max", "qdd_max", "model_error",
         "friction_band", "sources"}
#: the entries an ``[error_model]`` table may hold (and its ``sources`` may name)
SPEC_ENTRIES = frozenset(_KEYS)


class ErrorSpecError(ValueError):
    """An error specification that is incomplete, inconsistent or not in its units."""


def _per_joint(value, name: str, n: int, *, allow_zero: bool = True) -> np.ndarray:
    try:
        return per_joint(value, name, n, allow_zero=allow_zero)
    except (TypeError, ValueError) as exc:
        raise ErrorSpecError(str(exc)) from None


def _positive(value, name: str, *, allow_zero: bool = False) -> float:
    try:
        return positive(value, name, allow_zero=allow_zero)
    except (TypeError, ValueError) as exc:
        raise ErrorSpecError(str(exc)) from None


@dataclass(frozen=True, eq=False)
class ErrorSpec:
    """Sensor facts and stated assumptions behind a certified error model (see the module docstring).

    Per-joint entries are (n,) float arrays; scalars given to the constructor are broadcast to n joints.
    """

    n_joints: int
    sample_period: float
    torque_error: np.ndarray
    qd_max: np.ndarray
    qdd_max: np.ndarray
    position_resolution: np.ndarray | None = None
    significant_digits: int | None = None
    position_rounding: str = "nearest"
    torque_timing: str = "hold"
    latency: float = 0.0
    torque_rate: np.ndarray | None = None
    model_error: np.ndarray | float = 0.0
    friction_band: np.ndarray | float = 0.0
    sources: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = self.n_joints
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ErrorSpecError(f"n_joints must be a positive integer, got {n!r}")
        set_ = object.__setattr__
        set_(self, "sample_period", _positive(self.sample_period, "sample_period"))
        set_(self, "latency", _positive(self.latency, "latency", allow_zero=True))
        if (self.position_resolution is None) == (self.significant_digits is None):
            raise ErrorSpecError("give exactly one of position_resolution (or counts_per_turn) and "
                                 f"significant_digits, got {self.position_resolution!r} and {self.significant_digits!r}")
        if self.position_resolution is not None:
            set_(self, "position_resolution", _per_joint(self.position_resolution, "position_resolution", n,
                                                         allow_zero=False))
        else:
            d = self.significant_digits
            if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or not 1 <= d <= 17:
                raise ErrorSpecError(f"significant_digits must be an integer in 1..17, got {d!r}")
        if self.position_rounding not in _ROUNDING:
            raise ErrorSpecError(f"position_rounding must be one of {_ROUNDING}, got {self.position_rounding!r}")
        if self.torque_timing not in _TIMING:
            raise ErrorSpecError(f"torque_timing must be one of {_TIMING}, got {self.torque_timing!r}")
        for name in ("torque_error", "qd_max", "qdd_max", "model_error", "friction_band"):
            set_(self, name, _per_joint(getattr(self, name), name, n,
                                        allow_zero=name in ("torque_error", "model_error", "friction_band")))
        if self.torque_rate is not None:
            set_(self, "torque_rate", _per_joint(self.torque_rate, "torque_rate", n))
        elif self.latency > 0:
            raise ErrorSpecError(f"latency = {self.latency} s needs torque_rate (a bound on |d tau/dt| per joint)")
        if not isinstance(self.sources, dict) or not all(isinstance(v, str) for v in self.sources.values()):
            raise ErrorSpecError(f"sources must map entry names to strings, got {self.sources!r}")
        unknown = set(self.sources) - _KEYS
        if unknown:
            raise ErrorSpecError(f"sources names unknown entries {sorted(unknown)}; expected some of {sorted(_KEYS)}")

    # ------------------------------------------------------------------------------------------ the position error
    def position_error(self, q_meas) -> np.ndarray:
        """(N, n) bound on ``|q_meas - q_true|`` per sample and joint [rad].

        With a resolution: ``res / 2`` ("nearest") or ``res`` ("floor"). With significant digits: half a unit in
        the last written place of each logged value (its own decade: a value rounded up into the next decade
        is written in that decade's places).
        """
        q = np.asarray(q_meas, dtype=float)
        if q.ndim != 2 or q.shape[1] != self.n_joints:
            raise ErrorSpecError(f"q_meas must have shape (N, {self.n_joints}), got {q.shape}")
        if self.position_resolution is not None:
            step = self.position_resolution * (0.5 if self.position_rounding == "nearest" else 1.0)
            return np.broadcast_to(step, q.shape).copy()
        a = np.abs(q)
        exponent = _decade(np.where(a > 0, a, 1.0))
        # an exact zero is written "0": the true value was below half a unit of the smallest place written, which
        # for a fixed number of significant digits is not bounded; take the place of the smallest non-zero value
        # of that joint (a stated, data-driven floor, conservative for a joint that passes through zero)
        nonzero = np.where(a > 0, exponent, np.inf)
        floor_exp = np.min(nonzero, axis=0)
        floor_exp = np.where(np.isfinite(floor_exp), floor_exp, 0.0)
        exponent = np.where(a > 0, exponent, floor_exp[None, :])
        # 10^k correctly rounded (at most half an ulp below 10^k), halved exactly, one ulp up: >= half a unit
        half_ulp = 0.5 * _pow10(exponent - (self.significant_digits - 1))
        return np.nextafter(half_ulp, np.inf)

    # ---------------------------------------------------------------------------------------------- conversions
    def to_dict(self) -> dict:
        """JSON-ready: every entry with its unit in the key's documentation (module docstring) and its source."""
        def arr(x):
            return None if x is None else [float(v) for v in np.atleast_1d(x)]
        return {
            "n_joints": int(self.n_joints), "sample_period": self.sample_period,
            "position_resolution": arr(self.position_resolution), "significant_digits": self.significant_digits,
            "position_rounding": self.position_rounding, "torque_timing": self.torque_timing,
            "latency": self.latency, "torque_rate": arr(self.torque_rate), "torque_error": arr(self.torque_error),
            "qd_max": arr(self.qd_max), "qdd_max": arr(self.qdd_max), "model_error": arr(self.model_error),
            "friction_band": arr(self.friction_band), "sources": dict(self.sources),
        }

    @classmethod
    def from_mapping(cls, table: dict, n_joints: int, where: str = "error_model") -> "ErrorSpec":
        """From the ``[error_model]`` table of a TOML file (or an equal dict); ``where`` names it in errors."""
        if not isinstance(table, dict):
            raise ErrorSpecError(f"{where} must be a table, got {type(table).__name__}")
        unknown = set(table) - _KEYS
        if unknown:
            raise ErrorSpecError(f"{where} has unknown keys {sorted(unknown)}; expected some of {sorted(_KEYS)}")
        kw = dict(table)
        if "counts_per_turn" in kw:
            if "position_resolution" in kw:
                raise ErrorSpecError(f"{where}: give counts_per_turn or position_resolution, not both")
            counts = np.asarray(kw.pop("counts_per_turn"), dtype=float)
            if np.any(~np.isfinite(counts)) or np.any(counts < 1):
                raise ErrorSpecError(f"{where}.counts_per_turn must be >= 1, got {counts.tolist()}")
            kw["position_resolution"] = 2 * np.pi / counts
        missing = [k for k in ("sample_period", "torque_error", "qd_max", "qdd_max") if k not in kw]
        if missing:
            raise ErrorSpecError(f"{where} is missing {missing}")
        try:
            return cls(n_joints=n_joints, **kw)
        except ErrorSpecError as exc:
            raise ErrorSpecError(f"{where}: {exc}") from None

    @classmethod
    def from_toml(cls, path, n_joints: int) -> "ErrorSpec":
        """Read ``[error_model]`` from a TOML file; errors name the file."""
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise ErrorSpecError(f"--spec {path}: cannot read it as TOML ({exc})") from None
        if "error_model" not in data:
            raise ErrorSpecError(f"--spec {path}: no [error_model] table")
        return cls.from_mapping(data["error_model"], n_joints, where=f"{path} [error_model]")
