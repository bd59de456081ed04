"""h4bench trajectories: exciting Fourier trajectories with slow and fast phases, toppra time parameterisation,
and sample-by-sample checks against the workspace, singularity margin and speed/acceleration/torque limits."""

from trajectories.checks import CHECKS, check_trajectory
from trajectories.fourier import fourier_excitation, fourier_trajectory
from trajectories.limits import NOMINAL_PARAMETERS, InfeasibleTrajectoryError, Limits, nominal_parameters
from trajectories.timing import TOPPRA_VERSION, slow_down, waypoint_trajectory
from trajectories.trajectory import Trajectory

__all__ = [
    "CHECKS", "InfeasibleTrajectoryError", "Limits", "NOMINAL_PARAMETERS", "TOPPRA_VERSION", "Trajectory",
    "check_trajectory", "fourier_excitation", "fourier_trajectory", "nominal_parameters", "slow_down",
    "waypoint_trajectory",
]
