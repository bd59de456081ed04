"""Argument checks of :mod:`ident` (the same messages as :mod:`sim.validation`, which the simulator keeps for
itself: ``ident.processing`` and the estimators must not load the simulator to check an array).

Each check raises a ``TypeError`` (wrong kind of value) or ``ValueError`` (wrong value) whose message names the
argument, what was expected and what came, e.g. ``"q must have shape (n, 4), got (3,)"``; each returns the
value converted (float, int or a float array).
"""

from __future__ import annotations

import math

import numpy as np

from h4bench.checks import per_joint  # the n-joint check every layer shares

__all__ = ["as_float_array", "check_finite", "per_joint", "positive", "positive_int"]


def as_float_array(x, name: str) -> np.ndarray:
    """``x`` as a float array; TypeError for strings, None and non-numeric values."""
    if isinstance(x, (str, bytes)) or x is None:
        raise TypeError(f"{name} must be an array of numbers, got {type(x).__name__}")
    try:
        return np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array of numbers, got {type(x).__name__}") from exc


def check_finite(arr: np.ndarray, name: str) -> None:
    """ValueError naming how many entries of ``arr`` are NaN or infinite."""
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {np.count_nonzero(~np.isfinite(arr))} non-finite entries")


def positive(x, name: str, *, allow_zero: bool = False) -> float:
    """A finite real number > 0 (``>= 0`` with ``allow_zero``)."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(x).__name__}")
    x = float(x)
    if not (math.isfinite(x) and (x >= 0 if allow_zero else x > 0)):
        raise ValueError(f"{name} must be a finite number {'>= 0' if allow_zero else '> 0'}, got {x}")
    return x


def positive_int(x, name: str, minimum: int = 1) -> int:
    """An integer >= ``minimum`` (bool refused)."""
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(x).__name__}")
    if x < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {x}")
    return int(x)

