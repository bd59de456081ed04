"""Identification: interval arithmetic, the H4 regressor, data processing and estimators."""

from ident.parameters import N_PARAMETERS, NOMINAL_PARAMETERS, PARAMETER_NAMES, PARAMETER_UNITS, Box

__all__ = ["Box", "N_PARAMETERS", "NOMINAL_PARAMETERS", "PARAMETER_NAMES", "PARAMETER_UNITS"]
from ident.regressor import EXTRA_NAMES, inverse_dynamics, parameter_names, parameter_units, regressor  # noqa: E402

__all__ += ["EXTRA_NAMES", "inverse_dynamics", "parameter_names", "parameter_units", "regressor"]
from ident.estimate import InconsistentDataError, UnidentifiableError, estimate, min_consistent_bound  # noqa: E402
from ident.wls import WLSResult, wls  # noqa: E402

__all__ += ["InconsistentDataError", "UnidentifiableError", "WLSResult", "estimate", "min_consistent_bound", "wls"]
from ident.online import OnlineHull  # noqa: E402
from ident.outliers import OutlierBudgetError, OutlierRows, detect_outliers, relaxed_hull  # noqa: E402
from ident.uncertain import Distortion, IntervalEquation, interval_equation, interval_regressor, uncertain_hull  # noqa: E402

__all__ += ["Distortion", "IntervalEquation", "OnlineHull", "OutlierBudgetError", "OutlierRows", "detect_outliers",
            "interval_equation", "interval_regressor", "relaxed_hull", "uncertain_hull"]
from ident.lpsolver import LPError, LPFallbackWarning  # noqa: E402

__all__ += ["LPError", "LPFallbackWarning"]
from ident.serial import BaseParameters, SerialRobot, base_parameters  # noqa: E402  (pinocchio loaded on use)

__all__ += ["BaseParameters", "SerialRobot", "base_parameters"]
