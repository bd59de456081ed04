"""The torque-error components, each with its rigorous bound [N m] (the table of :mod:`sim.noise`).

Each component has ``bound`` (float [N m]), ``describe() -> dict`` (JSON-able) and either ``sample(t, rng) ->
(n, 4)`` (state-independent: realised once over the sample times) or the realised per-joint parameters the
stream evaluates per sample (:class:`Ripple` phases, :class:`GainError` gains); :class:`LogQuantisation` acts on
the log, not on the applied torque.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import ClassVar

import numpy as np

from h4bench.portable import exp
from h4bench.sim.validation import N_JOINTS

__all__ = [
    "DRIFT_KINDS",
    "Drift",
    "GAIN_MODES",
    "GainError",
    "LogQuantisation",
    "NoiseModelError",
    "Ripple",
    "Samples",
    "Sine",
    "Square",
    "TORQUE_LIMIT",
    "Uniform",
]

TORQUE_LIMIT = 15.0  # N m: the H4's actuator range (paper sec. 4.2; models/h4.xml ctrlrange)


class NoiseModelError(ValueError):
    """Bad torque-error model input (spec, amplitudes, sample times, torques)."""


# ---------------------------------------------------------------------------------------------- validation


def _real(x, name: str, *, positive: bool = False) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(x).__name__}")
    x = float(x)
    if not math.isfinite(x) or x < 0 or (positive and x == 0):
        raise NoiseModelError(f"{name} must be a finite number {'>' if positive else '>='} 0, got {x!r}")
    return x


def _plain(v):
    return float(v) if isinstance(v, (float, np.floating)) else v


def _round_up_sum(a: float, b: float) -> float:
    """a + b rounded toward +inf (TwoSum error term; Knuth, TAOCP vol. 2, 4.2.2)."""
    s = a + b
    bb = s - a
    err = (a - (s - bb)) + (b - bb)
    return math.nextafter(s, math.inf) if err > 0 else s


# ---------------------------------------------------------------------------------------------- components


@dataclass(frozen=True)
class _Amplitude:
    """A component whose bound is its amplitude [N m]."""

    amplitude: float
    KIND: ClassVar[str] = ""

    def __post_init__(self):
        object.__setattr__(self, "amplitude", _real(self.amplitude, f"{self.KIND} amplitude"))
        if hasattr(self, "frequency_hz"):
            object.__setattr__(self, "frequency_hz", _real(self.frequency_hz, f"{self.KIND} frequency_hz",
                                                           positive=True))

    @property
    def bound(self) -> float:
        return float(self.amplitude)

    def describe(self) -> dict:
        return {"kind": self.KIND, **{k: _plain(v) for k, v in asdict(self).items()}, "bound": self.bound}

    def _arg(self, t, rng):  # 2 pi f t + phi_i, a random phase per joint
        return 2 * np.pi * self.frequency_hz * t[:, None] + rng.uniform(0.0, 2 * np.pi, N_JOINTS)


@dataclass(frozen=True)
class Uniform(_Amplitude):
    """White noise, i.i.d. uniform in [-amplitude, amplitude] [N m] per sample and joint."""

    KIND: ClassVar[str] = "uniform"

    def sample(self, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        a = float(self.amplitude)
        return np.clip(rng.uniform(-a, a, (t.size, N_JOINTS)), -a, a)


@dataclass(frozen=True)
class Square(_Amplitude):
    """amplitude sign(sin(2 pi frequency_hz t + phi_i)), random phase per joint: sits on the bound."""

    frequency_hz: float = 5.0
    KIND: ClassVar[str] = "square"

    def sample(self, t, rng):
        return float(self.amplitude) * np.where(np.sin(self._arg(t, rng)) >= 0.0, 1.0, -1.0)


@dataclass(frozen=True)
class Sine(_Amplitude):
    """amplitude sin(2 pi frequency_hz t + phi_i), random phase per joint."""

    frequency_hz: float = 5.0
    KIND: ClassVar[str] = "sine"

    def sample(self, t, rng):
        return float(self.amplitude) * np.clip(np.sin(self._arg(t, rng)), -1.0, 1.0)


class Samples:
    """Given error values (n, 4) [N m]; bound = ``bound`` if given (values checked against it) else max |values|."""

    def __init__(self, values, bound: float | None = None):
        v = np.array(values, dtype=float)
        if v.ndim != 2 or v.shape[1] != N_JOINTS:
            raise NoiseModelError(f"samples values must have shape (n, 4), got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise NoiseModelError("samples values must be finite")
        peak = float(np.abs(v).max()) if v.size else 0.0
        self._bound = peak if bound is None else _real(bound, "samples bound")
        if peak > self._bound:
            raise NoiseModelError(f"samples values must lie within +-bound = {self._bound} N m, got max |e| = {peak}")
        v.setflags(write=False)
        self.values = v

    @property
    def bound(self) -> float:
        return self._bound

    def sample(self, t, rng):
        if self.values.shape[0] != t.size:
            raise NoiseModelError(f"samples values must have shape ({t.size}, 4) (one per sample time), "
                                  f"got {self.values.shape}")
        return self.values.copy()

    def describe(self) -> dict:
        return {"kind": "samples", "shape": list(self.values.shape), "bound": self.bound}


DRIFT_KINDS = ("band", "thermal")


@dataclass(frozen=True)
class Drift(_Amplitude):
    """Slow bounded drift [N m] (amplifier and current-sensor offset drift, thermal effects).

    kind ``band``: per joint a sum of ``terms`` sinusoids with frequencies uniform in (0, cutoff_hz], random
    phases and Gaussian weights (a band-limited Gaussian-like random signal), scaled so that its peak over the
    record is exactly ``amplitude`` (so the bound is attained on every joint). kind ``thermal``: per joint
    ``s_i amplitude (1 - (1 - c_i) exp(-t / time_constant))`` with a random sign s_i and a random initial
    fraction c_i in [0, 1] (a warm-up offset). Both stay within +-amplitude by construction.
    """

    kind: str = "band"
    cutoff_hz: float = 0.2
    time_constant: float = 30.0
    terms: int = 32
    KIND: ClassVar[str] = "drift"

    def __post_init__(self):
        super().__post_init__()
        if self.kind not in DRIFT_KINDS:
            raise NoiseModelError(f"drift kind must be one of {DRIFT_KINDS}, got {self.kind!r}")
        _real(self.cutoff_hz, "drift cutoff_hz", positive=True)
        _real(self.time_constant, "drift time_constant", positive=True)
        if isinstance(self.terms, bool) or not isinstance(self.terms, (int, np.integer)) or self.terms < 1:
            raise NoiseModelError(f"drift terms must be an integer >= 1, got {self.terms!r}")

    def sample(self, t, rng):
        a = float(self.amplitude)
        if self.kind == "thermal":
            sign = rng.choice([-1.0, 1.0], N_JOINTS)
            c0 = rng.uniform(0.0, 1.0, N_JOINTS)
            x = sign * (1.0 - (1.0 - c0) * exp(-t[:, None] / self.time_constant))
            return np.clip(a * x, -a, a)
        m = int(self.terms)
        freq = rng.uniform(0.0, self.cutoff_hz, (m, N_JOINTS))
        freq = self.cutoff_hz - freq  # in (0, cutoff_hz]
        phase = rng.uniform(0.0, 2 * np.pi, (m, N_JOINTS))
        weight = rng.standard_normal((m, N_JOINTS))
        x = np.zeros((t.size, N_JOINTS))
        for j in range(m):  # loop over terms, vectorised over samples
            x += weight[j] * np.sin(2 * np.pi * freq[j] * t[:, None] + phase[j])
        peak = np.abs(x).max(axis=0) if t.size else np.ones(N_JOINTS)
        peak[peak == 0.0] = 1.0
        return np.clip(a * (x / peak), -a, a)

    def describe(self) -> dict:
        d = super().describe()
        d["drift_kind"] = d.pop("kind")
        return {"kind": self.KIND, **d}


class Ripple:
    """Position-periodic torque ripple / cogging: ``sum_h a_h sin(n_h q_i + phi_hi)`` [N m].

    orders : (H,) positive integers n_h, periods per motor revolution (the H4's motors are direct drive, so q
    is the motor angle: cogging at LCM(slots, poles), the commutation harmonics at 6 x pole pairs, a once-per-
    revolution term from eccentricity or magnet imbalance); amplitudes : (H,) a_h >= 0 [N m]. Phases
    phi_hi are drawn uniformly per harmonic and joint. Bound: sum_h a_h (attained where the phases align).
    """

    def __init__(self, orders, amplitudes):
        try:
            o = [int(n) for n in orders]
        except TypeError as exc:
            raise TypeError(f"ripple orders must be a list of integers, got {type(orders).__name__}") from exc
        if any(isinstance(n, bool) or not isinstance(n, (int, np.integer)) for n in orders):
            raise TypeError(f"ripple orders must be integers, got {list(orders)!r}")
        if not o or any(n < 1 for n in o):
            raise NoiseModelError(f"ripple orders must be a non-empty list of integers >= 1, got {o}")
        a = [_real(x, f"ripple amplitudes[{i}]") for i, x in enumerate(amplitudes)]
        if len(a) != len(o):
            raise NoiseModelError(f"ripple amplitudes must have one value per order ({len(o)}), got {len(a)}")
        self.orders, self.amplitudes = tuple(o), tuple(a)

    @classmethod
    def split(cls, amplitude: float, orders) -> Ripple:
        """Total ``amplitude`` split equally over ``orders``."""
        amplitude = _real(amplitude, "ripple amplitude")
        return cls(orders, [amplitude / len(orders)] * len(orders)) if len(orders) else cls(orders, [])

    @property
    def bound(self) -> float:
        b = 0.0
        for a in self.amplitudes:
            b += a
        return b

    def phases(self, rng) -> np.ndarray:
        return rng.uniform(0.0, 2 * np.pi, (len(self.orders), N_JOINTS))

    def describe(self) -> dict:
        return {"kind": "ripple", "orders": list(self.orders), "amplitudes": list(self.amplitudes),
                "bound": self.bound}


GAIN_MODES = ("worst", "random")


@dataclass(frozen=True)
class GainError:
    """Torque-constant (current-gain) error ``g_i tau_cmd_i`` [N m], ``|g_i| <= max_gain``.

    mode ``worst``: g_i = +-max_gain with random signs; ``random``: g_i uniform in [-max_gain, max_gain].
    Bound: max_gain torque_limit; :meth:`ErrorStream.at` raises if ``|tau_cmd| > torque_limit``.
    """

    max_gain: float
    mode: str = "worst"
    torque_limit: float = TORQUE_LIMIT

    def __post_init__(self):
        object.__setattr__(self, "max_gain", _real(self.max_gain, "gain max_gain"))
        if self.mode not in GAIN_MODES:
            raise NoiseModelError(f"gain mode must be one of {GAIN_MODES}, got {self.mode!r}")
        object.__setattr__(self, "torque_limit", _real(self.torque_limit, "gain torque_limit", positive=True))

    @property
    def bound(self) -> float:
        return float(self.max_gain) * float(self.torque_limit)

    def gains(self, rng) -> np.ndarray:
        g = float(self.max_gain)
        if self.mode == "worst":
            return g * rng.choice([-1.0, 1.0], N_JOINTS)
        return np.clip(rng.uniform(-g, g, N_JOINTS), -g, g)

    def describe(self) -> dict:
        return {"kind": "gain", **{k: _plain(v) for k, v in asdict(self).items()}, "bound": self.bound}


@dataclass(frozen=True)
class LogQuantisation:
    """The logged torque is the command on a grid: ``round(tau_cmd / lsb) lsb`` [N m].

    Bound on ``|tau_cmd - logged|``: lsb/2, exact in floating point when lsb is a power of two <= 1 (scaling by
    it is exact); otherwise lsb/2 + 2^-52 (1.01 torque_limit + lsb) covers the two roundings (|tau_cmd| <=
    torque_limit is checked).
    """

    lsb: float
    torque_limit: float = TORQUE_LIMIT

    def __post_init__(self):
        object.__setattr__(self, "lsb", _real(self.lsb, "quantisation_lsb", positive=True))
        object.__setattr__(self, "torque_limit", _real(self.torque_limit, "quantisation torque_limit", positive=True))

    @property
    def exact(self) -> bool:
        return math.frexp(self.lsb)[0] == 0.5 and self.lsb <= 1.0

    @property
    def bound(self) -> float:
        half = 0.5 * float(self.lsb)
        if self.exact:
            return half
        return _round_up_sum(half, 2.0**-51 * (1.01 * self.torque_limit + self.lsb))

    def logged(self, tau: np.ndarray) -> np.ndarray:
        if not self.exact and np.abs(tau).max(initial=0.0) > self.torque_limit:
            raise NoiseModelError(f"tau_cmd must lie within +-torque_limit = {self.torque_limit} N m for the "
                                  f"quantiser's bound, got max |tau| = {np.abs(tau).max()}")
        return np.round(tau / self.lsb) * self.lsb

    def describe(self) -> dict:
        return {"kind": "quantisation", **{k: _plain(v) for k, v in asdict(self).items()}, "bound": self.bound}


_PRECOMPUTED = (Uniform, Square, Sine, Samples, Drift)
_COMPONENTS = _PRECOMPUTED + (Ripple, GainError, LogQuantisation)
