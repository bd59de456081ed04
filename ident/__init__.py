"""Identification: interval arithmetic, the H4 regressor, data processing and estimators."""

from ident.box import Box
from ident.robots.h4 import N_PARAMETERS, NOMINAL_PARAMETERS, PARAMETER_NAMES, PARAMETER_UNITS

__all__ = ["Box", "N_PARAMETERS", "NOMINAL_PARAMETERS", "PARAMETER_NAMES", "PARAMETER_UNITS"]
from ident.robots.h4 import EXTRA_NAMES, inverse_dynamics, parameter_names, parameter_units, regressor  # noqa: E402

__all__ += ["EXTRA_NAMES", "inverse_dynamics", "parameter_names", "parameter_units", "regressor"]
from ident.errors import InconsistentDataError, UnidentifiableError  # noqa: E402
from ident.estimators.estimate import estimate, min_consistent_bound  # noqa: E402
from ident.estimators.wls import WLSResult, wls  # noqa: E402

__all__ += ["InconsistentDataError", "UnidentifiableError", "WLSResult", "estimate", "min_consistent_bound", "wls"]
from ident.errors import OutlierBudgetError  # noqa: E402
from ident.estimators.online import OnlineHull  # noqa: E402
from ident.estimators.outliers import OutlierRows, detect_outliers, relaxed_hull  # noqa: E402
from ident.estimators.uncertain import uncertain_hull  # noqa: E402
from ident.robots.h4_interval import Distortion, IntervalEquation, interval_equation, interval_regressor  # noqa: E402

__all__ += ["Distortion", "IntervalEquation", "OnlineHull", "OutlierBudgetError", "OutlierRows", "detect_outliers",
            "interval_equation", "interval_regressor", "relaxed_hull", "uncertain_hull"]
from ident.errors import LPError, LPFallbackWarning, ProcessingError  # noqa: E402

__all__ += ["LPError", "LPFallbackWarning", "ProcessingError"]
from ident.robots.serial import BaseParameters, SerialRobot, base_parameters  # noqa: E402  (pinocchio loaded on use)

__all__ += ["BaseParameters", "SerialRobot", "base_parameters"]
