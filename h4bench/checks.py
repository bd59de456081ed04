"""Argument checks shared by every layer (``sim`` and ``ident`` alike): numpy only, nothing of the project's own.

Each check raises a ``TypeError`` (wrong kind of value) or ``ValueError`` (wrong value) whose message names the
argument, what was expected and what came, and returns the value converted.
"""

from __future__ import annotations

import numpy as np

__all__ = ["per_joint", "vector"]


def vector(x, name: str, n: int, *, scalar: bool = False) -> np.ndarray:
    """A finite float array of shape (n,); with ``scalar``, one number is accepted and broadcast to n.

    Parameters
    ----------
    x : the value
    name : the argument's name, for the message
    n : the length expected
    scalar : accept one number (broadcast)

    Returns
    -------
    (n,) float ndarray
    """
    what = f"a number or an array of shape ({n},)" if scalar else f"an array of shape ({n},)"
    if isinstance(x, (str, bytes)) or x is None:
        raise TypeError(f"{name} must be {what}, got {type(x).__name__}")
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be {what}, got {type(x).__name__}") from exc
    if scalar and arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{name} must {'be a scalar or ' if scalar else ''}have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr


def per_joint(x, name: str, n: int, *, allow_zero: bool = False) -> np.ndarray:
    """One number (broadcast to the ``n`` joints) or ``n`` of them, finite and > 0 (``>= 0`` with ``allow_zero``):
    a float array (n,)."""
    arr = vector(x, name, n, scalar=True)
    if np.any(arr < 0) if allow_zero else np.any(arr <= 0):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {arr}")
    return arr
