"""h4bench trajectories: exciting Fourier trajectories with slow and fast phases, toppra time parameterisation,
sample-by-sample checks against the workspace, singularity margin and speed/acceleration/torque limits, and
bounded-error experiment design (:mod:`trajectories.bounded`, :func:`design_excitation`)."""

from h4bench.trajectories.bounded import design_criterion, halfwidths, predicted_widths, processed_regressor
from h4bench.trajectories.checks import CHECKS, check_trajectory
from h4bench.trajectories.excitation import cache_dir, design_excitation
from h4bench.trajectories.fourier import fourier_excitation, fourier_trajectory
from h4bench.trajectories.limits import NOMINAL_PARAMETERS, InfeasibleTrajectoryError, Limits, nominal_parameters
from h4bench.trajectories.trajectory import Trajectory

__all__ = [
    "CHECKS", "InfeasibleTrajectoryError", "cache_dir", "design_criterion", "design_excitation", "halfwidths",
    "predicted_widths", "processed_regressor", "Limits", "NOMINAL_PARAMETERS", "TOPPRA_VERSION", "Trajectory",
    "check_trajectory", "fourier_excitation", "fourier_trajectory", "nominal_parameters", "slow_down",
    "waypoint_trajectory",
]

_TIMING = ("TOPPRA_VERSION", "slow_down", "waypoint_trajectory")  # in trajectories.timing, which imports toppra


def __getattr__(name: str):
    """The toppra-timed names, imported on first use (:mod:`trajectories.timing` imports toppra, about a second;
    a campaign run that recalls its designed trajectory never needs it)."""
    if name in _TIMING:
        from h4bench.trajectories import timing

        return getattr(timing, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
