"""h4bench simulation: the H4 in MuJoCo, its geometry and kinematics, ground truth."""

from sim.kinematics import (
    Jacobians,
    KinematicsError,
    cartesian_motion,
    forward_kinematics,
    inverse_kinematics,
    jacobian_dot,
    jacobians,
    singularity_measure,
)
from sim.model import DEFAULT_MODEL_PATH, H4Geometry, ModelError, apply_solver_constants, load_model
from sim.truth import TRUE_PARAMETER_ORDER, nacelle_mass_matrix, true_parameters

__all__ = [
    "DEFAULT_MODEL_PATH", "H4Geometry", "Jacobians", "KinematicsError", "ModelError", "TRUE_PARAMETER_ORDER",
    "apply_solver_constants",
    "cartesian_motion", "forward_kinematics", "inverse_kinematics", "jacobian_dot", "jacobians", "load_model",
    "nacelle_mass_matrix", "singularity_measure", "true_parameters",
]
from sim.controller import ControllerDesign, JointController, VelocityFilter, design_joint_controller  # noqa: E402
from sim.dataset import Dataset, DatasetError, GroundTruth, atomic_write_bytes  # noqa: E402
from sim.simulate import (  # noqa: E402
    NOISE_SHAPES,
    PrecomputedTorqueError,
    SimulationError,
    SimulationSettings,
    TorqueNoise,
    axis_inertia,
    default_controller,
    quantise,
    simulate,
)

__all__ += [
    "ControllerDesign", "Dataset", "DatasetError", "GroundTruth", "JointController", "NOISE_SHAPES",
    "PrecomputedTorqueError",
    "SimulationError", "SimulationSettings", "TorqueNoise", "VelocityFilter", "atomic_write_bytes", "axis_inertia",
    "default_controller", "design_joint_controller", "quantise", "simulate",
]
from sim.variants import broken_hypotheses_model, randomised_model, unbalanced_arms_model  # noqa: E402

__all__ += ["broken_hypotheses_model", "randomised_model", "unbalanced_arms_model"]
from sim.noise import ErrorStream, NoiseModelError, TorqueError, realistic_drive  # noqa: E402

__all__ += ["ErrorStream", "NoiseModelError", "TorqueError", "realistic_drive"]
