"""Argument validation shared by every package (sim imports nothing of ours, so ident, trajectories and scenarios
can all use it without breaking the one-way imports).

Each check raises a ``TypeError`` (wrong kind of value) or ``ValueError`` (wrong value) whose message names the
argument, what was expected and what came, e.g. ``"q must have shape (n, 4), got (3,)"``; each returns the
value converted (float, int or a float array).
"""

from __future__ import annotations

import math

import numpy as np

from h4bench.checks import per_joint, vector  # the checks every layer shares (numpy only)

N_JOINTS = 4  # the H4's four actuated joints: the one definition in sim (the other modules import it)

__all__ = ["N_JOINTS", "SimulationError", "as_float_array", "axis_array", "check_finite", "joint_array",
           "joint_vector", "positive", "positive_int", "real"]


class SimulationError(ValueError):
    """Bad simulation input (reference, noise, settings); re-exported by :mod:`sim.simulate` and :mod:`sim`."""


def as_float_array(x, name: str) -> np.ndarray:
    """``x`` as a float array; TypeError for strings, None and non-numeric values.

    Parameters
    ----------
    x : the value
    name : the argument's name, for the message

    Returns
    -------
    float ndarray
    """
    if isinstance(x, (str, bytes)) or x is None:
        raise TypeError(f"{name} must be an array of numbers, got {type(x).__name__}")
    try:
        return np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array of numbers, got {type(x).__name__}") from exc


def check_finite(arr: np.ndarray, name: str) -> None:
    """ValueError naming how many entries of ``arr`` are NaN or infinite.

    Parameters
    ----------
    arr : float array
    name : the argument's name, for the message

    Returns
    -------
    None
    """
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {np.count_nonzero(~np.isfinite(arr))} non-finite entries")


def real(x, name: str) -> float:
    """A finite real number (bool refused).

    Parameters
    ----------
    x : the value
    name : the argument's name, for the message

    Returns
    -------
    float
    """
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(x).__name__}")
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


def positive(x, name: str) -> float:
    """A finite real number > 0.

    Parameters
    ----------
    x : the value
    name : the argument's name, for the message

    Returns
    -------
    float
    """
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(x).__name__}")
    x = float(x)
    if not (math.isfinite(x) and x > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {x}")
    return x


def positive_int(x, name: str, minimum: int = 1) -> int:
    """An integer >= ``minimum`` (bool refused).

    Parameters
    ----------
    x : the value
    name : the argument's name, for the message
    minimum : the smallest allowed value

    Returns
    -------
    int
    """
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(x).__name__}")
    if x < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {x}")
    return int(x)


def joint_array(x, name: str = "q") -> np.ndarray:
    """A finite float array of shape (n, 4): one row per sample, one column per joint.

    Parameters
    ----------
    x : the value
    name : the argument's name, for the message

    Returns
    -------
    (n, 4) float ndarray
    """
    arr = as_float_array(x, name)
    if arr.ndim != 2 or arr.shape[1] != N_JOINTS:
        raise ValueError(f"{name} must have shape (n, {N_JOINTS}), got {arr.shape}")
    check_finite(arr, name)
    return arr


def joint_vector(x, name: str) -> np.ndarray:
    """A finite float array of shape (4,) (:func:`h4bench.checks.vector` with n = 4)."""
    return vector(x, name, N_JOINTS)


def axis_array(x, name: str, *, allow_zero: bool) -> np.ndarray:
    """A scalar (broadcast) or (4,) array, finite and > 0 (``>= 0`` with ``allow_zero``): the H4's four axes
    (:func:`h4bench.checks.per_joint` with n = 4)."""
    return per_joint(x, name, N_JOINTS, allow_zero=allow_zero)

