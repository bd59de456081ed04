"""The Box type: an axis-aligned box of parameter vectors."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Box", "default_names"]


def default_names(p: int) -> tuple[str, ...]:
    """``theta1 .. thetap``: the names of a box or estimate whose parameters were not named (a robot's names come
    from its model, e.g. :data:`ident.robots.h4.PARAMETER_NAMES`, carried by the prior)."""
    return tuple(f"theta{i + 1}" for i in range(p))


@dataclass(frozen=True)
class Box:
    """An axis-aligned box of parameter vectors, ``lower <= theta <= upper`` component-wise.

    lower, upper : (p,) float arrays; names : (p,) parameter names (default :func:`default_names`:
    ``theta1 .. thetap``).
    ``info`` carries optional diagnostics of the method that produced it (not part of equality).
    """

    lower: np.ndarray
    upper: np.ndarray
    names: tuple[str, ...] | None = None
    info: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        lower = np.array(self.lower, dtype=float).reshape(-1)
        upper = np.array(self.upper, dtype=float).reshape(-1)
        if lower.shape != upper.shape:
            raise ValueError(f"Box lower and upper must have the same shape, got {lower.shape} and {upper.shape}")
        names = default_names(lower.size) if self.names is None else tuple(self.names)
        if len(names) != lower.size:
            raise ValueError(f"Box names must have {lower.size} entries, got {len(names)}")
        if np.any(np.isnan(lower)) or np.any(np.isnan(upper)):
            raise ValueError("Box bounds must not be NaN")
        if np.any(lower > upper):
            bad = [names[i] for i in np.flatnonzero(lower > upper)]
            raise ValueError(f"Box lower must be <= upper, violated for {bad}")
        lower.setflags(write=False)
        upper.setflags(write=False)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "names", names)

    @property
    def width(self) -> np.ndarray:
        return self.upper - self.lower

    @property
    def mid(self) -> np.ndarray:
        return 0.5 * (self.lower + self.upper)

    def __len__(self) -> int:
        return self.lower.size

    def contains(self, theta) -> np.ndarray:
        """Per-component membership ``lower <= theta <= upper`` as a bool array (use ``.all()``)."""
        theta = np.asarray(theta, dtype=float).reshape(-1)
        if theta.shape != self.lower.shape:
            raise ValueError(f"theta must have shape {self.lower.shape}, got {theta.shape}")
        return (self.lower <= theta) & (theta <= self.upper)

    def to_dict(self) -> dict:
        """JSON-ready: ``{"names", "lower", "upper"}`` (lists; bounds in the parameters' units)."""
        return {"names": list(self.names), "lower": self.lower.tolist(), "upper": self.upper.tolist()}
