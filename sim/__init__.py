"""h4bench simulation: the H4 in MuJoCo, its geometry and kinematics, ground truth.

The public names below are resolved on first use (PEP 562 module ``__getattr__``): ``import sim`` loads no
sub-module, ``import sim.validation`` or ``import sim.noise`` loads only what that module needs, and
python-control (with the matplotlib it imports) is loaded only when a controller is designed.
"""

from __future__ import annotations

import importlib
import sys
import types

_LAZY = {
    "h4bench.sim.kinematics": ("Jacobians", "KinematicsError", "cartesian_motion", "forward_kinematics", "inverse_kinematics",
                       "jacobian_dot", "jacobians", "singularity_measure"),
    "h4bench.sim.model": ("DEFAULT_MODEL_PATH", "H4Geometry", "ModelError", "apply_solver_constants", "load_model"),
    "h4bench.sim.truth": ("TRUE_PARAMETER_ORDER", "nacelle_mass_matrix", "true_parameters"),
    "h4bench.sim.controller": ("JointController", "VelocityFilter"),
    "h4bench.sim.control_design": ("ControllerDesign", "design_joint_controller"),
    "h4bench.sim.dataset": ("Dataset", "DatasetError", "GroundTruth", "atomic_write_bytes"),
    "h4bench.sim.simulate": ("SimulationSettings", "axis_inertia", "default_controller", "quantise", "simulate"),
    "h4bench.sim.validation": ("N_JOINTS", "SimulationError"),
    "h4bench.sim.noise": ("ErrorStream", "NOISE_SHAPES", "NoiseModelError", "PrecomputedTorqueError", "TorqueError",
                  "TorqueNoise", "realistic_drive"),
    "h4bench.sim.variants": ("broken_hypotheses_model", "randomised_model", "unbalanced_arms_model"),
}
_MODULE_OF = {name: module for module, names in _LAZY.items() for name in names}

_SUBMODULES = ("control_design", "controller", "csvlog", "dataset", "kinematics", "model", "noise", "truth",
               "validation", "variants")

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str):
    if name in _SUBMODULES:  # ``import sim; sim.kinematics.f(...)`` keeps working
        return importlib.import_module(f"{__name__}.{name}")
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _SimModule(types.ModuleType):
    """``sim.simulate`` is the function :func:`sim.simulate.simulate` (as when this package imported it eagerly),
    also after the import system binds the sub-module of the same name to the package."""

    def __setattr__(self, name, value):
        if name == "simulate" and isinstance(value, types.ModuleType):
            value = value.simulate
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _SimModule
