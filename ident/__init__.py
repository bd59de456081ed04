"""Identification: interval arithmetic, the H4 regressor, data processing and estimators.

The layers: :mod:`ident.numerics` (interval arithmetic, HiGHS), :mod:`ident.estimators` (any ``(W, y, bound,
prior)``), :mod:`ident.processing` (filters, the paper's chain), :mod:`ident.robots` (the H4, URDF serial robots,
the TX40 log); :mod:`ident.box` and :mod:`ident.errors` are shared by all. ``import ident`` loads the estimators
only; the robot-side names below (the H4 regressor and its parameters, the serial robots) and the uncertain-
regressor hull (it uses the processing chain) are imported on first use (PEP 562), so that the package loads
neither mujoco, python-control, matplotlib, pinocchio nor rerun.
"""

from importlib import import_module

from h4bench.ident.box import Box
from h4bench.ident.errors import (EstimatorError, InconsistentDataError, LPError, LPFallbackWarning, OutlierBudgetError,
                          ProcessingError, UnidentifiableError)
from h4bench.ident.estimators.estimate import estimate, min_consistent_bound
from h4bench.ident.estimators.online import OnlineHull
from h4bench.ident.estimators.outliers import OutlierRows, detect_outliers, relaxed_hull
from h4bench.ident.estimators.wls import WLSResult, wls

_LAZY = {
    "h4bench.ident.robots.h4": ("EXTRA_NAMES", "N_PARAMETERS", "NOMINAL_PARAMETERS", "PARAMETER_NAMES", "PARAMETER_UNITS",
                        "inverse_dynamics", "parameter_names", "parameter_units", "regressor"),
    "h4bench.ident.robots.serial": ("BaseParameters", "SerialRobot", "base_parameters"),
    # the H4 interval regressor (built with the processing chain) and the generic Oettli-Prager hull
    "h4bench.ident.robots.h4_interval": ("Distortion", "IntervalEquation", "interval_equation", "interval_regressor"),
    "h4bench.ident.estimators.uncertain": ("uncertain_hull",),
}
_LAZY_NAME = {name: module for module, names in _LAZY.items() for name in names}

__all__ = ["Box", "EstimatorError", "InconsistentDataError", "LPError", "LPFallbackWarning", "OnlineHull",
           "OutlierBudgetError", "OutlierRows", "ProcessingError", "UnidentifiableError", "WLSResult",
           "detect_outliers", "estimate", "min_consistent_bound", "relaxed_hull", "wls", *sorted(_LAZY_NAME)]


def __getattr__(name: str):
    module = _LAZY_NAME.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY_NAME))
