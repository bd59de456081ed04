"""Identification: interval arithmetic, the H4 regressor, data processing and estimators."""

from ident.parameters import N_PARAMETERS, PARAMETER_NAMES, PARAMETER_UNITS, Box

__all__ = ["Box", "N_PARAMETERS", "PARAMETER_NAMES", "PARAMETER_UNITS"]
