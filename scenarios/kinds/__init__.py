"""Scenario kinds, one module each (see :mod:`scenarios.registry`)."""
