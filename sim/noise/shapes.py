"""One-shape torque noise (a scenario's ``noise.shape``): :class:`TorqueNoise`, realised by the components.

``TorqueNoise(bound, shape)`` is the single-component model of the scenarios' ``[noise]`` table: ``uniform``,
``square``, ``sine`` draw exactly what :class:`~sim.noise.components.Uniform`, :class:`~sim.noise.components.Square`
and :class:`~sim.noise.components.Sine` of amplitude ``bound`` draw (same generator calls, same values), ``array``
replays given values, ``none`` is zero. Its stream is the precomputed :class:`PrecomputedTorqueError` (the error
does not depend on the state; the logged torque is the command).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from h4bench.sim.noise.components import Sine, Square, Uniform
from h4bench.sim.validation import N_JOINTS, SimulationError

__all__ = ["NOISE_SHAPES", "PrecomputedTorqueError", "TorqueNoise"]

NOISE_SHAPES = ("uniform", "square", "sine", "array", "none")
_COMPONENT_OF_SHAPE = {"uniform": Uniform, "square": Square, "sine": Sine}


@dataclass(frozen=True)
class TorqueNoise:
    """Bounded torque noise ``|e| <= bound`` [N m] added to the commanded torque.

    shape: ``uniform`` (i.i.d. in [-bound, bound]), ``square`` (the worst case: +-bound square wave of
    ``frequency_hz`` with a random phase per joint), ``sine`` (bound sin(2 pi f t + phase)), ``array``
    (user-provided ``values`` (n, 4), checked against the bound) or ``none``. Bad values raise
    :class:`sim.SimulationError`.
    """

    bound: float = 0.0
    shape: str = "uniform"
    frequency_hz: float = 5.0
    values: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.shape not in NOISE_SHAPES:
            raise SimulationError(f"noise shape must be one of {NOISE_SHAPES}, got {self.shape!r}")
        if not (np.isfinite(self.bound) and self.bound >= 0):
            raise SimulationError(f"noise bound must be a finite number >= 0 [N m], got {self.bound!r}")
        if self.shape in ("square", "sine") and not (self.frequency_hz > 0):
            raise SimulationError(f"noise frequency_hz must be > 0, got {self.frequency_hz!r}")
        if self.shape == "array" and self.values is None:
            raise SimulationError("noise shape 'array' needs values of shape (n, 4)")

    def component(self):
        """The equivalent noise component (:class:`Uniform`, :class:`Square` or :class:`Sine` of amplitude
        ``bound``), or None for ``array`` and ``none``."""
        kind = _COMPONENT_OF_SHAPE.get(self.shape)
        if kind is None:
            return None
        return kind(self.bound) if kind is Uniform else kind(self.bound, self.frequency_hz)

    def sample(self, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noise at the sample times.

        Parameters
        ----------
        t : (n,) sample times [s] (from 0)
        rng : numpy.random.Generator

        Returns
        -------
        (n, 4) error [N m], within +-bound.
        """
        n = t.size
        if self.shape == "none" or self.bound == 0.0 and self.shape != "array":
            return np.zeros((n, N_JOINTS))
        comp = self.component()
        if comp is not None:
            return comp.sample(t, rng)
        values = np.asarray(self.values, dtype=float)
        if values.shape != (n, N_JOINTS):
            raise SimulationError(f"noise values must have shape ({n}, {N_JOINTS}) (one per sample and joint), "
                                  f"got {values.shape}")
        if not np.all(np.isfinite(values)) or np.abs(values).max() > self.bound:
            raise SimulationError(f"noise values must be finite and within +-bound = {self.bound} N m, "
                                  f"got max |e| = {np.nanmax(np.abs(values)):.6g}")
        return values.copy()

    def describe(self) -> dict:
        """JSON-able description: bound, shape, frequency_hz (the values are left out)."""
        d = asdict(self)
        d.pop("values")
        return d

    def start(self, t: np.ndarray, rng: np.random.Generator) -> PrecomputedTorqueError:
        """The per-sample error stream for sample times t (n,) [s] (the draws of :meth:`sample`).

        Parameters
        ----------
        t : (n,) sample times [s] (from 0)
        rng : numpy.random.Generator

        Returns
        -------
        PrecomputedTorqueError
        """
        return PrecomputedTorqueError(self.sample(np.asarray(t, dtype=float), rng))


class PrecomputedTorqueError:
    """A torque-error stream from precomputed values e (n, 4) [N m]: ``at(k, q, tau_cmd) = e[k]``; the logged
    torque is the command itself."""

    __slots__ = ("e", "_rows")

    def __init__(self, e: np.ndarray) -> None:
        self.e = np.asarray(e, dtype=float)
        self._rows = None

    def at(self, k: int, q: np.ndarray, tau_cmd: np.ndarray) -> np.ndarray:
        """Error (4,) [N m] at sample k (q, tau_cmd unused)."""
        return self.e[k]

    def at_list(self, k: int, q: list, tau_cmd: list) -> list:
        """:meth:`at` as a list of 4 floats (the simulator's per-sample path; q, tau_cmd unused)."""
        if self._rows is None:
            self._rows = self.e.tolist()
        return self._rows[k]

    def compiled_terms(self) -> dict | None:
        """What the compiled sample loop (:mod:`sim.compiled`) needs to compute :meth:`at_list` itself: the
        precomputed rows, no ripple, no gain error, no finiteness check (None for a subclass with its own
        ``at_list``)."""
        if type(self).at_list is not PrecomputedTorqueError.at_list:
            return None
        return {"pre": self.e, "ripple": np.empty((0, 6)), "gain": np.empty((0, 5)), "check_finite": False}

    def measured(self, tau_cmd: np.ndarray) -> np.ndarray:
        """The logged torques (n, 4) [N m]: a copy of the commands."""
        return np.array(tau_cmd, dtype=float)
