"""The torque-error stream protocol and :class:`ErrorStream`, one realisation of a :class:`~sim.noise.TorqueError`.

Protocol (what :func:`sim.simulate` calls): ``stream = model.start(t, rng)`` with t (n,) sample times from 0 [s]
and rng a ``numpy.random.Generator``; ``stream.at(k, q, tau_cmd) -> (4,)`` the error [N m] the motors add at
sample k (q (4,) true motor angles [rad], tau_cmd (4,) the clipped command [N m]); ``stream.measured(tau_cmd
(n, 4)) -> (n, 4)`` the logged torques; ``model.bound`` [N m] bounds ``|applied - logged|`` and
``model.describe()`` is a JSON-able dict.
"""

from __future__ import annotations

import math

import numpy as np

from h4bench.sim.noise.components import NoiseModelError
from h4bench.sim.validation import N_JOINTS, as_float_array

__all__ = ["ErrorStream"]

# ------------------------------------------------------------------------------------------------- stream


def _array(x, name: str, shape: tuple) -> np.ndarray:
    """A finite float array of the given shape, or a clear error (also the slow path of ``ErrorStream.at``)."""
    arr = as_float_array(x, name)
    if arr.shape != shape:
        rows = " (one row per sample time)" if len(shape) == 2 else ""
        raise NoiseModelError(f"{name} must have shape {shape}{rows}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise NoiseModelError(f"{name} must be finite, got {np.count_nonzero(~np.isfinite(arr))} non-finite entries")
    return arr


def _floats(x, name: str) -> list:
    """A (4,) float array as a list of 4 Python floats (anything else through :func:`_array`'s checks)."""
    try:
        out = x.tolist()
        if len(out) == N_JOINTS and all(isinstance(v, float) for v in out):
            return out
    except (AttributeError, TypeError):
        pass
    return _array(x, name, (N_JOINTS,)).tolist()


class ErrorStream:
    """One realisation of a :class:`TorqueError` over sample times ``t`` (n,) [s] (see :meth:`TorqueError.start`).

    at(k, q, tau_cmd) : (4,) error [N m] added to the commanded torque at sample k; measured(tau_cmd) : (n, 4)
    the logged torque; errors(q, tau_cmd) : (n, 4) all errors at once (vectorised, same values as ``at`` up to
    the last bit of ``sin``). Attributes: t (n,), bound (the model's total bound), state_independent (n, 4) the
    precomputed part, phases, gains (the realised per-joint parameters).
    """

    def __init__(self, t, pre, ripples, gains, quantiser, bound):
        self.t = t
        self.n = t.size
        self.bound = bound
        self.state_independent = pre
        pre.setflags(write=False)
        self._pre_rows = None  # the rows as lists of floats, made on first use (the compiled loop reads the array)
        # flattened for plain-float math: (order, amplitude, phase_0..3) per harmonic, (g_0..3, limit) per gain
        self.phases = [ph for _, ph in ripples]
        self.gains = [g for g, _ in gains]
        self._ripple = tuple((float(n), float(a), *map(float, ph[h])) for r, ph in ripples
                             for h, (n, a) in enumerate(zip(r.orders, r.amplitudes)))
        self._gain = tuple((*map(float, g), float(c.torque_limit)) for g, c in gains)
        self._ripple_components = [r for r, _ in ripples]
        self._gain_components = [c for _, c in gains]
        self._quantiser = quantiser
        self._fixed = not (self._ripple or self._gain)

    @property
    def _pre(self) -> list:
        if self._pre_rows is None:
            self._pre_rows = self.state_independent.tolist()
        return self._pre_rows

    def at(self, k: int, q, tau_cmd) -> np.ndarray:
        """Error (4,) [N m] at sample k: the motors apply ``tau_cmd + at(k, q, tau_cmd)``.

        k : sample index in [0, n); q : (4,) true motor angles [rad]; tau_cmd : (4,) commanded torque after
        clipping [N m] (|tau_cmd| <= torque_limit when a gain error is present). Returns a new array, or a
        read-only row of :attr:`state_independent` when no component depends on q or tau_cmd.
        """
        try:
            if k < 0:
                raise IndexError
            if self._fixed:  # nothing depends on the state: the precomputed row (a read-only view)
                return self.state_independent[k]
            self._pre[k]
        except (IndexError, TypeError):
            raise NoiseModelError(f"k must be an integer sample index in [0, {self.n}), got {k!r}") from None
        ql = _floats(q, "q") if self._ripple else None
        tl = _floats(tau_cmd, "tau_cmd") if self._gain else None
        return np.array(self.at_list(k, ql, tl))

    def at_list(self, k: int, q: list, tau_cmd: list) -> tuple:
        """:meth:`at` on Python floats, without its argument checks (the simulator's per-sample path): k a valid
        sample index, q and tau_cmd lists of 4 floats [rad, N m]. Returns the 4 errors [N m] (the same values:
        the same operations in the same order); raises NoiseModelError for a non-finite error or a command
        beyond a gain error's torque limit."""
        e0, e1, e2, e3 = self._pre[k]
        if self._ripple:
            q0, q1, q2, q3 = q
            sin = math.sin
            try:
                for n, a, p0, p1, p2, p3 in self._ripple:
                    e0 += a * sin(n * q0 + p0)
                    e1 += a * sin(n * q1 + p1)
                    e2 += a * sin(n * q2 + p2)
                    e3 += a * sin(n * q3 + p3)
            except ValueError:  # math.sin(inf)
                _array(q, "q", (N_JOINTS,))
                raise
        if self._gain:
            t0, t1, t2, t3 = tau_cmd
            for g0, g1, g2, g3, lim in self._gain:
                if not (-lim <= t0 <= lim and -lim <= t1 <= lim and -lim <= t2 <= lim and -lim <= t3 <= lim):
                    raise NoiseModelError(f"tau_cmd must be finite and within +-torque_limit = {lim} N m (the "
                                          f"gain error's bound assumes it), got {[t0, t1, t2, t3]}")
                e0 += g0 * t0
                e1 += g1 * t1
                e2 += g2 * t2
                e3 += g3 * t3
        s = e0 + e1 + e2 + e3
        if s - s != 0.0:
            raise NoiseModelError(f"q must be finite (the error at sample {k} is not), got {q!r}")
        return e0, e1, e2, e3

    def compiled_terms(self) -> dict | None:
        """What the compiled sample loop (:mod:`sim.compiled`) needs to compute :meth:`at_list` itself, in its
        order: the precomputed rows (n, 4), the ripple harmonics (order, amplitude, phase_0..3) (h, 6), the gain
        errors (g_0..3, torque limit) (g, 5), and the finiteness check of the sum. None for a subclass with its
        own ``at_list``."""
        if type(self).at_list is not ErrorStream.at_list:
            return None
        return {"pre": self.state_independent, "ripple": np.array(self._ripple, dtype=float).reshape(-1, 6),
                "gain": np.array(self._gain, dtype=float).reshape(-1, 5), "check_finite": True}

    def measured(self, tau_cmd) -> np.ndarray:
        """The torque the robot logs (n, 4) [N m] given all commanded torques tau_cmd (n, 4): the command
        itself, or its quantisation ``round(tau_cmd / lsb) lsb``."""
        tau = _array(tau_cmd, "tau_cmd", (self.n, N_JOINTS))
        return tau.copy() if self._quantiser is None else self._quantiser.logged(tau)

    def errors(self, q, tau_cmd) -> np.ndarray:
        """All errors (n, 4) [N m] given the motor angles q (n, 4) [rad] and commands tau_cmd (n, 4) [N m]
        (vectorised :meth:`at`, same summation order)."""
        q = _array(q, "q", (self.n, N_JOINTS))
        tau = _array(tau_cmd, "tau_cmd", (self.n, N_JOINTS))
        e = self.state_independent.copy()
        for r, ph in zip(self._ripple_components, self.phases):
            for h, (n, a) in enumerate(zip(r.orders, r.amplitudes)):
                e += a * np.clip(np.sin(n * q + ph[h]), -1.0, 1.0)
        for g, c in zip(self.gains, self._gain_components):
            if np.abs(tau).max(initial=0.0) > c.torque_limit:
                raise NoiseModelError(f"tau_cmd must lie within +-torque_limit = {c.torque_limit} N m, "
                                      f"got max |tau| = {np.abs(tau).max()}")
            e += g * tau
        return e
