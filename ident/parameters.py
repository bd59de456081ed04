"""The 14 base parameters of the H4 inverse dynamic model (paper eq. 18) and the Box type.

The order is defined here once; every other module refers to :data:`PARAMETER_NAMES`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PARAMETER_NAMES: tuple[str, ...] = (
    "Imot1", "Imot2", "Imot3", "Imot4",  # motor + arm + lumped forearm inertia about the motor axis [kg m^2]
    "Mnac",  # nacelle mass [kg]
    "Ibc",  # nacelle inertia about the vertical axis through D [kg m^2]
    "Fv1", "Fv2", "Fv3", "Fv4",  # viscous friction [N m s/rad]
    "Fs1", "Fs2", "Fs3", "Fs4",  # Coulomb friction [N m]
)
PARAMETER_UNITS: tuple[str, ...] = ("kg m^2",) * 4 + ("kg", "kg m^2") + ("N m s/rad",) * 4 + ("N m",) * 4
N_PARAMETERS = len(PARAMETER_NAMES)

# What a designer knows before identification: the paper's a priori values (Table 1: Imot 0.012 kg m^2,
# Mnac 1.0 kg; Ibc taken as 0.003 kg m^2, Table 2's order, since the a priori 0.0008 ignores the lateral bars)
# and frictions of the order of its Table 2. Used for control, feed-forward and trajectory checks; never
# as a truth.
NOMINAL_PARAMETERS: tuple[float, ...] = (0.012, 0.012, 0.012, 0.012, 1.0, 0.003,
                                         0.16, 0.06, 0.09, 0.09, 1.15, 1.10, 0.72, 0.99)


@dataclass(frozen=True)
class Box:
    """An axis-aligned box of parameter vectors, ``lower <= theta <= upper`` component-wise.

    lower, upper : (p,) float arrays; names : (p,) parameter names.
    ``info`` carries optional diagnostics of the method that produced it (not part of equality).
    """

    lower: np.ndarray
    upper: np.ndarray
    names: tuple[str, ...] = PARAMETER_NAMES
    info: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        lower = np.array(self.lower, dtype=float).reshape(-1)
        upper = np.array(self.upper, dtype=float).reshape(-1)
        if lower.shape != upper.shape:
            raise ValueError(f"Box lower and upper must have the same shape, got {lower.shape} and {upper.shape}")
        names = tuple(self.names)
        if len(names) != lower.size:
            if self.names is PARAMETER_NAMES:
                names = tuple(f"theta{i + 1}" for i in range(lower.size))
            else:
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
        return {"names": list(self.names), "lower": self.lower.tolist(), "upper": self.upper.tolist()}
